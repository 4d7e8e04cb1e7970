"""Automatic measurement of coded GCP targets: ArUco markers whose id names the ground point.

A target is an ArUco marker laid flat on the ground point, its centre on the point. The measurement is
the intersection of the marker's diagonals (projectively exact for a plane, unlike the corner mean),
from corners refined with cv2.cornerSubPix. Point id = `id_format.format(marker_id)` (default the bare
number), so `gcp.csv` names its points "7", "12", ... or the caller maps them. Pixels: OpenCV convention.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import Measurements


def aruco_dictionary(name: str):
    """An OpenCV predefined ArUco dictionary by name (e.g. 'DICT_4X4_50'); InputError if unknown."""
    key = name.strip().upper()
    if not key.startswith("DICT_"):
        key = "DICT_" + key
    if not hasattr(cv2.aruco, key):
        raise InputError(f"unknown ArUco dictionary {name!r} (e.g. DICT_4X4_50, DICT_5X5_100)", field="targets")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, key))


def _diagonal_centre(c: np.ndarray) -> np.ndarray:
    """Intersection of the diagonals c0-c2 and c1-c3 of a quadrilateral (4,2)."""
    p, r = c[0], c[2] - c[0]
    q, s = c[1], c[3] - c[1]
    den = r[0] * s[1] - r[1] * s[0]
    if abs(den) < 1e-12:
        return c.mean(0)
    t = ((q - p)[0] * s[1] - (q - p)[1] * s[0]) / den
    return p + t * r


def detect_gcp_targets(image_dir: str | Path, names: list[str], dictionary: str = "DICT_4X4_50",
                       id_format: str = "{}", sigma_px: float = 0.3) -> Measurements:
    """Measurements (px) of ArUco GCP targets in the images; markers seen twice in one image are dropped."""
    det = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), cv2.aruco.DetectorParameters())
    img_l, id_l, xy_l = [], [], []
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.001)
    for n in names:
        path = Path(image_dir) / n
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
        if img is None:
            raise InputError("cannot read image", path, field="images")
        corners, ids, _ = det.detectMarkers(img)
        if ids is None:
            continue
        ids = ids.ravel()
        uniq, cnt = np.unique(ids, return_counts=True)
        for c, mid in zip(corners, ids):
            if cnt[np.searchsorted(uniq, mid)] > 1:
                continue
            c = c.reshape(4, 2).astype(np.float32)
            side = float(np.min(np.linalg.norm(c - np.roll(c, 1, 0), axis=1)))
            win = max(2, int(side / 8))
            c = cv2.cornerSubPix(img, c.reshape(-1, 1, 2), (win, win), (-1, -1), crit).reshape(4, 2)
            img_l.append(n)
            id_l.append(id_format.format(int(mid)))
            xy_l.append(_diagonal_centre(c.astype(float)))
    k = len(img_l)
    return Measurements(np.array(img_l, dtype=object), np.array(id_l, dtype=object), np.array(xy_l).reshape(-1, 2),
                        np.full((k, 2), float(sigma_px)))
