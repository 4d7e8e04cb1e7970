"""HtmlReport draws its figures when the page is rendered, side by side in forked processes: the page is the
one drawn figure by figure in this process, and the figures leave pyplot's registry when added."""
from __future__ import annotations

import numpy as np

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
