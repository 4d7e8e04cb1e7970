"""Find the coded targets of a ChArUco plate in photos: ids and sub-pixel corners with honest sigmas.

Per image: ArUco markers (OpenCV ArucoDetector) -> markers whose id occurs twice are dropped (ambiguous)
-> ChArUco corners interpolated from the two adjacent markers (CharucoDetector, local homography, both
markers required) -> corners re-refined with cv2.cornerSubPix in a window of 0.2 square (only the symmetric
X-junction and the markers' black borders inside it) -> rejected when the window touches the image border or
when the corner disagrees with the homography of its detected grid neighbours (or, lacking those, of its two
markers). Sigma per corner: first-order propagation of the image noise (estimated per image) through the
cornerSubPix equations, times an empirical factor from simulations (docs/target_field.md).

Pixels: OpenCV convention (x right, y down, origin at the centre of the top-left pixel). Images are read
as stored (EXIF orientation ignored), so the measurements refer to the stored raster.
"""
from __future__ import annotations

import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import Measurements, read_points
from dgcal.fields.io.image_folders import list_image_files
from dgcal.fields.targets.plate import TargetField, load_layout

# sigma = hypot(SIGMA_FACTOR * propagated noise sigma, SIGMA_FLOOR_PX * max(1, 4 / half-window)^2), fitted to rendered
# images (JPEG q95, blur 0.8 px, noise 2 and 5 DN; 1200x800 and 3000x2000): the factor covers JPEG and correlated
# gradient noise, the floor the remaining model error (sampling, perspective within the window)
SIGMA_FACTOR = 1.9
SIGMA_FLOOR_PX = 0.025
SMALL_WINDOW_PX = 4  # below this half-window the floor grows as (4 / half)^2: 0.1 px at 2, 0.044 px at 3
# half-size of the cornerSubPix window in squares: only the X-junction and the white gap (0.125) around it;
# a window reaching the corners of the markers' black borders can slide towards them (seen in simulations)
WINDOW_SQUARES = 0.12
MIN_HALF_WINDOW = 2
MIN_GAP_PX = 2.5
MARKER_IMAGE_PX = 3000  # markers are searched on a copy at most this large (speed); corners use full resolution


@dataclass
class Detection:
    """Targets found in one image: string ids (K,), pixels (K,2), sigmas (K,2) px, and counts."""

    ids: np.ndarray
    xy: np.ndarray
    sigma: np.ndarray
    stats: dict
    window_px: np.ndarray | None = None  # half-size of each corner's cornerSubPix window (px)
    square_px: np.ndarray | None = None  # local size of a square (px, geometric mean of the two axes)


def read_gray(path: str | Path) -> np.ndarray:
    """8-bit grey image as stored (EXIF orientation ignored); InputError naming the file if unreadable."""
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
    if img is None or img.size == 0:
        raise InputError("cannot read the image (missing, corrupt or not an image)", path)
    return img


def resolve_field(field: TargetField | str | Path) -> tuple[TargetField, set | None, str]:
    """The field layout, the ids of the field CSV (None: all targets) and where the layout came from."""
    if isinstance(field, TargetField):
        return field, None, "given"
    pts = read_points(field)
    tf = load_layout(field)
    source = str(Path(field).with_suffix(".json"))
    if tf is None:
        tf, source = TargetField(), "default layout (no field.json beside the field CSV)"
        print(f"warning: {source}; assuming the default dgcal plate", file=sys.stderr)
    return tf, set(str(i) for i in pts.ids), source


def estimate_noise(img: np.ndarray) -> float:
    """Robust image noise sigma (DN): median absolute Laplacian-type response (edges are a minority)."""
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    # bands of 34 rows spread over the image, about 1 MP in all (enough for a median, fast on 20 MP)
    h = img.shape[0]
    step = max(34, int(34 * img.size / 1e6))
    bands = [img[r:r + 34] for r in range(0, max(1, h - 33), step)]
    r = np.concatenate([cv2.filter2D(b.astype(np.float32), -1, k)[1:-1, 1:-1].ravel() for b in bands])
    a = np.rint(np.abs(r)).astype(np.int64)
    # median of the integer responses, interpolated within its bin (a plain median moves in whole steps)
    cdf = np.cumsum(np.bincount(a)) / a.size
    m = int(np.searchsorted(cdf, 0.5))
    below = cdf[m - 1] if m > 0 else 0.0
    med = max(m - 0.5, 0.0) + (0.5 - below) / max(cdf[m] - below, 1e-12) * (1.0 if m > 0 else 0.5)
    return float(1.4826 * med / 6.0)


class CharucoFieldDetector:
    """Detector for one TargetField; reusable across images (holds the OpenCV objects)."""

    def __init__(self, tf: TargetField, keep_ids: set | None = None):
        self.tf = tf
        self.board = tf.board()
        dp = cv2.aruco.DetectorParameters()
        dp.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
        self.aruco = cv2.aruco.ArucoDetector(tf.detection_dictionary(), dp)
        cp = cv2.aruco.CharucoParameters()
        cp.minMarkers = 2
        cp.checkMarkers = False  # its global board check rejects raised blocks; corners are checked locally below
        self.charuco = cv2.aruco.CharucoDetector(self.board, cp, dp)
        ids, num, xyz = tf.targets()
        self.target_of_corner = {int(n): str(i) for n, i in zip(num, ids)}
        self.keep_ids = keep_ids
        mids, mcorners, printed = tf.markers()
        self.printed_markers = set(int(m) for m in mids[printed])
        self.marker_board_corners = {int(m): c for m, c in zip(mids, mcorners)}
        n = tf.n_squares - 1
        self.corner_board_xy = {k: np.array([(k % n + 1) * tf.square_m, (k // n + 1) * tf.square_m])
                                for k in self.target_of_corner}
        rc = np.floor(mcorners.mean(axis=1)[:, ::-1] / tf.square_m).astype(int)
        marker_at = {(int(r), int(c)): int(m) for (r, c), m in zip(rc, mids)}
        # the markers in the white squares touching each corner (corner (r, c) joins squares r..r+1, c..c+1)
        self.adjacent = {k: [marker_at[q] for q in ((k // n + a, k % n + b) for a in (0, 1) for b in (0, 1))
                             if q in marker_at] for k in self.target_of_corner}

    def _markers(self, img: np.ndarray):
        """ArUco markers, found on a copy reduced to at most MARKER_IMAGE_PX a side (identification needs no
        more; the ChArUco corners are refined on the full image), corners in full-image pixels."""
        scale = min(1.0, MARKER_IMAGE_PX / max(img.shape[:2]))
        if scale > 0.9:
            mcorners, mids, _ = self.aruco.detectMarkers(img)
            return mcorners, mids
        small = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        sx, sy = small.shape[1] / img.shape[1], small.shape[0] / img.shape[0]
        mcorners, mids, _ = self.aruco.detectMarkers(small)
        # pixel centres: x_full = (x_small + 0.5) / s - 0.5
        mcorners = tuple(((c.reshape(4, 2) + 0.5) / [sx, sy] - 0.5).reshape(1, 4, 2).astype(np.float32)
                         for c in mcorners)
        return mcorners, mids

    def detect(self, img: np.ndarray) -> Detection:
        """Targets in a grey image (uint8)."""
        h, w = img.shape[:2]
        stats = {"size": [int(w), int(h)], "markers": 0, "corners": 0, "rejected_duplicate_marker": 0,
                 "rejected_border": 0, "rejected_small": 0, "rejected_homography": 0, "not_in_field": 0}
        empty = Detection(np.zeros(0, object), np.zeros((0, 2)), np.zeros((0, 2)), stats)
        mcorners, mids = self._markers(img)
        if mids is None or len(mids) == 0:
            return empty
        mids = mids.ravel().astype(int)
        uniq, counts = np.unique(mids, return_counts=True)
        dup = set(uniq[counts > 1].tolist())
        keep = [i for i, m in enumerate(mids) if m not in dup and m in self.printed_markers]
        stats["rejected_duplicate_marker"] = int(sum(counts[counts > 1]))
        stats["markers"] = len(keep)
        if len(keep) < 2:
            return empty
        mc = tuple(mcorners[i] for i in keep)
        mi = mids[keep].reshape(-1, 1).astype(np.int32)
        cc, cids, _, _ = self.charuco.detectBoard(img, markerCorners=mc, markerIds=mi)
        if cids is None or len(cids) == 0:
            return empty
        cids = cids.ravel().astype(int)
        cc = cc.reshape(-1, 2).astype(float)
        sel = np.array([k in self.target_of_corner for k in cids], bool)
        stats["not_in_field"] = int((~sel).sum())
        cids, cc = cids[sel], cc[sel]
        marker_img = {int(mids[i]): mcorners[i].reshape(4, 2).astype(float) for i in keep}

        # local board->image homography from the adjacent markers: square size and refinement window
        H_mk = []
        for k in cids:
            ms = [m for m in self.adjacent[int(k)] if m in marker_img]
            H_mk.append(fit_homography(np.concatenate([self.marker_board_corners[m] for m in ms]),
                                       np.concatenate([marker_img[m] for m in ms])) if ms else None)
        keep_h = np.array([H is not None for H in H_mk], bool)
        cids, cc = cids[keep_h], cc[keep_h]
        H_mk = [H for H in H_mk if H is not None]
        if len(cids) == 0:
            return empty
        A = np.array([homography_jacobian(H, self.corner_board_xy[int(k)]) for H, k in zip(H_mk, cids)])
        sv = np.linalg.svd(A, compute_uv=False)
        sq_px = np.sqrt(sv[:, 0] * sv[:, 1]) * self.tf.square_m
        # the axis-aligned window must stay within +-WINDOW_SQUARES of a square around the corner (there the
        # pattern is point-symmetric: X-junction and the markers' black borders), whatever the perspective
        A_inv_norm = np.abs(np.linalg.inv(A)).sum(axis=2).max(axis=1)
        half = np.minimum(np.floor(WINDOW_SQUARES * self.tf.square_m / A_inv_norm), 60).astype(int)
        # too small or too oblique for a precise corner: tiny window, or a white gap between the square
        # and the marker border so thin that cornerSubPix can slide onto the marker's corner
        gap_px = sv[:, 1] * (self.tf.square_m - self.tf.marker_m) / 2
        small = (half < MIN_HALF_WINDOW) | (gap_px < MIN_GAP_PX)
        stats["rejected_small"] = int(small.sum())
        inside = ~small & ((cc[:, 0] - half - 2 >= 0) & (cc[:, 0] + half + 2 <= w - 1) &
                  (cc[:, 1] - half - 2 >= 0) & (cc[:, 1] + half + 2 <= h - 1))
        stats["rejected_border"] = int((~inside).sum() - small.sum())
        cids, cc, sq_px, half = cids[inside], cc[inside], sq_px[inside], half[inside]
        H_mk = [H for H, ok in zip(H_mk, inside) if ok]
        if len(cids) == 0:
            return empty

        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
        refined = cc.copy()
        for hw in np.unique(half):
            idx = np.nonzero(half == hw)[0]
            pts = cc[idx].astype(np.float32).reshape(-1, 1, 2)
            refined[idx] = cv2.cornerSubPix(img, pts, (int(hw), int(hw)), (-1, -1), crit).reshape(-1, 2)
        noise = estimate_noise(img)
        sigma = _corner_sigmas(img, refined, half, noise)
        # model error grows on small windows (blur and the marker borders close to the junction)
        floor = SIGMA_FLOOR_PX * np.maximum(1.0, SMALL_WINDOW_PX / half) ** 2
        sigma = np.sqrt(sigma ** 2 + floor[:, None] ** 2)

        bad = self._homography_outliers(cids, refined, sq_px, H_mk)
        stats["rejected_homography"] = int(bad.sum())
        ok = ~bad & np.isfinite(sigma).all(axis=1)
        ids = np.array([self.target_of_corner[int(k)] for k in cids[ok]], dtype=object)
        xy, sig, hw, sqp = refined[ok], sigma[ok], half[ok], sq_px[ok]
        if self.keep_ids is not None:
            known = np.array([i in self.keep_ids for i in ids], bool)
            stats["not_in_field"] += int((~known).sum())
            ids, xy, sig, hw, sqp = ids[known], xy[known], sig[known], hw[known], sqp[known]
        stats["corners"] = int(len(ids))
        stats["noise_dn"] = noise
        return Detection(ids, xy, sig, stats, hw, sqp)

    def _homography_outliers(self, cids, xy, sq_px, H_mk) -> np.ndarray:
        """Corners off the homography of their detected 3x3 grid neighbours (or of their two markers)."""
        n = self.tf.n_squares - 1
        pos = {int(k): j for j, k in enumerate(cids)}
        board = np.array([self.corner_board_xy[int(k)] for k in cids])
        tol = np.maximum(1.0, 0.04 * sq_px)
        suspect = np.zeros(len(cids), bool)
        for _pass in range(2):
            bad = np.zeros(len(cids), bool)
            for j, k in enumerate(cids):
                r, c = divmod(int(k), n)
                nb = [pos[kk] for kk in ((r + dr) * n + c + dc for dr in (-1, 0, 1) for dc in (-1, 0, 1)
                                          if (dr or dc) and 0 <= r + dr < n and 0 <= c + dc < n)
                      if kk in pos and not suspect[pos[kk]]]
                if len(nb) >= 5:
                    H, lim = fit_homography(board[nb], xy[nb]), tol[j]
                else:
                    H, lim = H_mk[j], 2 * tol[j]
                bad[j] = H is None or np.hypot(*(apply_homography(H, board[j:j + 1])[0] - xy[j])) > lim
            suspect = bad
        return bad


def fit_homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray | None:
    """3x3 homography mapping src (N,2) to dst (N,2), N >= 4, by normalised DLT; None if degenerate."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    if len(src) < 4:
        return None

    def norm(p):
        c = p.mean(axis=0)
        s = np.sqrt(2) / max(np.sqrt(((p - c) ** 2).sum(axis=1)).mean(), 1e-12)
        return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])
    Ts, Td = norm(src), norm(dst)
    a = src @ Ts[:2, :2].T + Ts[:2, 2]
    b = dst @ Td[:2, :2].T + Td[:2, 2]
    z, o = np.zeros(len(a)), np.ones(len(a))
    bx, by = b[:, 0], b[:, 1]
    M = np.concatenate([np.column_stack([a[:, 0], a[:, 1], o, z, z, z, -bx * a[:, 0], -bx * a[:, 1], -bx]),
                        np.column_stack([z, z, z, a[:, 0], a[:, 1], o, -by * a[:, 0], -by * a[:, 1], -by])])
    _, sv, vt = np.linalg.svd(M)
    if sv[-2] < 1e-9 * sv[0]:
        return None
    H = np.linalg.inv(Td) @ vt[-1].reshape(3, 3) @ Ts
    return H / H[2, 2] if abs(H[2, 2]) > 1e-15 else None


def apply_homography(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Points (N,2) mapped by H."""
    q = np.asarray(p, float) @ H[:, :2].T + H[:, 2]
    return q[:, :2] / q[:, 2:3]


def homography_jacobian(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """d(H p)/dp (2x2) at point p (2,)."""
    q = H @ np.append(p, 1.0)
    return (H[:2, :2] * q[2] - np.outer(q[:2], H[2, :2])) / q[2] ** 2


def _corner_sigmas(img: np.ndarray, xy: np.ndarray, half: np.ndarray, noise_dn: float) -> np.ndarray:
    """Sigma (px) of cornerSubPix corners: sandwich covariance A^-1 (sg^2 sum w^2 |p-q|^2 g g^T) A^-1 with
    A = sum w g g^T, the weights and gradients of cornerSubPix and sg the gradient noise."""
    sg2 = noise_dn ** 2 * 12.0 / 64.0  # variance of the Sobel/8 derivative of white noise
    out = np.full((len(xy), 2), np.nan)
    h, w = img.shape
    for j, (q, hw) in enumerate(zip(xy, half)):
        x0, y0 = int(round(q[0])), int(round(q[1]))
        if x0 - hw < 1 or y0 - hw < 1 or x0 + hw > w - 2 or y0 + hw > h - 2:
            continue
        ys, xs = np.mgrid[y0 - hw:y0 + hw + 1, x0 - hw:x0 + hw + 1]
        wgt = np.exp(-((xs - x0) / hw) ** 2 - ((ys - y0) / hw) ** 2)
        patch = img[y0 - hw - 1:y0 + hw + 2, x0 - hw - 1:x0 + hw + 2].astype(np.float32)
        gx = cv2.Sobel(patch, cv2.CV_32F, 1, 0, ksize=3)[1:-1, 1:-1] / 8.0
        gy = cv2.Sobel(patch, cv2.CV_32F, 0, 1, ksize=3)[1:-1, 1:-1] / 8.0
        g = np.stack([gx, gy], axis=-1).reshape(-1, 2)
        wv = wgt.ravel()
        d2 = ((xs - q[0]) ** 2 + (ys - q[1]) ** 2).ravel()
        A = (g * wv[:, None]).T @ g
        B = (g * (wv ** 2 * d2)[:, None]).T @ g
        try:
            Ai = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            continue
        cov = sg2 * Ai @ B @ Ai
        out[j] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return SIGMA_FACTOR * out


def detect_image(img: np.ndarray, field: TargetField | str | Path) -> Detection:
    """Targets in one grey image (uint8 array)."""
    tf, keep, _ = resolve_field(field)
    return CharucoFieldDetector(tf, keep).detect(img)


_WORKER: dict = {}


def _detect_file(path: str, tf_dict: dict, keep: set | None):
    """Worker: detect in one file; returns (name, Detection) or (name, error message)."""
    key = (repr(tf_dict), None if keep is None else tuple(sorted(keep)))
    det = _WORKER.get("det")
    if det is None or _WORKER.get("key") != key:  # one detector per process, reused for its images
        det = CharucoFieldDetector(TargetField.from_dict(tf_dict), keep)
        _WORKER.update(det=det, key=key)
    try:
        img = read_gray(path)
    except InputError as exc:
        return Path(path).name, str(exc)
    return Path(path).name, det.detect(img)


def detect_folder(image_dir: str | Path, field: TargetField | str | Path, workers: int | None = None,
                  progress: bool = True) -> tuple[Measurements, dict]:
    """Detect the field's targets in every image of a folder (in parallel, with a progress bar).

    Returns the measurement table (`image` = file name, `id`, pixel `xy`, `sigma` px) and a report:
    per-image counts (markers, corners, rejections, size, noise), `image_size` when all images agree
    (else None) and the layout source. Unreadable images or an empty folder raise InputError naming the file."""
    files = list_image_files(image_dir)
    tf, keep, source = resolve_field(field)
    for f in files:  # fail fast, before any work, on files that cannot even be opened as images
        if f.stat().st_size == 0:
            raise InputError("cannot read the image (empty file)", f)
    n_workers = max(1, min(len(files), workers if workers is not None else min(2, os.cpu_count() or 1)))
    results: dict[str, Detection] = {}
    args = [(str(f), tf.to_dict(), keep) for f in files]
    bar = tqdm(total=len(files), desc="detect", unit="img", disable=not progress, file=sys.stderr)
    try:
        if n_workers == 1:
            for a in args:
                name, res = _detect_file(*a)
                if isinstance(res, str):
                    raise InputError(res.split(": ", 1)[-1], a[0])
                results[name] = res
                bar.update()
        else:
            with ProcessPoolExecutor(n_workers) as pool:
                futs = {pool.submit(_detect_file, *a): a[0] for a in args}
                for fut in as_completed(futs):
                    name, res = fut.result()
                    if isinstance(res, str):
                        for other in futs:
                            other.cancel()
                        raise InputError(res.split(": ", 1)[-1], futs[fut])
                    results[name] = res
                    bar.update()
    finally:
        bar.close()
    names = [f.name for f in files]
    image = np.concatenate([np.full(len(results[n].ids), n, dtype=object) for n in names])
    ids = np.concatenate([results[n].ids for n in names]).astype(object)
    xy = np.concatenate([results[n].xy for n in names]).reshape(-1, 2)
    sig = np.concatenate([results[n].sigma for n in names]).reshape(-1, 2)
    sizes = {tuple(results[n].stats["size"]) for n in names}
    report = {"n_images": len(names), "n_points": int(len(ids)), "layout": source,
              "image_size": list(sizes.pop()) if len(sizes) == 1 else None,
              "images": {n: results[n].stats for n in names}}
    return Measurements(image, ids, xy, sig), report
