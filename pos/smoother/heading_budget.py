"""The heading sigma of a record whose motion never determined the heading (issue 27).

A heading comes from the GNSS course (moving faster than `HEADING_SPEED_MPS`), from horizontal accelerations the
accelerometers see well above their bias, or, with nothing else, from the earth's rotation (gyrocompassing): the
gyros see the horizontal earth rate Omega cos(lat) and its direction is north. Any gyro bias along the horizontal
is indistinguishable from a heading error, so static alignment reaches sigma_psi = sigma_b / (Omega cos lat) at
best, sigma_b the gyro bias the grade leaves (turn-on and instability) with the white noise averaged over the
record. A navigation-grade IMU gyrocompasses to hundredths of a degree; a MEMS gyro (hundreds of deg/h of bias
against 10-15 deg/h of earth rate) cannot, and its heading is as good as unknown: the sigma of a heading uniform
on the circle, 180/sqrt(3) = 104 deg.

The smoother's linearised covariance misses this on such records: about a wrong heading its gyro-bias and
earth-rate terms still look informative (a static consumer-grade record gave 25-30 deg sigmas with 60-150 deg
errors). `add_heading_budget` raises the heading variance of every keyframe to at least the gyrocompassing limit
when neither a course nor large enough accelerations exist, about the nav frame's down axis (roll and pitch
unchanged).
"""
from __future__ import annotations

import numpy as np

from dgcal.fields.constants import OMEGA_EARTH

HEADING_SPEED_MPS = 3.0          # the GNSS course gives the first heading above this ground speed
HEADING_UNKNOWN_SIGMA_DEG = 104.0  # a heading uniform over the circle (180/sqrt(3) deg)
# horizontal accelerations (m/s^2) beyond this many accelerometer-bias sigmas make the heading observable: a heading
# error psi turns them into a horizontal specific-force error psi*|a| the bias cannot absorb when the vehicle turns
ACCEL_OBSERVABLE_SIGMAS = 5.0


def gyrocompass_sigma(noise, lat_deg: float, duration_s: float) -> float:
    """Heading sigma (rad) static alignment reaches with the gyro model `noise` (smoother noise: turn-on bias sigma
    rad/s, white noise rad/sqrt(s)) over `duration_s` at latitude `lat_deg`: sigma_b / (Omega cos lat), at most that
    of an unknown heading."""
    sb = float(np.hypot(noise.gyro_bias_sigma, float(noise.gyro_arw) / np.sqrt(max(duration_s, 1.0))))
    horizontal = OMEGA_EARTH * abs(np.cos(np.radians(lat_deg)))
    unknown = np.radians(HEADING_UNKNOWN_SIGMA_DEG)
    return float(min(sb / horizontal, unknown)) if horizontal > 0 else float(unknown)


def heading_from_motion(t: np.ndarray, v_nav: np.ndarray, noise) -> bool:
    """True when the motion determines the heading: a horizontal speed above HEADING_SPEED_MPS (a course), or a
    horizontal acceleration (1 s secants of the velocities v_nav m/s at times t s) beyond ACCEL_OBSERVABLE_SIGMAS
    accelerometer-bias sigmas."""
    v_h = np.hypot(v_nav[:, 0], v_nav[:, 1])
    if np.any(v_h > HEADING_SPEED_MPS):
        return True
    if len(t) < 2:
        return False
    j = np.clip(np.searchsorted(t, t + 1.0), 0, len(t) - 1)
    dt = t[j] - t
    ok = dt > 0.5
    a_h = np.linalg.norm(v_nav[j[ok], :2] - v_nav[ok, :2], axis=1) / dt[ok]
    return bool(a_h.size and a_h.max() > ACCEL_OBSERVABLE_SIGMAS * float(noise.accel_bias_sigma))


def add_heading_budget(sol, noise) -> None:
    """Raise each keyframe's heading variance to at least the gyrocompassing limit (`gyrocompass_sigma`) when the
    motion does not determine the heading (`heading_from_motion`): variance added about the nav down axis in body
    coordinates to the rotation blocks of `sol.cov_pose` and `sol.cov_block`; the floor (deg) in
    sol.info['heading_budget_deg']."""
    if sol.cov_pose is None or heading_from_motion(sol.t, sol.v_nav, noise):
        return
    floor = gyrocompass_sigma(noise, sol.frame.lat0, float(sol.t[-1] - sol.t[0]))
    u_b = sol.R_body_to_nav[:, 2, :]                     # nav down in body axes: a rotation about it is heading only
    rph_rate = heading_rows(sol.R_body_to_nav)
    var_h = np.einsum("ni,nij,nj->n", rph_rate, sol.cov_pose[:, :3, :3], rph_rate)
    add = np.maximum(floor ** 2 - var_h, 0.0)
    dC = add[:, None, None] * np.einsum("ni,nj->nij", u_b, u_b)
    for C in (sol.cov_pose, sol.cov_block):
        if C is not None:
            C[:, :3, :3] += dC
    sol.info["heading_budget_deg"] = round(float(np.degrees(floor)), 4)


def heading_rows(R_body_to_nav: np.ndarray) -> np.ndarray:
    """d heading / d delta_theta_body (N,3) for R_body_to_nav perturbed as R Exp(delta_theta) (ZYX Euler angles)."""
    r = np.arctan2(R_body_to_nav[:, 2, 1], R_body_to_nav[:, 2, 2])
    p = -np.arcsin(np.clip(R_body_to_nav[:, 2, 0], -1.0, 1.0))
    cp = np.maximum(np.cos(p), 1e-9)
    return np.stack([np.zeros_like(r), np.sin(r) / cp, np.cos(r) / cp], -1)
