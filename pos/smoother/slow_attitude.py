"""The first attitude of a slow platform (issue 27): no course above `HEADING_SPEED_MPS`, so the anchor's
pseudo-attitude is a guess and the gyros, propagated with zero biases, drift it — a consumer MEMS gyro's turn-on
bias (0.2 deg/s sigma) turns the guess over in minutes. The smoother settled on such guesses upside down (a slow
robot's roll at 180 deg with a 0.2 deg sigma) or with a heading that drifts against the GNSS course behind an
estimated z-gyro bias of thousands of deg/h.

`slow_platform_attitude` replaces the guess: roll and pitch from the accelerometers (the mean specific force about
each keyframe: a slow platform's accelerations are small beside gravity), and the heading from the GNSS track where
it is straight and long enough to give a course (`dgcal.pos.smoother.heading_budget.track_course`): the propagated
heading is corrected by the course minus it, median-filtered and interpolated in time between such stretches,
which also takes the z-gyro bias's drift out of the guess. A platform that never gives a course keeps its
propagated heading. The guess assumes the platform moves forward (body x along the track).
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter

from dgcal.fields.frames import R_body_to_ned_from_rph
from dgcal.pos.smoother.heading_budget import track_course

MEDIAN_SAMPLES = 9      # course corrections median-filtered over this many stretch epochs (outlier courses out)


def level_attitude(imu, t_key: np.ndarray, R_body_to_nav: np.ndarray, window_s: float = 1.0) -> np.ndarray:
    """R_body_to_nav (K,3,3) with roll and pitch from the mean specific force (body FRD) within +-window_s/2 of each
    keyframe (t_key GPS s), the heading kept."""
    a = np.searchsorted(imu.t, t_key - 0.5 * window_s)
    b = np.minimum(np.maximum(np.searchsorted(imu.t, t_key + 0.5 * window_s), a + 1), len(imu.t))
    cf = np.vstack([np.zeros(3), np.cumsum(imu.dvel, axis=0)])
    f = cf[b] - cf[np.minimum(a, b - 1)]
    roll = np.degrees(np.arctan2(-f[:, 1], -f[:, 2]))
    pitch = np.degrees(np.arctan2(f[:, 0], np.hypot(f[:, 1], f[:, 2])))
    heading = np.degrees(np.arctan2(R_body_to_nav[:, 1, 0], R_body_to_nav[:, 0, 0]))
    return R_body_to_ned_from_rph(roll, pitch, heading)


def slow_platform_attitude(imu, t_key: np.ndarray, R_body_to_nav: np.ndarray, p_ant_nav: np.ndarray,
                           sigma_h_m: float) -> np.ndarray:
    """The initial R_body_to_nav (K,3,3) of a slow platform (module doc): levelled by the accelerometers, its
    heading turned onto the course of the antenna track p_ant_nav (K,3, nav m; fixes of horizontal sigma
    sigma_h_m) where that gives one."""
    R = level_attitude(imu, t_key, R_body_to_nav)
    psi = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    course, sigma, ok = track_course(t_key, p_ant_nav, psi, sigma_h_m)
    if ok.sum() < 3:
        return R
    corr = np.unwrap(np.angle(np.exp(1j * (course[ok] - psi[ok]))))
    corr = median_filter(corr, size=min(MEDIAN_SAMPLES, len(corr)), mode="nearest")
    c = np.interp(t_key, t_key[ok], corr)
    cc, sc = np.cos(c), np.sin(c)
    Rz = np.zeros((len(c), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = cc, -sc, sc, cc, 1.0
    return Rz @ R
