"""Standard calibration boards described by a small TOML file: ChArUco, chessboard, ArUco grid.

A board file (`--board BOARD.toml`) holds::

    type = "charuco"            # charuco | chessboard | aruco-grid (default charuco)
    columns = 4                 # squares across (aruco-grid: markers across)
    rows = 5                    # squares down   (aruco-grid: markers down)
    square_m = 0.054            # square side (aruco-grid: marker pitch, marker + gap), m
    marker_m = 0.0405           # ArUco marker side, m (charuco, aruco-grid)
    dictionary = "DICT_4X4_1000"  # OpenCV ArUco dictionary name (charuco, aruco-grid)
    first_id = 0                # id of the first marker (default 0)
    inverted = false            # printed with black and white swapped (detected in 255 - image)
    legacy = false              # OpenCV's legacy ChArUco layout (before 4.6) (default false)
    mirrored = "auto"           # views of the back face: "auto" (recognised, default), true (only), false (never)

caliscope's board files are read too: `square_size_override_cm` (cm), `aruco_scale` (marker side as a fraction
of the square), `legacy_pattern`, and `board_width`, `board_height` with `units` ("inch" or "cm") when no
square size is given (square = the largest that fits, as caliscope computes it).

Board frame (OpenCV's, m): origin at the top-left corner of the board's outer squares (aruco-grid: of the first
marker), x to the right, y down the printed face, z into the board (away from a camera looking at its face).
Corner ids are the board's own corner indices, as strings:

- charuco, chessboard: inner chessboard corner (row r, column c), id ``r * (columns - 1) + c`` (OpenCV's ChArUco
  corner id; findChessboardCornersSB's order), at ((c + 1) square, (r + 1) square).
- aruco-grid: corner k (0 top-left, 1 top-right, 2 bottom-right, 3 bottom-left, OpenCV's order) of the i-th marker
  (row by row, marker id ``first_id + i``), id ``4 i + k``.
"""
from __future__ import annotations

import json
import math
import re
import sys
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from dgcal.fields.errors import InputError
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.io.text_files import read_text
from dgcal.fields.io.validate import toml_numbers_in_range
from dgcal.fields.io.formats import Points, write_points
from dgcal.fields.targets.plate import read_layout_json

BOARD_TYPES = ("charuco", "chessboard", "aruco-grid")
INCH_M = 0.0254
# keys of dgcal's board files, and those of caliscope's that are understood (others are reported and ignored)
BOARD_KEYS = ("type", "columns", "rows", "square_m", "marker_m", "dictionary", "first_id", "inverted", "legacy",
              "mirrored")
CALISCOPE_KEYS = ("square_size_override_cm", "square_size_overide_cm", "aruco_scale", "legacy_pattern",
                  "board_width", "board_height", "units")


def dictionary_names() -> list[str]:
    """The OpenCV ArUco predefined dictionary names (DICT_...)."""
    return sorted(k for k in dir(cv2.aruco) if k.startswith("DICT_") and isinstance(getattr(cv2.aruco, k), int))


def cv_dictionary(name: str):
    """The OpenCV predefined ArUco dictionary `name`; InputError (field dictionary) if there is none."""
    if not (isinstance(name, str) and name.startswith("DICT_") and isinstance(getattr(cv2.aruco, name, None), int)):
        near = [k for k in dictionary_names() if str(name).upper().replace("-", "_") in k]
        hint = f" (did you mean {', '.join(near[:3])}?)" if near else " (e.g. DICT_4X4_1000, DICT_5X5_250)"
        raise InputError(f"unknown ArUco dictionary {name!r}{hint}", field="dictionary")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


MAX_BOARD_SQUARES = 1000                     # squares (markers) across a board
MIN_BOARD_SIDE_M, MAX_BOARD_SIDE_M = 1e-4, 100.0   # m, the side of a square


@dataclass(frozen=True)
class Board:
    """A standard calibration board: type, squares across and down, square and marker sides (m), ArUco dictionary,
    first marker id, print polarity (inverted), OpenCV legacy ChArUco layout, and back-face handling."""

    type: str = "charuco"
    columns: int = 0
    rows: int = 0
    square_m: float = 0.0
    marker_m: float | None = None
    dictionary: str | None = None
    first_id: int = 0
    inverted: bool = False
    legacy: bool = False
    mirrored: bool | None = None        # None: recognised automatically; True: only back-face views; False: never

    def __post_init__(self):
        if self.type not in BOARD_TYPES:
            raise InputError(f"unknown board type {self.type!r}; use one of {', '.join(BOARD_TYPES)}", field="type")
        for k in ("columns", "rows"):
            v = getattr(self, k)
            if not isinstance(v, int) or isinstance(v, bool) or v < (1 if self.type == "aruco-grid" else 2):
                raise InputError(f"needs a whole number of {'markers' if self.type == 'aruco-grid' else 'squares'}"
                                 f" >= {1 if self.type == 'aruco-grid' else 2}, got {v!r}", field=k)
        if self.type != "aruco-grid" and (self.columns - 1) * (self.rows - 1) < 4:
            raise InputError(f"a {self.columns} x {self.rows} board has fewer than 4 inner corners", field="columns")
        for k in ("columns", "rows"):
            if getattr(self, k) > MAX_BOARD_SQUARES:
                raise InputError(f"implausible board: more than {MAX_BOARD_SQUARES} across, got {getattr(self, k)}",
                                 field=k)
        if not (isinstance(self.square_m, (int, float)) and math.isfinite(self.square_m)
                and MIN_BOARD_SIDE_M <= self.square_m <= MAX_BOARD_SIDE_M):
            raise InputError(f"square side must be a number of metres in [{MIN_BOARD_SIDE_M:g}, {MAX_BOARD_SIDE_M:g}],"
                             f" got {self.square_m!r}", field="square_m")
        if self.type == "chessboard":
            return
        if self.marker_m is None:
            raise InputError(f"a {self.type} board needs the marker side", field="marker_m")
        if not (isinstance(self.marker_m, (int, float)) and math.isfinite(self.marker_m)
                and 0.01 * self.square_m <= self.marker_m):
            raise InputError(f"marker side must be a positive number of metres (at least 1 % of the square), got "
                             f"{self.marker_m!r}", field="marker_m")
        if self.type == "charuco" and not self.marker_m < self.square_m:
            raise InputError(f"the marker ({self.marker_m:g} m) must be smaller than the square ({self.square_m:g} m)",
                             field="marker_m")
        if self.type == "aruco-grid" and not self.marker_m < self.square_m:
            raise InputError(f"the marker ({self.marker_m:g} m) must be smaller than the marker pitch square_m "
                             f"({self.square_m:g} m: marker plus gap)", field="marker_m")
        if self.dictionary is None:
            raise InputError(f"a {self.type} board needs an ArUco dictionary", field="dictionary")
        d = cv_dictionary(self.dictionary)
        if not isinstance(self.first_id, int) or self.first_id < 0:
            raise InputError(f"must be a whole number >= 0, got {self.first_id!r}", field="first_id")
        size = int(d.bytesList.shape[0])
        if self.first_id + self.n_markers > size:
            last = self.first_id + self.n_markers - 1
            raise InputError(f"{self.dictionary} has {size} markers; ids {self.first_id}..{last} of this board do "
                             "not fit", field="first_id")

    # --- sizes and ids -------------------------------------------------------------------------
    @property
    def n_markers(self) -> int:
        """Number of ArUco markers on the board (0 for a chessboard)."""
        if self.type == "charuco":
            return (self.columns * self.rows) // 2
        return self.columns * self.rows if self.type == "aruco-grid" else 0

    @property
    def n_corners(self) -> int:
        """Number of corners (targets) the board defines."""
        if self.type == "aruco-grid":
            return 4 * self.n_markers
        return (self.columns - 1) * (self.rows - 1)

    @property
    def size_m(self) -> tuple[float, float]:
        """Printed width and height of the board (m), margins excluded."""
        if self.type == "aruco-grid":
            gap = self.square_m - self.marker_m
            return self.columns * self.square_m - gap, self.rows * self.square_m - gap
        return self.columns * self.square_m, self.rows * self.square_m

    @property
    def pattern_size(self) -> tuple[int, int]:
        """Inner corners across and down (OpenCV's patternSize for chessboards)."""
        return self.columns - 1, self.rows - 1

    def marker_ids(self) -> np.ndarray:
        """Marker ids on the board, row by row (first_id, first_id + 1, ...)."""
        return self.first_id + np.arange(self.n_markers, dtype=np.int32)

    def corner_ids(self) -> np.ndarray:
        """The string corner ids '0' .. 'K-1' (the board's own corner indices)."""
        return np.array([str(k) for k in range(self.n_corners)], dtype=object)

    def corner_xyz(self) -> np.ndarray:
        """(K,3) corner coordinates in the board frame (m; x right, y down, z = 0), in corner-index order."""
        if self.type == "aruco-grid":
            return np.asarray(self.cv_board().getObjPoints(), float).reshape(-1, 3)
        c, r = np.meshgrid(np.arange(self.columns - 1), np.arange(self.rows - 1))
        return np.column_stack([(c.ravel() + 1) * self.square_m, (r.ravel() + 1) * self.square_m,
                                np.zeros(c.size)])

    def points(self) -> Points:
        """The corners as a field Points table (board frame, m; no coordinate sigmas)."""
        n = self.n_corners
        return Points(self.corner_ids(), self.corner_xyz(), np.full((n, 3), np.nan),
                      np.full(n, "control", dtype=object))

    # --- OpenCV objects --------------------------------------------------------------------------
    def cv_dictionary(self):
        """The board's OpenCV ArUco dictionary."""
        return cv_dictionary(self.dictionary)

    def cv_board(self):
        """OpenCV's CharucoBoard or GridBoard of this board (None for a chessboard)."""
        if self.type == "chessboard":
            return None
        ids = self.marker_ids()
        if self.type == "charuco":
            b = cv2.aruco.CharucoBoard((self.columns, self.rows), float(self.square_m), float(self.marker_m),
                                       self.cv_dictionary(), ids)
            b.setLegacyPattern(bool(self.legacy))
            return b
        return cv2.aruco.GridBoard((self.columns, self.rows), float(self.marker_m),
                                   float(self.square_m - self.marker_m), self.cv_dictionary(), ids)

    def black_squares(self) -> np.ndarray:
        """(rows, columns) bool: chessboard squares printed black on the front face (before inversion)."""
        if self.type == "aruco-grid":
            return np.zeros((self.rows, self.columns), bool)
        if self.type == "chessboard":
            r, c = np.mgrid[0:self.rows, 0:self.columns]
            return (r + c) % 2 == 0
        centre = np.asarray(self.cv_board().getObjPoints(), float)[:, :, :2].mean(axis=1)
        rc = np.floor(centre[:, ::-1] / self.square_m).astype(int)
        black = np.ones((self.rows, self.columns), bool)
        black[rc[:, 0], rc[:, 1]] = False
        return black

    def black_rectangles(self) -> np.ndarray:
        """(K,4) rectangles x0, y0, x1, y1 (board frame, m) printed black on the front face (before inversion):
        black chessboard squares and the black cells of the markers (runs along a row merged)."""
        s = self.square_m
        r, c = np.nonzero(self.black_squares())
        rects = [np.column_stack([c * s, r * s, (c + 1) * s, (r + 1) * s]).astype(float)]
        if self.type != "chessboard":
            b = self.cv_board()
            nbits = self.cv_dictionary().markerSize
            for mid, cor in zip(np.asarray(b.getIds()).ravel(), np.asarray(b.getObjPoints(), float)[:, :, :2]):
                cells = cv2.aruco.generateImageMarker(self.cv_dictionary(), int(mid), nbits + 2, borderBits=1) < 128
                (x0, y0), (x1, _) = cor.min(axis=0), cor.max(axis=0)
                cw = (x1 - x0) / (nbits + 2)
                for i in range(nbits + 2):
                    d = np.diff(np.concatenate([[0], cells[i].astype(int), [0]]))
                    for a, e in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)):
                        rects.append(np.array([[x0 + a * cw, y0 + i * cw, x0 + e * cw, y0 + (i + 1) * cw]]))
        return np.concatenate(rects, axis=0)

    # --- persistence -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The board as a plain dict (TOML/JSON keys of this module)."""
        d = asdict(self)
        if d["mirrored"] is None:
            d["mirrored"] = "auto"
        return {k: v for k, v in d.items() if v is not None}

    def to_toml(self) -> str:
        """The board as TOML text (dgcal's keys)."""
        def val(v):
            if isinstance(v, bool):
                return "true" if v else "false"
            if isinstance(v, str):
                return f'"{v}"'
            return repr(v)
        return "".join(f"{k} = {val(v)}\n" for k, v in self.to_dict().items())

    def describe(self) -> str:
        """One line: type, size, square/marker (mm), dictionary, polarity."""
        parts = [f"{self.type} {self.columns} x {self.rows}", f"square {self.square_m * 1000:g} mm"]
        if self.type != "chessboard":
            parts += [f"marker {self.marker_m * 1000:g} mm", str(self.dictionary)]
            if self.first_id:
                parts.append(f"first id {self.first_id}")
        if self.inverted:
            parts.append("inverted")
        if self.legacy:
            parts.append("legacy layout")
        return ", ".join(parts)


def _key_line(text: str, key: str) -> int | None:
    """Line number of `key = ...` in TOML text (None when absent)."""
    for i, line in enumerate(text.splitlines(), 1):
        if re.match(rf"\s*{re.escape(key)}\s*=", line):
            return i
    return None


def board_from_dict(d: dict, path: str | Path | None = None, text: str = "") -> Board:
    """A Board from the keys of a board file (dgcal's or caliscope's; see the module doc); InputError naming the
    file, line and field."""
    def fail(msg, key):
        raise InputError(msg, path, _key_line(text, key) if key else None, key)

    def num(key):
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            fail(f"must be a number, got {v!r}", key)
        return float(v)

    def flag(key):
        v = d[key]
        if not isinstance(v, bool):
            fail(f"must be true or false, got {v!r}", key)
        return v

    unknown = [k for k in d if k not in BOARD_KEYS + CALISCOPE_KEYS]
    if unknown:
        print(f"dgcal: warning: {path or 'board'}: ignoring unknown key(s) {', '.join(unknown)}", file=sys.stderr)
    kw: dict = {}
    kind = d.get("type", "charuco")
    kw["type"] = kind if not isinstance(kind, str) else kind.strip().lower().replace("_", "-")
    for k in ("columns", "rows", "first_id"):
        if k in d:
            if isinstance(d[k], bool) or not isinstance(d[k], int):
                fail(f"must be a whole number, got {d[k]!r}", k)
            kw[k] = d[k]
    for k in ("columns", "rows"):
        if k not in kw:
            fail("missing (squares across / down)", None if path is None else k)
    if "square_m" in d:
        kw["square_m"] = num("square_m")
    else:
        ck = next((k for k in ("square_size_override_cm", "square_size_overide_cm") if k in d and d[k]), None)
        if ck is not None:
            kw["square_m"] = round(num(ck) / 100.0, 12)
        elif "board_width" in d and "board_height" in d:
            unit = {"inch": INCH_M, "cm": 0.01, "mm": 0.001, "m": 1.0}.get(str(d.get("units", "inch")))
            if unit is None:
                fail(f"units must be inch, cm, mm or m, got {d.get('units')!r}", "units")
            kw["square_m"] = min(num("board_height") * unit / kw["rows"], num("board_width") * unit / kw["columns"])
        else:
            fail("missing: the square side (square_m, m)", "square_m")
    if "marker_m" in d:
        kw["marker_m"] = num("marker_m")
    elif kw["type"] == "charuco" and ("aruco_scale" in d or "square_size_override_cm" in d):
        kw["marker_m"] = round(kw["square_m"] * (num("aruco_scale") if "aruco_scale" in d else 0.75), 12)
    if "dictionary" in d:
        kw["dictionary"] = str(d["dictionary"])
    for k, src in (("inverted", "inverted"), ("legacy", "legacy"), ("legacy", "legacy_pattern")):
        if src in d:
            kw[k] = flag(src)
    if "mirrored" in d:
        m = d["mirrored"]
        if m == "auto":
            kw["mirrored"] = None
        elif isinstance(m, bool):
            kw["mirrored"] = m
        else:
            fail(f'must be "auto", true or false, got {m!r}', "mirrored")
    try:
        return Board(**kw)
    except InputError as exc:
        key = exc.field
        raise InputError(exc.reason, path, _key_line(text, key) if key else None, key) from None


def read_board(path: str | Path) -> Board:
    """Read a board TOML file (see the module doc); InputError naming the file, line and field."""
    p = Path(path)
    text = read_text(p, encoding="utf-8")
    try:
        d = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        raise InputError(f"not valid TOML ({' '.join(str(exc).split(' (at')[0].split())})", p,
                         int(m.group(1)) if m else None) from None
    except RecursionError:
        raise InputError("not valid TOML (nested too deeply)", p) from None
    toml_numbers_in_range(d, p, text)
    if "board" in d and isinstance(d["board"], dict):   # a [board] table is accepted too
        d = d["board"]
    return board_from_dict(d, p, text)


# ---------------------------------------------------------------------------------------------
# rasters (printing and rendering)
# ---------------------------------------------------------------------------------------------
def _coverage(lo: float, hi: float) -> tuple[int, np.ndarray]:
    """First texel index and the covered fraction of each texel of the interval [lo, hi) (texel units)."""
    i0, i1 = int(math.floor(lo)), int(math.ceil(hi))
    k = np.arange(i0, i1, dtype=float)
    return i0, np.clip(np.minimum(hi, k + 1) - np.maximum(lo, k), 0.0, 1.0)


def rectangles_raster(rects: np.ndarray, shape: tuple[int, int], texel_m: float,
                      origin_m: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Area-filtered raster (float32 (H,W), 1 = white, 0 = black) of black rectangles x0, y0, x1, y1 (m); texel
    (row i, col j) covers [ox + j t, ox + (j+1) t) x [oy + i t, oy + (i+1) t)."""
    h, w = shape
    grey = np.ones((h, w), np.float32)
    ox, oy = origin_m
    for x0, y0, x1, y1 in (np.asarray(rects, float) - [ox, oy, ox, oy]) / texel_m:
        j0, cx = _coverage(max(x0, 0.0), min(x1, w))
        i0, cy = _coverage(max(y0, 0.0), min(y1, h))
        if len(cx) and len(cy):
            grey[i0:i0 + len(cy), j0:j0 + len(cx)] -= np.outer(cy, cx).astype(np.float32)
    return np.clip(grey, 0.0, 1.0)


def board_texture(board: Board, texel_m: float, margin_m: float | None = None) -> tuple[np.ndarray, tuple]:
    """Anti-aliased texture of the printed board with a white paper margin (default one square): grey (H,W)
    float32 0..1 as printed (inversion applied to the board area) and the board-frame position (m) of the
    texture's top-left corner."""
    margin = board.square_m if margin_m is None else float(margin_m)
    bw, bh = board.size_m
    n_w, n_h = int(math.ceil((bw + 2 * margin) / texel_m - 1e-9)), int(math.ceil((bh + 2 * margin) / texel_m - 1e-9))
    origin = (-margin, -margin)
    grey = rectangles_raster(board.black_rectangles(), (n_h, n_w), texel_m, origin)
    if board.inverted:
        # black and white swapped over the board area: black coverage a - b with a the board's, b the marks'
        area = rectangles_raster(np.array([[0.0, 0.0, bw, bh]]), (n_h, n_w), texel_m, origin)  # 1 - a
        grey = np.clip(1.0 + area - grey, 0.0, 1.0).astype(np.float32)
    return grey, origin


# ---------------------------------------------------------------------------------------------
# field files
# ---------------------------------------------------------------------------------------------
BOARD_LAYOUT_KIND = "dgcal-board"


def write_board_field(field_csv: str | Path, board: Board) -> Points:
    """Write the board's field CSV `id,x,y,z` (board frame, m; ids = corner indices) and, beside it, its layout
    JSON (`field.json`, kind dgcal-board: `dgcal camera --field field.csv --images ...` then detects this board)."""
    pts = board.points()
    write_points(field_csv, pts)
    with atomic_write(Path(field_csv).with_suffix(".json")) as fh:
        json.dump({"kind": BOARD_LAYOUT_KIND, **board.to_dict()}, fh, indent=2)
    return pts


def load_board_layout(field_csv: str | Path) -> Board | None:
    """The board described beside a field CSV (`field.json` of kind dgcal-board), or None."""
    found = read_layout_json(field_csv, BOARD_LAYOUT_KIND)
    if found is None:
        return None
    d, p = found
    return board_from_dict({k: v for k, v in d.items() if k != "kind"}, p)
