"""A tiny builder for one-file HTML reports: headings, text, key/value and row tables, PNG figures
embedded as base64 (matplotlib, Agg backend; drawn side by side when the page is rendered), written atomically."""
from __future__ import annotations

import base64
import functools
import html
import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import matplotlib

matplotlib.use("Agg")  # reports render PNGs without a display: the one place dgcal picks matplotlib's backend
import matplotlib.pyplot as plt  # noqa: E402  (after the backend choice)
import numpy as np  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator  # noqa: E402
from PIL import Image  # noqa: E402

from dgcal.fields.io.csv_tables import atomic_write  # noqa: E402
from dgcal.fields.processes import fork_map  # noqa: E402
from dgcal.reports.glossary import glossary_for, humanise_text, is_raw_key, label  # noqa: E402
from dgcal.reports.units import (column_decimals, fmt_number, fmt_value, gps_time, is_coordinate_label, plain,  # noqa: E402
                                 unit_of_label)  # noqa: E402

# tick labels in full numbers (no "1e9" offset or ×10⁶ factor above the axis: a GPS time or a coordinate reads as is)
matplotlib.rcParams.update({"axes.formatter.useoffset": False, "axes.formatter.limits": (-6, 12),
                            "figure.constrained_layout.use": False})

_STYLE = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1100px;
color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.6em;border-bottom:2px solid #345;padding-bottom:.2em}h2{font-size:1.25em;margin-top:1.6em;color:#345}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:.2em .6em;text-align:left}
th{background:#eef2f6}td.n{text-align:right}
.warn{background:#fff4e0;border-left:4px solid #e69500;padding:.4em .8em;margin:.3em 0}
.ok{background:#eaf7ea;border-left:4px solid #3a3;padding:.4em .8em;margin:.3em 0}
figure{margin:1em 0}figcaption{font-size:.9em;color:#555}img{max-width:100%}
.small{font-size:.85em;color:#555}
td.nw{white-space:nowrap}
.lead{margin:.6em 0 1em}.lead table{font-size:1.05em}.lead th{background:#dde6ef}
.nav a{margin-right:1em}dl.glossary dt{font-weight:600;margin-top:.4em}dl.glossary dd{margin-left:1.2em;color:#444}
@media print{body{max-width:none;margin:0;font-size:10pt}figure{page-break-inside:avoid}h2{page-break-after:avoid}
a{color:#222;text-decoration:none}}
"""


PNG_COMPRESS_LEVEL = 3   # zlib level: 3 compresses a report figure twice as fast as PIL's 6 (files within 15 %)


def figure_png(fig, dpi: int = 110) -> bytes:
    """PNG bytes of a matplotlib figure cropped to its content plus savefig's pad (as `bbox_inches="tight"`);
    the figure is closed.

    The crop is cut from one drawing, around the drawn pixels (the ink) when they keep clear of the canvas's edge:
    savefig's tight box costs a second full drawing, and matplotlib's own box of the content, which lays out every
    tick label again, a quarter of one (text layout is most of a report figure's time). Ink at the edge may be
    content spilling over it (tick labels below a short figure), which needs the canvas moved: only savefig does
    that."""
    canvas = FigureCanvasAgg(fig)
    fig.set_dpi(dpi)
    _readable_log_axes(fig)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    face = rgba[0, 0].copy()   # the face as drawn (a clear face is Agg's transparent white); ink here: box None
    box = _ink_box(rgba, face)
    pad = matplotlib.rcParams["savefig.pad_inches"]
    buf = io.BytesIO()
    if box is None:
        content = fig.get_tightbbox(canvas.get_renderer())
        fig.savefig(buf, format="png", dpi=dpi, bbox_inches=content.padded(pad))
    else:
        _crop_png(rgba, box, int(round(pad * dpi)), face, dpi, buf)
    plt.close(fig)
    return buf.getvalue()


def _readable_log_axes(fig) -> None:
    """Log axes labelled in plain numbers (0.2, 1, 5 rather than 10⁰), with the 2 and 5 of each decade labelled
    too when the axis spans fewer than three decades (matplotlib would label one tick, or none)."""
    for ax in fig.get_axes():
        for axis, scale in ((ax.xaxis, ax.get_xscale()), (ax.yaxis, ax.get_yscale())):
            if scale != "log":
                continue
            lo, hi = sorted(axis.get_view_interval())
            axis.set_major_formatter(FuncFormatter(lambda v, _: plain(v, 3)))
            if lo > 0 and np.log10(hi / lo) < 3:
                axis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))
                axis.set_minor_formatter(FuncFormatter(lambda v, _: plain(v, 3)))


def _ink_box(rgba: np.ndarray, face: np.ndarray) -> tuple[int, int, int, int] | None:
    """Rows r0:r1 and columns c0:c1 of the pixels that differ from the figure's face `face` (RGBA uint8, as drawn);
    the whole canvas when there are none, None when they reach its edge."""
    ink = rgba.view(np.uint32)[..., 0] != face.view(np.uint32)[0]
    rows, cols = np.flatnonzero(ink.any(axis=1)), np.flatnonzero(ink.any(axis=0))
    if not len(rows):
        return 0, rgba.shape[0], 0, rgba.shape[1]
    if rows[0] == 0 or cols[0] == 0 or rows[-1] == rgba.shape[0] - 1 or cols[-1] == rgba.shape[1] - 1:
        return None
    return rows[0], rows[-1] + 1, cols[0], cols[-1] + 1


def _crop_png(rgba: np.ndarray, box: tuple[int, int, int, int], pad: int, face: np.ndarray, dpi: float,
              out) -> None:
    """Write the pixels of `box` (rows r0:r1, columns c0:c1) plus `pad` pixels around, the face colour beyond the
    drawing, as PNG to `out`. PIL cuts and converts in C from a view of the canvas: no array-sized copies in
    Python (they were a quarter of a simple figure's time)."""
    r0, r1, c0, c1 = box[0] - pad, box[1] + pad, box[2] - pad, box[3] + pad
    h, w = rgba.shape[:2]
    canvas = Image.frombuffer("RGBA", (w, h), rgba, "raw", "RGBA", 0, 1)
    if r0 >= 0 and c0 >= 0 and r1 <= h and c1 <= w:   # beyond the ink the canvas is the face colour already
        page = canvas.crop((c0, r0, c1, r1))
    else:
        page = Image.new("RGBA", (c1 - c0, r1 - r0), tuple(int(v) for v in face))
        rs0, cs0 = max(r0, 0), max(c0, 0)
        page.paste(canvas.crop((cs0, rs0, min(c1, w), min(r1, h))), (cs0 - c0, rs0 - r0))
    if page.getchannel("A").getextrema()[0] == 255:   # opaque (a report figure's usual white face): RGB, a quarter
        page = page.convert("RGB")                     # less to compress
    page.save(out, format="png", dpi=(dpi, dpi), compress_level=PNG_COMPRESS_LEVEL)


def figures_png(figs: Sequence, dpi: int = 110) -> list[bytes | None]:
    """PNG bytes of figures, drawn side by side in forked processes (fields.processes.fork_map); every figure is
    closed here too, where a child drew it. An entry may instead be a function that makes the figure (made where
    it is drawn, so the making runs side by side too); one that returns None gives None."""
    for fig in figs:
        if not _is_maker(fig):
            plt.close(fig)   # out of pyplot's registry; the figure itself stays drawable
    return fork_map([functools.partial(_made_png, fig, dpi) for fig in figs])


def _is_maker(fig) -> bool:
    return callable(fig) and not isinstance(fig, Figure)


def _made_png(fig_or_maker, dpi: int) -> bytes | None:
    fig = fig_or_maker() if _is_maker(fig_or_maker) else fig_or_maker
    return None if fig is None else figure_png(fig, dpi)


MIN_BOTTOM_IN = 0.55   # room for tick labels and an x-axis label below the lowest axes (without a layout engine)


def new_figure(w_in: float = 8.0, h_in: float = 5.0, **kw):
    """A matplotlib (figure, axes) on the Agg backend, for embedding, laid out by matplotlib's constrained layout
    (tick labels, axis labels, titles, colour bars and legends beside the axes do not overlap) with at most 8 ticks
    on an x axis. `layout=None` instead keeps MIN_BOTTOM_IN below the axes (matplotlib's 11 % of a short figure's
    height is less), so the x-axis label lies inside the canvas."""
    kw.setdefault("layout", "constrained")
    fig, axes = plt.subplots(figsize=(w_in, h_in), **kw)
    if kw["layout"] is None and fig.subplotpars.bottom * h_in < MIN_BOTTOM_IN:
        fig.subplots_adjust(bottom=MIN_BOTTOM_IN / h_in)
    for ax in np.atleast_1d(axes).ravel():
        if getattr(ax, "name", "") == "rectilinear":
            ax.xaxis.set_major_locator(MaxNLocator(nbins=8))
    return fig, axes


def _fmt(v, unit: str = "", coordinate: bool = False, decimals: int | None = None) -> str:
    """A cell's text: numbers by unit (dgcal.reports.units), lists comma-separated, never e± notation."""
    return fmt_value(v, unit, coordinate, decimals)


def _label(k) -> str:
    """A row or column name as words: a raw summary key through the glossary's labels."""
    return label(k) if is_raw_key(k) else str(k)


def _cell(key_label: str, v) -> str:
    """A key/value table's value formatted by the unit of its label (GPS times as week and seconds of week)."""
    if isinstance(v, str):
        return v
    if "lat, lon" in key_label and isinstance(v, (list, tuple)) and len(v) == 3:   # latitude, longitude, height
        return f"{fmt_number(v[0], '°', True)}°, {fmt_number(v[1], '°', True)}°, {fmt_number(v[2], 'm')} m"
    if "GPS time" in key_label or key_label.endswith("(GPS s)"):
        return fmt_value([gps_time(x) for x in v]) if isinstance(v, (list, tuple)) else gps_time(v)
    return _fmt(v, unit_of_label(key_label), is_coordinate_label(key_label))


@dataclass
class _Figure:
    """A figure of a page, drawn when the page is rendered."""

    fig: object
    caption: str


def _figure_html(png: bytes, caption: str) -> str:
    b64 = base64.b64encode(png).decode("ascii")
    cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    return f'<figure><img src="data:image/png;base64,{b64}" alt="{html.escape(caption)}">{cap}</figure>'


NOWRAP_CHARS = 24   # a cell this short (a value ± sigma) stays on one line: a line break inside a number misleads


_NUMERIC = re.compile(r"^[+\-−]?[\d.]|^–$")


def _td(text: str) -> str:
    """A table cell: numbers right-aligned, a short one on one line (a line break inside a value ± sigma
    misleads); words left-aligned, as they are."""
    if not _NUMERIC.match(text):
        return f"<td>{html.escape(text)}</td>"
    c = "n nw" if len(text) <= NOWRAP_CHARS else "n"
    return f'<td class="{c}">{html.escape(text)}</td>'


def _strip_tags(text: str) -> str:
    return re.sub(r"<[^>]*>", " ", text)


class HtmlReport:
    """Collects sections of an HTML page; `write(path)` stores it as one self-contained file."""

    def __init__(self, title: str):
        self.title = title
        self.parts: list[str | _Figure] = []

    def heading(self, text: str, level: int = 2) -> "HtmlReport":
        self.parts.append(f"<h{level}>{html.escape(text)}</h{level}>")
        return self

    def text(self, text: str, cls: str | None = None) -> "HtmlReport":
        c = f' class="{cls}"' if cls else ""
        self.parts.append(f"<p{c}>{html.escape(text)}</p>")
        return self

    def warnings(self, items: Iterable[str], none_text: str = "No warnings.") -> "HtmlReport":
        items = list(items)
        if not items:
            self.parts.append(f'<div class="ok">{html.escape(none_text)}</div>')
        for w in items:
            self.parts.append(f'<div class="warn">{html.escape(humanise_text(w))}</div>')
        return self

    def kv_table(self, pairs: Iterable[tuple[str, object]], cls: str | None = None) -> "HtmlReport":
        """A table of name/value rows: a raw summary key becomes words (dgcal.reports.glossary.label), a value is
        formatted by the unit in its name's parentheses (dgcal.reports.units); rows whose value is None are left
        out. `cls`: a class of the table ('lead': the headline result)."""
        rows = "".join(f"<tr><th>{html.escape(lab)}</th>{_td(_cell(lab, v))}</tr>"
                       for lab, v in ((_label(k), v) for k, v in pairs if v is not None))
        c = f' class="{cls}"' if cls else ""
        self.parts.append(f"<table{c}>{rows}</table>")
        return self

    def headline(self, pairs: Iterable[tuple[str, object]], text: str | None = None) -> "HtmlReport":
        """The page's result at its top: an optional sentence, then the values with their sigmas (a lead table)."""
        self.parts.append('<div class="lead">')
        if text:
            self.text(text)
        self.kv_table(pairs)
        self.parts.append("</div>")
        return self

    def table(self, header: Sequence[str], rows: Iterable[Sequence]) -> "HtmlReport":
        """A table with a header row; every column's numbers formatted by the unit in its header's parentheses."""
        header = [_label(h) for h in header]
        units = [unit_of_label(h) for h in header]
        coords = [is_coordinate_label(h) for h in header]
        rows = [list(r) for r in rows]
        width = max([len(header)] + [len(r) for r in rows])
        units += [""] * (width - len(units))
        coords += [False] * (width - len(coords))
        dec = [None if coords[j] else column_decimals([r[j] for r in rows if j < len(r)], units[j])
               for j in range(width)]
        head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
        body = "".join("<tr>" + "".join(_td(_fmt(v, units[j], coords[j], dec[j])) for j, v in enumerate(r))
                       + "</tr>" for r in rows)
        self.parts.append(f"<table><tr>{head}</tr>{body}</table>")
        return self

    def glossary(self) -> "HtmlReport":
        """The glossary of the technical terms the page uses so far (dgcal.reports.glossary), as a last section."""
        text = " ".join(p if isinstance(p, str) else p.caption for p in self.parts)
        entries = glossary_for(_strip_tags(text))
        if entries:
            self.parts.append('<h2 id="glossary">Glossary</h2><dl class="glossary">' + "".join(
                f"<dt>{html.escape(t)}</dt><dd>{html.escape(w)}</dd>" for t, w in entries) + "</dl>")
        return self

    def figure(self, fig_or_png, caption: str = "") -> "HtmlReport":
        """Embed a matplotlib figure (or PNG bytes) as a base64 image; a figure is drawn when the page is
        rendered, side by side with the page's other figures (`render`). A function that makes the figure (or
        returns None: no figure, no caption) is called then too, side by side with the others."""
        if isinstance(fig_or_png, (bytes, bytearray)):
            self.parts.append(_figure_html(fig_or_png, caption))
        else:
            if not _is_maker(fig_or_png):
                plt.close(fig_or_png)   # out of pyplot's registry now (a page may hold many); still drawable
            self.parts.append(_Figure(fig_or_png, caption))
        return self

    def raw(self, html_text: str) -> "HtmlReport":
        self.parts.append(html_text)
        return self

    def render(self, glossary: bool = True) -> str:
        """The page; its figures drawn first, side by side (`figures_png`); with `glossary`, the glossary of the
        terms it uses last (once)."""
        if glossary and not any(isinstance(p, str) and 'id="glossary"' in p for p in self.parts):
            self.glossary()
        pending = [(i, p) for i, p in enumerate(self.parts) if isinstance(p, _Figure)]
        pngs = figures_png([p.fig for _, p in pending])
        for (i, p), png in zip(pending, pngs):
            self.parts[i] = "" if png is None else _figure_html(png, p.caption)
        return (f"<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>{html.escape(self.title)}</title>"
                f"<style>{_STYLE}</style></head><body><h1>{html.escape(self.title)}</h1>"
                + "\n".join(p for p in self.parts if p) + "</body></html>\n")

    def write(self, path: str | Path) -> Path:
        """Write the page atomically; returns the path."""
        with atomic_write(path, encoding="utf-8") as fh:
            fh.write(self.render())
        return Path(path)
