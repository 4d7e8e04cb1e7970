"""OpenCV `calibrateCamera` on dgcal's measurements: the baseline the self-calibration is compared with."""
from __future__ import annotations

import cv2
import numpy as np

from dgcal.calib.camera.conversions import from_opencv, opencv_from_K_dist
from dgcal.calib.camera.models import CameraModel
from dgcal.fields.io.formats import Points


def calibrate_with_opencv(points: Points, image: np.ndarray, ids: np.ndarray, xy: np.ndarray,
                          image_size: tuple[int, int], rational: bool = False) -> tuple[float, CameraModel]:
    """RMS (px) and model of OpenCV's calibration of a planar (z = 0) field; fraser7 (B2 = 0), or opencv8 if
    `rational`."""
    index = {k: i for i, k in enumerate(points.ids)}
    objs, imgs = [], []
    for name in dict.fromkeys(image.tolist()):
        m = image == name
        objs.append(points.xyz[[index[k] for k in ids[m]]].astype(np.float32))
        imgs.append(xy[m].astype(np.float32))
    flags = cv2.CALIB_RATIONAL_MODEL if rational else 0
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, K, dist, _, _ = cv2.calibrateCamera(objs, imgs, tuple(image_size), None, None, flags=flags, criteria=crit)
    return float(rms), from_opencv(opencv_from_K_dist(K, dist), image_size, "opencv8" if rational else None)
