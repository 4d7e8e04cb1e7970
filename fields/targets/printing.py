"""The printable field: the ChArUco plate's black rectangles (`dgcal.fields.targets.texture`) as a true-scale PDF
(vector) and PNG (with DPI); the same sheet for a standard board."""
from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Rectangle
from PIL import Image

from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.targets.boards import Board, board_texture, write_board_field
from dgcal.fields.targets.plate import TargetField, layout_path, write_field
from dgcal.fields.targets.texture import black_rectangles

INCH_M = 0.0254


def print_raster(tf: TargetField, dpi: float) -> np.ndarray:
    """uint8 raster of the printed plate at `dpi` (white paper, black marks, grey cut circle)."""
    px = INCH_M / dpi
    n_px = int(round(tf.board_size_m / px))
    img = np.full((n_px, n_px), 255, np.uint8)
    for x0, y0, x1, y1 in np.round(black_rectangles(tf) / px).astype(int):
        img[y0:y1, x0:x1] = 0
    c = n_px / 2 - 0.5
    cv2.circle(img, (int(round(c * 16)), int(round(c * 16))), int(round(tf.diameter_m / 2 / px * 16)), 128,
               thickness=max(1, int(round(0.001 / px))), lineType=cv2.LINE_AA, shift=4)
    return img


def _label(tf: TargetField) -> str:
    ids, _, _ = tf.targets()
    return (f"dgcal ChArUco plate  diameter {tf.diameter_m:g} m  square {tf.square_m * 1000:g} mm  "
            f"marker {tf.marker_m * 1000:g} mm  {tf.dictionary}  {len(ids)} targets  "
            f"board {tf.n_squares}x{tf.n_squares}{'  legacy' if tf.legacy_pattern else ''}")


def write_pdf(path: str | Path, tf: TargetField) -> None:
    """Vector PDF of the plate at true scale (page = the board square), with a 100 mm check bar."""
    S = tf.board_size_m
    fig = Figure(figsize=(S / INCH_M, S / INCH_M))  # a bare Figure: no pyplot state, no GUI backend
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, S)
    ax.set_ylim(S, 0)
    ax.axis("off")
    r = black_rectangles(tf)
    polys = np.stack([r[:, [0, 1]], r[:, [2, 1]], r[:, [2, 3]], r[:, [0, 3]]], axis=1)
    ax.add_collection(PolyCollection(polys, facecolors="black", edgecolors="none", antialiased=False))
    ax.add_patch(Circle((S / 2, S / 2), tf.diameter_m / 2, fill=False, edgecolor="0.5", linewidth=1.0))
    pt = 72 / INCH_M  # points per metre
    ax.text(0.02 * S, 0.02 * S, _label(tf), fontsize=0.012 * pt, va="top", ha="left")
    ax.text(0.02 * S, 0.04 * S, "print at 100 % (no scaling); the bar below the title must measure 100.0 mm",
            fontsize=0.010 * pt, va="top", ha="left")
    ax.add_patch(Rectangle((0.02 * S, 0.06 * S), 0.1, 0.004, color="black"))
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="pdf")


def write_png(path: str | Path, tf: TargetField, dpi: float = 100.0) -> None:
    """PNG raster of the plate at true scale with its DPI recorded (pHYs), for printing or viewing."""
    img = print_raster(tf, dpi)
    with atomic_write(path, "wb") as fh:
        Image.fromarray(img).save(fh, format="PNG", dpi=(dpi, dpi))


PAGES_MM = {"A4": (210, 297), "A3": (297, 420), "A2": (420, 594), "A1": (594, 841), "A0": (841, 1189)}


def tile_grid(tf: TargetField, page: str = "A3", margin_m: float = 0.010, overlap_m: float = 0.010,
              landscape: bool = True) -> list[tuple[int, int, float, float, float, float]]:
    """Tiles (row, col, x0, y0, x1, y1 in the board frame, m) covering the plate on `page` sheets: each tile
    is the printable area (page minus margins); neighbours overlap by `overlap_m`; empty tiles are left out."""
    w_mm, h_mm = PAGES_MM[page]
    if landscape:
        w_mm, h_mm = h_mm, w_mm
    tw, th = w_mm / 1000 - 2 * margin_m, h_mm / 1000 - 2 * margin_m
    S, R = tf.board_size_m, tf.diameter_m / 2
    nx = max(1, math.ceil((S - overlap_m) / (tw - overlap_m)))
    ny = max(1, math.ceil((S - overlap_m) / (th - overlap_m)))
    # centre the tile grid on the board
    x_start = S / 2 - (nx * (tw - overlap_m) + overlap_m) / 2
    y_start = S / 2 - (ny * (th - overlap_m) + overlap_m) / 2
    tiles = []
    for r in range(ny):
        for c in range(nx):
            x0, y0 = x_start + c * (tw - overlap_m), y_start + r * (th - overlap_m)
            x1, y1 = x0 + tw, y0 + th
            # nearest point of the tile to the plate centre: skip tiles off the plate
            dx = max(x0 - S / 2, 0, S / 2 - x1)
            dy = max(y0 - S / 2, 0, S / 2 - y1)
            if math.hypot(dx, dy) < R:
                tiles.append((r, c, x0, y0, x1, y1))
    return tiles


def tile_figure(tf: TargetField, tile: tuple, page: str = "A3", margin_m: float = 0.010,
                overlap_m: float = 0.010, rects: np.ndarray | None = None):
    """The matplotlib figure of one tile (from `tile_grid`) on a landscape `page` sheet at true scale."""
    r, c, x0, y0, x1, y1 = tile
    w_mm, h_mm = PAGES_MM[page]
    pw, ph = h_mm / 1000, w_mm / 1000  # landscape
    rects = black_rectangles(tf) if rects is None else rects
    S = tf.board_size_m
    fig = Figure(figsize=(pw / INCH_M, ph / INCH_M))  # a bare Figure: no pyplot state, no GUI backend
    ax = fig.add_axes((0, 0, 1, 1))
    # the axes span the whole sheet: the tile sits inside the margins
    ax.set_xlim(x0 - margin_m, x0 - margin_m + pw)
    ax.set_ylim(y0 - margin_m + ph, y0 - margin_m)
    ax.axis("off")
    sel = (rects[:, 2] > x0) & (rects[:, 0] < x1) & (rects[:, 3] > y0) & (rects[:, 1] < y1)
    rs = rects[sel]
    polys = np.stack([rs[:, [0, 1]], rs[:, [2, 1]], rs[:, [2, 3]], rs[:, [0, 3]]], axis=1)
    coll = PolyCollection(polys, facecolors="black", edgecolors="none", antialiased=False)
    clip = Rectangle((x0, y0), x1 - x0, y1 - y0, transform=ax.transData)
    coll.set_clip_path(clip)
    ax.add_collection(coll)
    circ = Circle((S / 2, S / 2), tf.diameter_m / 2, fill=False, edgecolor="0.5", linewidth=0.5)
    circ.set_clip_path(clip)
    ax.add_patch(circ)
    ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, edgecolor="0.6", linewidth=0.3))
    ax.add_patch(Rectangle((x0 + overlap_m, y0 + overlap_m), x1 - x0 - 2 * overlap_m, y1 - y0 - 2 * overlap_m,
                           fill=False, edgecolor="0.8", linewidth=0.3, linestyle="--"))
    ax.text(x0, y0 - margin_m / 2, f"tile row {r + 1} col {c + 1}  ({page}, print at 100 %, overlap "
            f"{overlap_m * 1000:g} mm)  {_label(tf)}", fontsize=0.0025 * 72 / INCH_M, va="center", ha="left",
            color="0.3")
    return fig


def write_pdf_tiles(path: str | Path, tf: TargetField, page: str = "A3", margin_m: float = 0.010,
                    overlap_m: float = 0.010) -> int:
    """Multi-page PDF of the plate on `page` sheets at true scale (landscape), one tile per page with its
    row/column, the tile outline and overlap lines for assembling; returns the number of pages."""
    rects = black_rectangles(tf)
    tiles = tile_grid(tf, page, margin_m, overlap_m)
    from matplotlib.backends.backend_pdf import PdfPages   # here: 0.4 s to import, only PDF tiles need it
    with atomic_write(path, "wb") as fh, PdfPages(fh) as pdf:
        for tile in tiles:
            fig = tile_figure(tf, tile, page, margin_m, overlap_m, rects)
            pdf.savefig(fig)
    return len(tiles)


def write_field_files(out_dir: str | Path, tf: TargetField, names: dict[str, str], png_dpi: float | None = 100.0,
                      tiles: str | None = None) -> dict[str, Path]:
    """`dgcal field`'s files in `out_dir`, named by role in `names`: field (CSV, with its layout JSON beside it),
    pdf (true scale), png (at `png_dpi`; None: none) and, with a page size `tiles`, the tiled PDF (role
    tiles, a name with `{page}`); returns the paths by role and the number of tile pages (key tile_pages)."""
    out = Path(out_dir)
    paths: dict = {"field": out / names["field"], "pdf": out / names["pdf"]}
    write_field(paths["field"], tf)
    paths["layout"] = layout_path(paths["field"])
    write_pdf(paths["pdf"], tf)
    if png_dpi is not None:
        paths["png"] = out / names["png"]
        write_png(paths["png"], tf, png_dpi)
    if tiles:
        paths["tiles"] = out / names["tiles"].format(page=tiles)
        paths["tile_pages"] = write_pdf_tiles(paths["tiles"], tf, tiles)
    return paths


# ---------------------------------------------------------------------------------------------
# standard boards (dgcal.fields.targets.boards)
# ---------------------------------------------------------------------------------------------
BOARD_MARGIN_M = 0.015     # white paper around a printed board (a chessboard needs a quiet zone)
BOARD_HEADER_M = 0.012     # strip above it for the title and the check bar


def _board_label(board: Board) -> str:
    return f"dgcal board: {board.describe()}  ({board.n_corners} corners)"


def write_board_pdf(path: str | Path, board: Board) -> None:
    """Vector PDF of a standard board at true scale: the board with a white margin, a title line and a check bar
    (100 mm, or the largest whole 10 mm that fits). Inverted boards are printed white on black."""
    bw, bh = board.size_m
    m, top = BOARD_MARGIN_M, BOARD_HEADER_M
    W, H = bw + 2 * m, bh + 2 * m + top
    fig = Figure(figsize=(W / INCH_M, H / INCH_M))
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(-m, bw + m)
    ax.set_ylim(bh + m, -m - top)
    ax.axis("off")
    r = board.black_rectangles()
    ink = "white" if board.inverted else "black"
    if board.inverted:
        ax.add_patch(Rectangle((0, 0), bw, bh, color="black", linewidth=0))
    polys = np.stack([r[:, [0, 1]], r[:, [2, 1]], r[:, [2, 3]], r[:, [0, 3]]], axis=1)
    ax.add_collection(PolyCollection(polys, facecolors=ink, edgecolors="none", antialiased=False))
    pt = 72 / INCH_M
    ax.text(0, -m - top + 0.002, _board_label(board) + "  - print at 100 %", fontsize=min(0.0035, top / 3) * pt,
            va="top", ha="left")
    bar = min(0.1, math.floor(bw * 100) / 100)
    ax.add_patch(Rectangle((0, -m - 0.004), bar, 0.002, color="black"))
    ax.text(bar + 0.002, -m - 0.003, f"{bar * 1000:g} mm", fontsize=0.0025 * pt, va="center", ha="left")
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="pdf")


def board_raster(board: Board, dpi: float) -> np.ndarray:
    """uint8 raster of the printed board with its white margin at `dpi` (area-filtered edges)."""
    grey, _ = board_texture(board, INCH_M / dpi, BOARD_MARGIN_M)
    return np.clip(np.rint(grey * 255), 0, 255).astype(np.uint8)


def write_board_files(out_dir: str | Path, board: Board, names: dict[str, str], png_dpi: float | None = 300.0,
                      ) -> dict[str, Path]:
    """`dgcal field --board`'s files in `out_dir`, named by role in `names`: field (CSV, ids = corner indices, with
    its layout JSON beside it), board (a normalised copy of the board TOML), pdf (true scale) and png (at
    `png_dpi`; None: none); returns the paths by role."""
    out = Path(out_dir)
    paths: dict = {"field": out / names["field"], "pdf": out / names["pdf"],
                   "board": out / names.get("board", "board.toml")}
    write_board_field(paths["field"], board)
    paths["layout"] = paths["field"].with_suffix(".json")
    with atomic_write(paths["board"]) as fh:
        fh.write(f"# {_board_label(board)}\n" + board.to_toml())
    write_board_pdf(paths["pdf"], board)
    if png_dpi is not None:
        paths["png"] = out / names["png"]
        with atomic_write(paths["png"], "wb") as fh:
            Image.fromarray(board_raster(board, png_dpi)).save(fh, format="PNG", dpi=(png_dpi, png_dpi))
    return paths
