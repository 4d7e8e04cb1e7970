"""Find the corners of a standard board (dgcal.fields.targets.boards) in a grey image with OpenCV.

- charuco: `cv2.aruco.CharucoDetector` (markers, then chessboard corners interpolated and refined by OpenCV's own
  cornerSubPix step); corner ids are OpenCV's ChArUco corner ids.
- chessboard: `cv2.findChessboardCornersSB` (exhaustive search when the quick one fails; the whole board must be
  in view), corners refined by cornerSubPix in a window of 0.35 of the distance to the nearest grid neighbour (0.03
  px RMS on rendered images against 0.06 px for SB's own accuracy mode, at a fifth of its time); ids in its
  row-major order, turned so that the board's top-left square is the black one
  when columns + rows is odd (otherwise the board is symmetric under a half turn and so are its ids: a fixed flat
  board is unaffected).
- aruco-grid: `cv2.aruco.ArucoDetector` (markers found with cornerSubPix corners), missed markers recovered by
  `refineDetectedMarkers` against the board; then every marker corner is re-located as the intersection of
  straight lines fitted to its two sides (sub-pixel edge points at the half-way grey level along each side's
  normal): a marker corner is an L-junction, which cornerSubPix pulls inwards under blur (0.25 px RMS on rendered
  images, 0.05 px after the edge fit). Ids 4 * marker index + corner.

The ArUco dictionary is cut to the board's own codes (no other marker can be reported). A print with black and
white swapped (`inverted`) is detected in 255 - image. A view of the board's back face (a mirror image: markers
do not decode) is recognised without an option: when the image shows fewer than half the board's markers, the
horizontally flipped image is searched as well and the better of the two kept, its x coordinates mapped back
(x = W - 1 - x'), so the corner ids are the physical corners' either way.

Pixels: OpenCV convention (x right, y down, origin at the centre of the top-left pixel). Sigmas are not
estimated (NaN: equal weights, the adjustment's sigma0 gives the noise level), as in OpenCV's calibrateCamera.
"""
from __future__ import annotations

import cv2
import numpy as np

from dgcal.calib.selfcal.detection import Detection
from dgcal.fields.targets.boards import Board

SB_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE
CHESS_WINDOW = 0.35        # cornerSubPix half-window / distance to the nearest grid neighbour (chessboard corners)
EDGE_SAMPLES = 14          # edge points per marker side (between 15 % and 85 % of the side)
MIN_CELL_PX = 4.0          # ArUco-grid markers whose cells are narrower (along any side) give no precise corners
MAX_EDGE_SCATTER_PX = 0.15  # RMS distance of a side's edge points from their line beyond which the side is not used


class BoardDetector:
    """Detector for one Board; reusable across images (holds the OpenCV objects)."""

    def __init__(self, board: Board, keep_ids: set | None = None):
        self.board = board
        self.keep_ids = keep_ids
        self.n_markers = board.n_markers
        if board.type == "chessboard":
            return
        full = board.cv_dictionary()
        lo = board.first_id
        # the dictionary cut to the board's codes: ids 0 .. n-1 here are first_id .. first_id + n - 1
        self.dictionary = cv2.aruco.Dictionary(full.bytesList[lo:lo + self.n_markers].copy(), full.markerSize,
                                               full.maxCorrectionBits)
        ids = np.arange(self.n_markers, dtype=np.int32)
        dp = cv2.aruco.DetectorParameters()
        if board.type == "charuco":
            self.cv_board = cv2.aruco.CharucoBoard((board.columns, board.rows), float(board.square_m),
                                                   float(board.marker_m), self.dictionary, ids)
            self.cv_board.setLegacyPattern(bool(board.legacy))
            self.charuco = cv2.aruco.CharucoDetector(self.cv_board, cv2.aruco.CharucoParameters(), dp)
        else:
            dp.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
            self.cv_board = cv2.aruco.GridBoard((board.columns, board.rows), float(board.marker_m),
                                                float(board.square_m - board.marker_m), self.dictionary, ids)
            self.aruco = cv2.aruco.ArucoDetector(self.dictionary, dp)

    # --- one face --------------------------------------------------------------------------------
    def _face(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """(corner indices (K,), pixels (K,2), markers found) in one image as given (no flip)."""
        b = self.board
        none = (np.zeros(0, int), np.zeros((0, 2)), 0)
        if b.type == "chessboard":
            ok, c = cv2.findChessboardCornersSB(img, b.pattern_size, flags=SB_FLAGS)
            if not ok or c is None:
                ok, c = cv2.findChessboardCornersSB(img, b.pattern_size, flags=SB_FLAGS | cv2.CALIB_CB_EXHAUSTIVE)
            if not ok or c is None:
                return none
            xy = self._orient_chessboard(img, c.reshape(-1, 2).astype(float))
            return np.arange(b.n_corners), refine_chessboard_corners(img, xy, b.pattern_size), 0
        if b.type == "charuco":
            cc, cids, _, mids = self.charuco.detectBoard(img)
            n_mk = 0 if mids is None else len(mids)
            if cids is None or len(cids) == 0:
                return none[0], none[1], n_mk
            return cids.ravel().astype(int), cc.reshape(-1, 2).astype(float), n_mk
        corners, mids, rejected = self.aruco.detectMarkers(img)
        if mids is not None and len(mids):
            corners, mids, _, _ = self.aruco.refineDetectedMarkers(img, self.cv_board, corners, mids, rejected)
        if mids is None or len(mids) == 0:
            return none
        mids = mids.ravel().astype(int)
        uniq, cnt = np.unique(mids, return_counts=True)
        keep = ~np.isin(mids, uniq[cnt > 1])  # a code seen twice is ambiguous: both dropped
        idx = (4 * mids[keep][:, None] + np.arange(4)).ravel()
        if not keep.any():
            return none
        quads = np.array([c.reshape(4, 2) for c, k in zip(corners, keep) if k], float)
        cells = self.dictionary.markerSize + 2
        # markers too small or too oblique for precise corners: a cell narrower than MIN_CELL_PX along a side
        big = np.linalg.norm(quads - np.roll(quads, -1, axis=1), axis=2).min(axis=1) / cells >= MIN_CELL_PX
        refined = refine_marker_corners(img, quads[big], cells, (b.square_m - b.marker_m) / b.marker_m)
        idx = idx.reshape(-1, 4)[big].ravel()
        return idx, refined.reshape(-1, 2), int(big.sum())

    def _orient_chessboard(self, img: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """Corners in the board's own order: reversed (a half turn) when the square at the top-left of corner 0
        is not the black one (only decidable when columns + rows is odd)."""
        b = self.board
        if (b.columns + b.rows) % 2 == 0:
            return xy
        nx = b.columns - 1
        c0, c1, c2 = xy[0], xy[1], xy[nx]
        p = c0 - 0.5 * (c1 - c0) - 0.5 * (c2 - c0)          # centre of the square up-left of corner 0
        q = c0 + 0.5 * (c1 - c0) - 0.5 * (c2 - c0)          # its neighbour to the right (the other colour)
        v = cv2.getRectSubPix(img, (3, 3), (float(p[0]), float(p[1]))).mean()
        w = cv2.getRectSubPix(img, (3, 3), (float(q[0]), float(q[1]))).mean()
        return xy if v < w else xy[::-1].copy()

    # --- public ------------------------------------------------------------------------------------
    def detect(self, gray: np.ndarray) -> Detection:
        """Corners of the board in a grey image (uint8), front or back face."""
        img = 255 - gray if self.board.inverted else gray
        h, w = img.shape[:2]
        stats = {"size": [int(w), int(h)], "markers": 0, "corners": 0, "mirrored": False, "not_in_field": 0}
        mode = self.board.mirrored
        best = self._face(img) if mode is not True else (np.zeros(0, int), np.zeros((0, 2)), 0)
        mirrored = False
        if mode is not False and self.board.type != "chessboard" and best[2] < max(2, (self.n_markers + 1) // 2):
            # a mirror image of the board (its back face): markers decode only in the flipped image
            ids_f, xy_f, n_f = self._face(np.ascontiguousarray(img[:, ::-1]))
            if len(ids_f) > len(best[0]) or (mode is True):
                xy_f = xy_f.copy()
                xy_f[:, 0] = (w - 1) - xy_f[:, 0]
                best, mirrored = (ids_f, xy_f, n_f), True
        ids, xy, n_mk = best
        ok = np.isfinite(xy).all(axis=1)
        ids, xy = ids[ok], xy[ok]
        sid = np.array([str(int(k)) for k in ids], dtype=object)
        if self.keep_ids is not None:
            known = np.array([k in self.keep_ids for k in sid], bool)
            stats["not_in_field"] = int((~known).sum())
            sid, xy = sid[known], xy[known]
        stats.update(markers=int(n_mk), corners=int(len(sid)), mirrored=bool(mirrored and len(sid) > 0))
        return Detection(sid, xy, np.full((len(sid), 2), np.nan), stats)

    def detect_inverted_polarity(self, gray: np.ndarray) -> int:
        """Corners found when the print polarity is taken the other way round (diagnosing a wrong `inverted`)."""
        img = gray if self.board.inverted else 255 - gray
        n = len(self._face(img)[0])
        if self.board.type != "chessboard":
            n = max(n, len(self._face(np.ascontiguousarray(img[:, ::-1]))[0]))
        return n


def refine_marker_corners(img: np.ndarray, quads: np.ndarray, cells: int, gap_ratio: float) -> np.ndarray:
    """Marker corners (n,4,2) re-located as intersections of lines fitted to the markers' sides: along each side,
    EDGE_SAMPLES points where the grey profile across the side crosses half-way between its dark and light ends
    (profiles from the middle of the black border cell to the middle of the white beyond: +-0.5 of the smaller of
    a cell and the white gap). `cells` = marker cells
    across including the border, `gap_ratio` = white gap / marker side. A corner whose sides are not clean straight
    edges (points scattered by more than MAX_EDGE_SCATTER_PX) or whose fit lands far from the input is NaN."""
    n = len(quads)
    if n == 0:
        return np.zeros((0, 4, 2))
    g = img.astype(np.float32)
    a, b = quads, np.roll(quads, -1, axis=1)                     # side j runs from corner j to corner j+1
    side = b - a
    length = np.linalg.norm(side, axis=2)                        # (n,4) px
    e = side / np.maximum(length, 1e-9)[..., None]
    centre = quads.mean(axis=1, keepdims=True)
    nrm = np.stack([e[..., 1], -e[..., 0]], axis=-1)
    mid = 0.5 * (a + b)
    flip = np.sum((mid - centre) * nrm, axis=2) < 0               # make the normal point outwards
    nrm[flip] *= -1
    cell = length / cells
    # the profile runs from the middle of the marker's black border cell to the middle of the white beyond it
    half = 0.5 * np.minimum(cell, np.maximum(gap_ratio, 0.05) * length)   # (n,4) px
    s = np.linspace(0.15, 0.85, EDGE_SAMPLES)
    m = 25
    d = np.linspace(-1.0, 1.0, m)
    # sample positions (n,4,S,m,2)
    base = a[:, :, None, :] + s[None, None, :, None] * side[:, :, None, :]
    off = (half[:, :, None, None] * d[None, None, None, :])[..., None] * nrm[:, :, None, None, :]
    pts = base[:, :, :, None, :] + off
    flat = pts.reshape(-1, 2).astype(np.float32)
    cols = 4 * EDGE_SAMPLES * m                                   # one row per marker keeps remap's maps small
    prof = cv2.remap(g, flat[:, 0].reshape(n, cols), flat[:, 1].reshape(n, cols), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).reshape(n, 4, EDGE_SAMPLES, m)
    lo = prof[..., :2].mean(axis=-1)
    hi = prof[..., -2:].mean(axis=-1)
    thr = 0.5 * (lo + hi)
    sign = np.sign(hi - lo)[..., None]
    above = (prof - thr[..., None]) * sign > 0                    # inside -> outside: dark (or light) -> other
    k = np.argmax(above, axis=-1)                                 # first sample past the half-way level
    valid = (k > 0) & above.any(axis=-1) & (np.abs(hi - lo) > 10)
    kk = np.clip(k, 1, m - 1)
    p0 = np.take_along_axis(prof, (kk - 1)[..., None], axis=-1)[..., 0]
    p1 = np.take_along_axis(prof, kk[..., None], axis=-1)[..., 0]
    frac = np.clip((thr - p0) / np.where(np.abs(p1 - p0) > 1e-6, p1 - p0, 1e-6), 0, 1)
    t = d[kk - 1] + frac * (d[1] - d[0])                          # (n,4,S) in half-window units
    edge = base + (t * half[:, :, None])[..., None] * nrm[:, :, None, :]
    out = np.full_like(quads, np.nan)
    lines = np.full((n, 4, 3), np.nan)
    for i in range(n):
        for j in range(4):
            ok = valid[i, j]
            if ok.sum() < 6:
                continue
            P = edge[i, j, ok]
            c = P.mean(axis=0)
            _, sv, vt = np.linalg.svd(P - c, full_matrices=False)
            if sv[1] / np.sqrt(len(P)) > MAX_EDGE_SCATTER_PX:   # not a straight, clean edge (occluded, cut, blurred)
                continue
            nv = vt[1]
            lines[i, j] = [nv[0], nv[1], -nv @ c]
    for j in range(4):
        # corner j is where side j-1 (ending at j) meets side j (starting at j)
        L1, L2 = lines[:, (j - 1) % 4], lines[:, j]
        X = np.cross(L1, L2)
        good = np.isfinite(X).all(axis=1) & (np.abs(X[:, 2]) > 1e-12)
        P = X[good, :2] / X[good, 2:3]
        near = np.linalg.norm(P - quads[good, j], axis=1) < np.maximum(1.0, 0.5 * half[good, j])
        idx = np.flatnonzero(good)[near]
        out[idx, j] = P[near]
    return out

def refine_chessboard_corners(img: np.ndarray, xy: np.ndarray, pattern: tuple[int, int]) -> np.ndarray:
    """Chessboard corners (K,2) in row-major grid order refined by cornerSubPix, each in a half-window of
    CHESS_WINDOW x the distance to its nearest grid neighbour (2 to 30 px)."""
    nx, ny = pattern
    g = xy.reshape(ny, nx, 2)
    big = np.full((ny, nx), np.inf)
    near = big.copy()
    dx = np.linalg.norm(np.diff(g, axis=1), axis=2)
    dy = np.linalg.norm(np.diff(g, axis=0), axis=2)
    for arr, sl_a, sl_b in ((dx, (slice(None), slice(0, -1)), (slice(None), slice(1, None))),
                            (dy, (slice(0, -1), slice(None)), (slice(1, None), slice(None)))):
        near[sl_a] = np.minimum(near[sl_a], arr)
        near[sl_b] = np.minimum(near[sl_b], arr)
    half = np.clip(np.floor(CHESS_WINDOW * near.ravel()), 2, 30).astype(int)
    h, w = img.shape[:2]
    out = xy.copy()
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    inside = (xy[:, 0] - half - 1 >= 0) & (xy[:, 0] + half + 1 <= w - 1) & (xy[:, 1] - half - 1 >= 0) \
        & (xy[:, 1] + half + 1 <= h - 1)
    for hw in np.unique(half):
        idx = np.flatnonzero((half == hw) & inside)
        if len(idx):
            pts = xy[idx].astype(np.float32).reshape(-1, 1, 2)
            out[idx] = cv2.cornerSubPix(img, pts, (int(hw), int(hw)), (-1, -1), crit).reshape(-1, 2)
    return out
