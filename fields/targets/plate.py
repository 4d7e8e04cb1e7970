"""The rotating-plate target field: a ChArUco chessboard cut to a circular plate, optionally with raised blocks.

Geometry (see docs/target_field.md):
- The board is an N x N chessboard of `square_m` squares (N = ceil(diameter / square)); every white square
  holds an ArUco marker of `marker_m` from `dictionary` (OpenCV's CharucoBoard layout, marker ids 0, 1, ...
  row by row over the white squares). Only squares lying wholly on the circular plate are printed.
- Targets are the inner chessboard corners whose four neighbouring squares are all printed and at the same
  height. Target id ``C<rr><cc>``: row rr (from the top of the print) and column cc (from the left) of the
  inner corner, zero padded to two digits (three when the board has more than 101 squares a side).
  OpenCV's ChArUco corner number is ``rr * (N - 1) + cc``. Ids depend only on N, so they are stable.
- Plate frame: origin at the plate centre, x to the right and y to the top of the printed face, z out of
  the face (towards a camera looking at it). Board frame (OpenCV): origin at the board's top-left corner,
  x right, y down, metres.
- Non-planar fields: `blocks` raise rectangles of whole squares by a height (the print is glued on a
  block's top); a target's z is the height of its squares.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from dgcal.fields.errors import InputError
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.io.text_files import read_text
from dgcal.fields.io.formats import Points, write_points

DICTIONARIES = ("DICT_4X4_1000", "DICT_5X5_1000", "DICT_6X6_1000", "DICT_7X7_1000", "DICT_4X4_250",
                "DICT_5X5_250", "DICT_6X6_250", "DICT_7X7_250", "DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_36h11")


@dataclass(frozen=True)
class Block:
    """A raised block: squares [row0, row0+nrows) x [col0, col0+ncols) lifted by `height_m` (m)."""

    row0: int
    col0: int
    nrows: int
    ncols: int
    height_m: float


@dataclass
class TargetField:
    """A circular ChArUco plate: sizes in metres; `blocks` make it non-planar."""

    diameter_m: float = 2.4
    square_m: float = 0.08
    marker_m: float = 0.06
    dictionary: str = "DICT_5X5_1000"
    blocks: tuple[Block, ...] = field(default_factory=tuple)
    sigma_xy_m: float = 0.0002
    sigma_z_m: float = 0.0005
    legacy_pattern: bool = False

    def __post_init__(self):
        self.blocks = tuple(b if isinstance(b, Block) else Block(**b) for b in self.blocks)
        for name in ("diameter_m", "square_m", "marker_m", "sigma_xy_m", "sigma_z_m"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or abs(v) > 1000:
                raise InputError(f"{name} must be a finite number of metres (at most 1000), not {v!r}",
                                 field=name)
        if not (self.diameter_m > 0 and self.square_m > 0) or self.diameter_m / self.square_m > 2000:
            raise InputError(f"a plate of {self.diameter_m} m with {self.square_m} m squares is implausible "
                             "(more than 2000 squares across)", field="square_m")
        if not (self.diameter_m > 0 and self.square_m > 0 and 0 < self.marker_m < self.square_m):
            raise InputError(f"field sizes must satisfy 0 < marker ({self.marker_m}) < square ({self.square_m}) "
                             f"and diameter > 0 ({self.diameter_m})")
        if self.dictionary not in DICTIONARIES:
            raise InputError(f"unknown dictionary {self.dictionary!r}; use one of {', '.join(DICTIONARIES)}")
        need = (self.n_squares ** 2 + 1) // 2
        if need > self.dictionary_size():
            raise InputError(f"{self.dictionary} has {self.dictionary_size()} markers, the board needs {need}: "
                             "use larger squares or a 1000-marker dictionary")
        for b in self.blocks:
            if b.row0 < 0 or b.col0 < 0 or b.row0 + b.nrows > self.n_squares or b.col0 + b.ncols > self.n_squares:
                raise InputError(f"block {b} lies outside the {self.n_squares}x{self.n_squares} board")

    # --- sizes ---------------------------------------------------------------------------
    @property
    def n_squares(self) -> int:
        """Squares per side of the board (the plate's bounding square)."""
        return int(math.ceil(self.diameter_m / self.square_m - 1e-9))

    @property
    def board_size_m(self) -> float:
        return self.n_squares * self.square_m

    def dictionary_size(self) -> int:
        """Number of markers in the dictionary."""
        special = {"DICT_ARUCO_ORIGINAL": 1024, "DICT_APRILTAG_36h11": 587}
        return special.get(self.dictionary) or int(self.dictionary.rsplit("_", 1)[1])

    # --- cv2 objects ---------------------------------------------------------------------
    def cv_dictionary(self):
        """The OpenCV ArUco dictionary."""
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    def board(self):
        """The OpenCV CharucoBoard of the whole N x N square. Marker ids are compact: the printed markers
        (white squares wholly on the plate) get 0 .. P-1 row by row, the unprinted ones P and up, so a
        detector need only search the first P codes of the dictionary."""
        n = self.n_squares
        args = ((n, n), float(self.square_m), float(self.marker_m), self.cv_dictionary())
        b = cv2.aruco.CharucoBoard(*args)
        b.setLegacyPattern(bool(self.legacy_pattern))
        centre = np.array(b.getObjPoints(), float)[:, :, :2].mean(axis=1)
        rc = np.floor(centre[:, ::-1] / self.square_m).astype(int)
        printed = self.square_printed()[rc[:, 0], rc[:, 1]]
        ids = np.empty(len(printed), np.int32)
        ids[printed] = np.arange(printed.sum())
        ids[~printed] = printed.sum() + np.arange((~printed).sum())
        b = cv2.aruco.CharucoBoard(*args, ids)
        b.setLegacyPattern(bool(self.legacy_pattern))
        return b

    def n_printed_markers(self) -> int:
        """Number of markers on the plate (their ids are 0 .. P-1)."""
        _, _, printed = self.markers()
        return int(printed.sum())

    def detection_dictionary(self):
        """The dictionary cut to the printed markers' codes (ArUco identification time grows with its size)."""
        d = self.cv_dictionary()
        p = self.n_printed_markers()
        return cv2.aruco.Dictionary(d.bytesList[:p].copy(), d.markerSize, d.maxCorrectionBits)

    # --- layout ----------------------------------------------------------------------------
    def square_printed(self) -> np.ndarray:
        """(N,N) bool: squares lying wholly on the plate (row from the top, column from the left)."""
        n, s = self.n_squares, self.square_m
        edges = np.arange(n + 1) * s - self.board_size_m / 2
        r2 = self.diameter_m ** 2 / 4
        far = np.maximum(edges[:-1] ** 2, edges[1:] ** 2)  # farthest edge coordinate of each square
        return (far[:, None] + far[None, :]) <= r2 + 1e-12

    def square_height(self) -> np.ndarray:
        """(N,N) height (m) of each square above the plate."""
        h = np.zeros((self.n_squares, self.n_squares))
        for b in self.blocks:
            h[b.row0:b.row0 + b.nrows, b.col0:b.col0 + b.ncols] = b.height_m
        return h

    def markers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All board markers: ids (M,), corners (M,4,2) in the board frame (m), printed flag (M,)."""
        b = self.board()
        ids = np.asarray(b.getIds()).ravel().astype(int)
        corners = np.array(b.getObjPoints(), float)[:, :, :2]
        centre = corners.mean(axis=1)
        rc = np.floor(centre[:, ::-1] / self.square_m).astype(int)
        printed = self.square_printed()[rc[:, 0], rc[:, 1]]
        return ids, corners, printed

    def black_squares(self) -> np.ndarray:
        """(N,N) bool: chessboard squares that are black (the others hold markers)."""
        _, corners, _ = self.markers()
        rc = np.floor(corners.mean(axis=1)[:, ::-1] / self.square_m).astype(int)
        black = np.ones((self.n_squares, self.n_squares), bool)
        black[rc[:, 0], rc[:, 1]] = False
        return black

    def corner_id(self, row, col) -> np.ndarray:
        """String target ids of inner corners (row, col)."""
        w = 2 if self.n_squares <= 101 else 3
        return np.array([f"C{int(r):0{w}d}{int(c):0{w}d}" for r, c in zip(np.atleast_1d(row), np.atleast_1d(col))],
                        dtype=object)

    def targets(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Target corners: string ids (K,), OpenCV ChArUco corner numbers (K,), plate-frame xyz (K,3) m."""
        n = self.n_squares
        pr, h = self.square_printed(), self.square_height()
        r, c = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
        quad_p = pr[:-1, :-1] & pr[:-1, 1:] & pr[1:, :-1] & pr[1:, 1:]
        quad_h = (h[:-1, :-1] == h[:-1, 1:]) & (h[:-1, :-1] == h[1:, :-1]) & (h[:-1, :-1] == h[1:, 1:])
        ok = quad_p & quad_h
        r, c = r[ok], c[ok]
        xy_board = np.column_stack([(c + 1) * self.square_m, (r + 1) * self.square_m])
        xyz = np.column_stack([self.board_to_plate(xy_board), h[r, c]])
        return self.corner_id(r, c), (r * (n - 1) + c).astype(int), xyz

    def board_to_plate(self, xy_board: np.ndarray) -> np.ndarray:
        """Plate-frame xy (m) of board-frame xy (m): origin at the centre, y flipped to point up."""
        xy = np.asarray(xy_board, float)
        half = self.board_size_m / 2
        return np.stack([xy[..., 0] - half, half - xy[..., 1]], axis=-1)

    def points(self) -> Points:
        """The targets as a Points table (plate frame, m) with the field's sigmas."""
        ids, _, xyz = self.targets()
        sig = np.tile([self.sigma_xy_m, self.sigma_xy_m, self.sigma_z_m], (len(ids), 1))
        return Points(ids, xyz, sig, np.full(len(ids), "control", dtype=object))

    # --- persistence -----------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = asdict(self)
        d["blocks"] = [asdict(b) for b in self.blocks]
        d["kind"] = "dgcal-charuco-plate"
        return d

    @classmethod
    def from_dict(cls, d: dict, path: str | Path | None = None) -> "TargetField":
        """A field from its JSON description (as written by `to_dict`)."""
        keys = {f for f in cls.__dataclass_fields__}
        try:
            return cls(**{k: v for k, v in d.items() if k in keys})
        except InputError as exc:
            raise InputError(f"bad field layout: {exc.reason}", path, field=exc.field) from None
        except (TypeError, ValueError) as exc:
            raise InputError(f"bad field layout: {exc}", path) from None


def nonplanar_field(**kw) -> TargetField:
    """The default plate with four raised blocks (0.10 m and 0.20 m) for self-calibration with depth."""
    base = TargetField(**kw)
    n = base.n_squares
    a, w = n // 5, max(2, n // 5)
    b = n - a - w
    blocks = (Block(a, a, w, w, 0.10), Block(a, b, w, w, 0.20), Block(b, a, w, w, 0.20), Block(b, b, w, w, 0.10))
    return TargetField(**{**kw, "blocks": blocks})


@dataclass
class FieldOptions:
    """The printable plate of `dgcal field`: diameter, chessboard square and ArUco marker side (m), OpenCV
    dictionary, raised blocks, and the target sigmas in and across the plate plane (m)."""

    diameter_m: float = 2.4
    square_m: float = 0.08
    marker_m: float = 0.06
    dictionary: str = "DICT_5X5_1000"
    nonplanar: bool = False          # four raised blocks (0.10 m and 0.20 m)
    sigma_xy_m: float = 0.0002
    sigma_z_m: float = 0.0005


def make_target_field(opts: FieldOptions) -> TargetField:
    """The target field (plate layout) of `opts`; InputError on an impossible layout."""
    kw = dict(diameter_m=opts.diameter_m, square_m=opts.square_m, marker_m=opts.marker_m,
              dictionary=opts.dictionary, sigma_xy_m=opts.sigma_xy_m, sigma_z_m=opts.sigma_z_m)
    return nonplanar_field(**kw) if opts.nonplanar else TargetField(**kw)


def layout_path(field_csv: str | Path) -> Path:
    """The layout JSON written beside a field CSV (`field.csv` -> `field.json`)."""
    p = Path(field_csv)
    return p.with_suffix(".json")


def write_field(field_csv: str | Path, tf: TargetField) -> Points:
    """Write the field CSV `id,x,y,z,sx,sy,sz` (plate frame, m) and its layout JSON beside it."""
    pts = tf.points()
    write_points(field_csv, pts)
    with atomic_write(layout_path(field_csv)) as fh:
        json.dump(tf.to_dict(), fh, indent=2)
    return pts


def read_layout_json(field_csv: str | Path, kind: str) -> tuple[dict, Path] | None:
    """The layout JSON beside a field CSV and its path when its `kind` is `kind`, else None (no file, another
    kind); a file that is not JSON is an InputError naming it."""
    p = layout_path(field_csv)
    if not p.is_file():
        return None
    try:
        d = json.loads(read_text(p))
    except (ValueError, RecursionError) as exc:
        raise InputError(f"cannot read field layout: {' '.join(str(exc).split())[:120]}", p) from None
    if not isinstance(d, dict) or d.get("kind") != kind:
        return None
    return d, p


def load_layout(field_csv: str | Path) -> TargetField | None:
    """The field layout stored beside a field CSV, or None when there is none."""
    found = read_layout_json(field_csv, "dgcal-charuco-plate")
    return None if found is None else TargetField.from_dict(*found)
