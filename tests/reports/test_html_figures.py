"""HtmlReport draws its figures when the page is rendered, side by side in forked processes: the page is the
one drawn figure by figure in this process, and the figures leave pyplot's registry when added."""
from __future__ import annotations

import io

import numpy as np
from matplotlib.colors import to_rgba
from PIL import Image

import dgcal.reports.html as html
from dgcal.reports.html import HtmlReport, new_figure


def _page() -> HtmlReport:
    rep = HtmlReport("figures")
    for k in range(5):
        fig, ax = new_figure(4, 3)
        ax.plot(np.arange(50), np.sin(np.arange(50) / (k + 2)), label=f"curve {k}")
        ax.legend()
        rep.figure(fig, f"figure {k}")
        rep.text(f"after figure {k}")
    return rep


def test_figures_drawn_side_by_side_give_the_same_page(monkeypatch):
    before = set(html.plt.get_fignums())         # figures other tests of this process left open
    side_by_side = _page()
    assert set(html.plt.get_fignums()) <= before   # closed in pyplot, still drawable
    page = side_by_side.render()
    monkeypatch.setattr(html, "fork_map", lambda tasks: [t() for t in tasks])
    assert _page().render() == page
    assert page.count("<img src=\"data:image/png;base64,") == 5
    assert page.index("figure 0") < page.index("after figure 0") < page.index("figure 1")


def test_figures_png_leaves_no_figure_open_where_children_drew_them():
    before = set(html.plt.get_fignums())
    figs = []
    for k in range(3):
        fig, ax = new_figure(3, 2)
        ax.plot([0, 1], [k, 1 - k])
        figs.append(fig)
    pngs = html.figures_png(figs, dpi=60)
    assert set(html.plt.get_fignums()) <= before
    assert [p[:8] for p in pngs] == [b"\x89PNG\r\n\x1a\n"] * 3
    assert pngs == [html.figure_png(f, 60) for f in figs]       # the same bytes drawn here


def _tight_png(fig, dpi: int) -> np.ndarray:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return np.asarray(Image.open(buf).convert("L"), float)


def test_figure_png_is_savefigs_tight_crop_from_one_drawing():
    """Content inside the figure is cut from one drawing, content spilling over its edge goes through savefig:
    either way the picture is savefig's tight crop (same size to a pixel, the same ink)."""
    for spill in (False, True):
        fig, ax = new_figure(4, 3, layout=None)   # the crop, not the layout engine, is under test here
        ax.plot(np.arange(30), np.cos(np.arange(30) / 4), label="curve")
        ax.legend()
        ax.set_title("a title")
        if spill:   # a long tick label and an axis label hanging below the figure
            fig.subplots_adjust(bottom=0.02)
            ax.set_xlabel("an axis label\nover two lines")
        tight = _tight_png(fig, 80)
        got = np.asarray(Image.open(io.BytesIO(html.figure_png(fig, 80))).convert("L"), float)
        assert abs(got.shape[0] - tight.shape[0]) <= 1 and abs(got.shape[1] - tight.shape[1]) <= 1
        h, w = min(got.shape[0], tight.shape[0]), min(got.shape[1], tight.shape[1])
        ink_got, ink_tight = (255 - got).sum(), (255 - tight).sum()
        assert abs(ink_got - ink_tight) < 0.02 * ink_tight                          # nothing cut off or added
        assert np.abs(got[:h, :w] - tight[:h, :w]).mean() < 12                      # at most a sub-pixel shift


def test_a_figure_inside_its_canvas_is_drawn_once_and_keeps_its_face_colour(monkeypatch):
    """The crop of content inside the canvas comes from the one drawing (no savefig, no second layout), around the
    drawn pixels plus savefig's pad, in the figure's own face colour (opaque: RGB; transparent: RGBA)."""
    draws = []
    real_draw = html.Figure.draw
    monkeypatch.setattr(html.Figure, "draw", lambda self, renderer: draws.append(face) or real_draw(self, renderer))
    for face, mode in (("#ddeeff", "RGB"), ("none", "RGBA")):
        fig, ax = new_figure(4, 3)
        fig.set_facecolor(face)
        fig.set_edgecolor(face)
        ax.plot([0, 1, 2], [0, 2, 1])
        draws.clear()
        img = Image.open(io.BytesIO(html.figure_png(fig, 80)))
        assert draws == [face] and img.mode == mode
        px = np.asarray(img)
        border = np.concatenate([px[:8].reshape(-1, px.shape[2]), px[-8:].reshape(-1, px.shape[2]),
                                 px[:, :8].reshape(-1, px.shape[2]), px[:, -8:].reshape(-1, px.shape[2])])
        want = np.round(np.array(to_rgba(face)) * 255)[:px.shape[2]] if face != "none" else [255, 255, 255, 0]
        assert np.all(border == want)                                               # the pad: face colour only
        inner = px[9:-9, 9:-9].reshape(-1, px.shape[2])
        assert [np.any(inner[:, c] != want[c]) for c in range(px.shape[2])].count(True) >= 1   # the drawing is there


def test_a_figure_maker_is_called_when_the_page_is_drawn_and_none_leaves_no_figure():
    def curve():
        fig, ax = new_figure(3, 2)
        ax.plot([0, 1, 2], [1, 0, 1])
        return fig

    eager, lazy = HtmlReport("p"), HtmlReport("p")
    eager.figure(curve(), "a curve")
    lazy.figure(curve, "a curve")
    lazy.figure(lambda: None, "nothing to show")
    lazy_page = lazy.render()
    assert lazy_page == eager.render()
    assert "nothing to show" not in lazy_page and lazy_page.count("<img") == 1
