"""Blunder detection on ground control: Baarda's standardised residuals of image measurements, suspects named."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgcal.bundle.adjustment import BundleResult

CRITICAL_W = 4.0   # |w| above this (two-sided, about 1e-4 false alarm per coordinate) marks a suspect


@dataclass
class Suspect:
    """A measurement whose standardised residual exceeds the critical value."""

    image: str
    point: str
    residual_px: tuple[float, float]
    w: float                         # largest |standardised residual| of its two coordinates (coordinates: the
                                     # 3-dof test as an equivalent |w|)
    redundancy: float                # smallest redundancy number of its two coordinates
    removed: bool = False
    kind: str = "measurement"        # "measurement" (an image measurement), "coordinates" (a control point's) or
                                     # "centre" (an image's camera-centre prior: `image` names it)
    coordinate_error_m: tuple[float, float, float] | None = None   # adjusted - given (world axes): coordinates, centre

    def as_dict(self) -> dict:
        d = {"kind": self.kind, "image": self.image, "id": self.point,
             "residual_px": [float(v) for v in self.residual_px], "w": float(self.w),
             "redundancy": float(self.redundancy), "removed": self.removed}
        if self.coordinate_error_m is not None:
            d["coordinate_error_m"] = [float(v) for v in self.coordinate_error_m]
        return d


def standardized(result: BundleResult, obs_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standardised residuals (k,2) and redundancy numbers (k,2) of the selected pixel observations."""
    idx = np.atleast_1d(np.asarray(obs_idx, int))
    if len(idx) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return result.standardized_residuals(idx), result.redundancy_numbers(idx)


def find_suspects(result: BundleResult, obs_idx: np.ndarray, image_names, point_ids,
                  critical: float = CRITICAL_W, min_redundancy: float = 0.02) -> list[Suspect]:
    """Suspect measurements among `obs_idx`, worst first. Observations with almost no redundancy
    (a GCP seen once, an image with few points) cannot be tested and are never flagged."""
    idx = np.atleast_1d(np.asarray(obs_idx, int))
    w, r = standardized(result, idx)
    out = []
    for n, k in enumerate(idx):
        testable = r[n] > min_redundancy
        if not testable.any():
            continue
        wk = float(np.max(np.abs(w[n][testable])))
        if wk > critical:
            out.append(Suspect(str(image_names[result.obs_image[k]]), str(point_ids[result.obs_point[k]]),
                               tuple(result.residuals_px[k]), wk, float(r[n].min())))
    return sorted(out, key=lambda s: -s.w)
