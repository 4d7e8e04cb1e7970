"""Traditional two-step mounting calibration (seed 003 eq. 4-5, 8-9): per-epoch lever arm and boresight at the
EVENT time (delay assumed 0), then their robust mean.

Per epoch i, in the world frame of the block:
    l_b,i        = R_body_to_world,i^T (C_world,i - r_imu_world,i)
    R_cam_to_body,i = R_body_to_world,i^T R_cam_to_world,i
Mean: lever arm by the mean after rejecting epochs further than 4 sigmas from the mean (iterated);
boresight by chordal rotation averaging after the same test on the angular distance from a first mean.
Sigmas: spread / sqrt(n) (the per-epoch values are treated as independent samples).
"""
from __future__ import annotations

import numpy as np

from dgcal.calib.mounting.common import Epochs, MountingResult, rotation_mean
from dgcal.fields.pose import so3_log
from dgcal.fields.pose import transpose as T


def per_epoch_values(ep: Epochs) -> tuple[np.ndarray, np.ndarray]:
    """Per-epoch lever arms (N,3) m in body and boresights `R_cam_to_body` (N,3,3) at event time."""
    R_body_to_world = ep.pos.R_body_to_world
    lever = np.einsum("nji,nj->ni", R_body_to_world, ep.eop.C_world - ep.pos.r_imu_world)
    return lever, T(R_body_to_world) @ ep.eop.R_cam_to_world


def _clip_outliers(x: np.ndarray, k: float = 4.0, rounds: int = 5) -> np.ndarray:
    """Rows of x (N,d) further than k standard deviations from the mean in any column (iterated).

    Mean/std clipping rather than median/MAD: an uncalibrated delay makes the per-epoch lever arm bimodal
    (one mode per ground speed), and a MAD test would throw away a whole heading."""
    bad = np.zeros(len(x), bool)
    for _ in range(rounds):
        m, s = x[~bad].mean(axis=0), x[~bad].std(axis=0)
        s = np.where(s > 0, s, np.inf)
        new = np.any(np.abs(x - m) > k * s, axis=1)
        if np.array_equal(new, bad):
            break
        bad = new
    return bad


def calibrate_traditional(ep: Epochs) -> MountingResult:
    """Lever arm and boresight as robust means of per-epoch values at event time (delay fixed to 0)."""
    lever, R_cam_to_body = per_epoch_values(ep)
    R_cam_to_body_0 = rotation_mean(R_cam_to_body)
    ang0 = so3_log(R_cam_to_body @ R_cam_to_body_0.T)  # body-frame rotation of each epoch from the first mean
    bad = _clip_outliers(np.column_stack([lever, ang0])) if len(ep) >= 5 else np.zeros(len(ep), bool)
    keep = ~bad
    l_mean = lever[keep].mean(axis=0)
    R_cam_to_body_mean = rotation_mean(R_cam_to_body[keep])
    # left residuals: R_cam_to_body,i = Exp(a_i) R_cam_to_body_mean, a_i about body axes
    ang = so3_log(R_cam_to_body @ R_cam_to_body_mean.T)
    n = int(keep.sum())
    ddof = 1 if n > 1 else 0
    cov = np.zeros((7, 7))
    X = np.column_stack([lever[keep], ang[keep]])
    cov[1:, 1:] = np.cov(X.T, ddof=ddof) / max(n, 1) if n > 1 else np.zeros((6, 6))
    per_epoch = {"image": [str(s) for s in ep.image], "t_event": ep.t_event.tolist(),
                 "lever_arm_m": lever.tolist(), "boresight_deg": np.degrees(ang).tolist(),
                 "rejected": bad.tolist()}
    res = MountingResult("traditional", l_mean, R_cam_to_body_mean, 0.0, cov, n, [str(s) for s in ep.image[bad]],
                         list(ep.warnings), per_epoch)
    res.extra["delay_fixed"] = True
    res.extra["lever_arm_spread_m"] = lever[keep].std(axis=0, ddof=ddof).tolist()
    res.extra["boresight_spread_deg"] = np.degrees(ang[keep].std(axis=0, ddof=ddof)).tolist()
    return res
