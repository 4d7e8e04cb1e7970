"""The plate's marks as geometry (black rectangles in the board frame) and as an anti-aliased texture for rendering
simulated photos: NumPy and OpenCV's marker bits only, so the simulator need not load matplotlib (printing, which
draws the same rectangles, does)."""
from __future__ import annotations

import math

import cv2
import numpy as np

from dgcal.fields.targets.plate import TargetField


def marker_cells(tf: TargetField, marker_id: int) -> np.ndarray:
    """(B,B) bool: black cells of a marker including its one-cell black border, row 0 at the marker's top."""
    nbits = tf.cv_dictionary().markerSize
    img = cv2.aruco.generateImageMarker(tf.cv_dictionary(), int(marker_id), nbits + 2, borderBits=1)
    return img < 128


def black_rectangles(tf: TargetField, rows: slice | None = None, cols: slice | None = None) -> np.ndarray:
    """(K,4) black rectangles x0, y0, x1, y1 in the board frame (m, y down) of the printed plate.

    Runs of black marker cells along a row are merged, so a vector print has few seams."""
    black = tf.black_squares() & tf.square_printed()
    n, s = tf.n_squares, tf.square_m
    sel = np.zeros((n, n), bool)
    sel[rows if rows is not None else slice(None), cols if cols is not None else slice(None)] = True
    rects = []
    r, c = np.nonzero(black & sel)
    rects += [np.column_stack([c * s, r * s, (c + 1) * s, (r + 1) * s])]
    ids, corners, printed = tf.markers()
    for mid, cor, pr in zip(ids, corners, printed):
        x0, y0 = cor.min(axis=0)
        x1, y1 = cor.max(axis=0)
        rc = (int((y0 + y1) / 2 // s), int((x0 + x1) / 2 // s))
        if not pr or not sel[rc]:
            continue
        cells = marker_cells(tf, mid)
        nb = cells.shape[0]
        cw = (x1 - x0) / nb
        for i in range(nb):
            row = np.concatenate([[False], cells[i], [False]]).astype(int)
            d = np.diff(row)
            starts, ends = np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]
            for a, b in zip(starts, ends):
                rects.append(np.array([[x0 + a * cw, y0 + i * cw, x0 + b * cw, y0 + (i + 1) * cw]]))
    return np.concatenate(rects, axis=0) if rects else np.zeros((0, 4))


def _coverage(lo: float, hi: float) -> tuple[int, np.ndarray]:
    """First texel index and the covered fraction of each texel of the interval [lo, hi) (texel units)."""
    i0, i1 = int(math.floor(lo)), int(math.ceil(hi))
    k = np.arange(i0, i1, dtype=float)
    return i0, np.clip(np.minimum(hi, k + 1) - np.maximum(lo, k), 0.0, 1.0)


def field_texture(tf: TargetField, texel_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Anti-aliased plate texture over the board square: (grey, alpha) float32 (H,W), grey 1 = white,
    alpha = plate-disk coverage. Texel (row i, col j) covers board [j t, (j+1) t) x [i t, (i+1) t) (m)."""
    n_px = int(math.ceil(tf.board_size_m / texel_m - 1e-9))
    grey = np.ones((n_px, n_px), np.float32)
    for x0, y0, x1, y1 in black_rectangles(tf) / texel_m:
        j0, cx = _coverage(x0, x1)
        i0, cy = _coverage(y0, y1)
        grey[i0:i0 + len(cy), j0:j0 + len(cx)] -= np.outer(cy, cx).astype(np.float32)
    np.clip(grey, 0.0, 1.0, out=grey)
    c = (((np.arange(n_px) + 0.5) * texel_m - tf.board_size_m / 2) / texel_m).astype(np.float32)
    alpha = np.float32(0.5 + tf.diameter_m / 2 / texel_m) - np.hypot(c[:, None], c[None, :])
    np.clip(alpha, 0.0, 1.0, out=alpha)
    return grey, alpha
