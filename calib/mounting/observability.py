"""Observability diagnostics of the mounting calibration: can this flight pattern separate the unknowns?"""
from __future__ import annotations

import numpy as np

from dgcal.calib.mounting.common import Epochs, MountingResult

MIN_EPOCHS = 10


def _heading_groups(v_world: np.ndarray, speed_min: float = 2.0) -> np.ndarray:
    """Track azimuths (deg) of moving epochs."""
    moving = np.linalg.norm(v_world[:, :2], axis=1) > speed_min
    return np.degrees(np.arctan2(v_world[moving, 0], v_world[moving, 1])) % 360


def observability_warnings(ep: Epochs, result: MountingResult | None = None,
                           corr_limit: float = 0.9) -> list[str]:
    """Warnings on flight geometry (headings, heights, speed variation, epoch count) and high correlations."""
    out = []
    n = len(ep)
    if n < MIN_EPOCHS:
        out.append(f"only {n} epochs: at least {MIN_EPOCHS} are needed for a meaningful calibration")
    az = _heading_groups(ep.pos.v_world)
    if len(az):
        # circular spread: one heading when all tracks lie within +-30 deg of their mean direction
        c = np.exp(1j * np.radians(az))
        mean_dir = np.angle(c.mean())
        dev = np.degrees(np.abs(np.angle(c * np.exp(-1j * mean_dir))))
        if np.all(dev < 30):
            out.append("all strips fly one heading: the exposure delay and the along-track lever arm are not "
                       "separable (fly strips in opposite headings, ideally with different ground speeds)")
    # what separates delay from lever arm is the variation of the body-frame velocity (and angular rate)
    v_b = np.einsum("nji,nj->ni", ep.pos.R_body_to_world, ep.pos.v_world)
    spread = float(np.std(v_b[:, 0])) if n > 1 else 0.0
    rate = float(np.degrees(np.std(np.linalg.norm(ep.pos.omega_b, axis=1)))) if n > 1 else 0.0
    if spread < 1.0 and rate < 0.5:
        out.append(f"the forward ground speed varies by only {spread:.2f} m/s (std) over the epochs: the delay is "
                   "nearly inseparable from the along-track lever arm")
    z = ep.eop.C_world[:, 2]
    if n > 1 and np.ptp(z) < 0.25 * max(np.median(np.abs(z)), 1.0):
        out.append("one flying height only: boresight errors and POS attitude errors, and the vertical lever arm "
                   "and height-dependent bundle errors, are hard to tell apart (fly two heights, e.g. 300 m and 600 m)")
    if result is not None:
        s = result.sigmas
        if s[0] > 0.002:
            out.append(f"the exposure delay is poorly determined (sigma {s[0] * 1e3:.1f} ms): fly strips in opposite "
                       "headings with different ground speeds, or add turns")
        if np.any(s[1:4] > 0.05):
            out.append("the lever arm is poorly determined (sigma " + ", ".join(f"{v:.3f}" for v in s[1:4]) + " m)")
        C = result.correlation()
        names = result.PARAM_NAMES
        for i in range(7):
            for j in range(i + 1, 7):
                if np.isfinite(C[i, j]) and abs(C[i, j]) > corr_limit:
                    out.append(f"high correlation {C[i, j]:+.3f} between {names[i]} and {names[j]}")
    return out
