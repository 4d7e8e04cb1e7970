"""The first attitude of a slow platform (issue 27): no course above `HEADING_SPEED_MPS`, so the anchor's
pseudo-attitude is a guess and the gyros, propagated with zero biases, drift it — a consumer MEMS gyro's turn-on
bias (0.2 deg/s sigma) turns the guess over in minutes. The smoother settled on such guesses upside down (a slow
robot's roll at 180 deg with a 0.2 deg sigma) or with a heading that drifts against the GNSS course behind an
estimated z-gyro bias of thousands of deg/h.

`slow_platform_attitude` replaces the guess: roll and pitch from the accelerometers (the mean specific force about
each keyframe: a slow platform's accelerations are small beside gravity); the heading integrated from the gyros'
rotation about the vertical of that levelled attitude (consistent with the gyro increments up to the z bias), then
aligned with the GNSS track where it is straight and long enough to give a course
(`dgcal.pos.smoother.heading_budget.track_course`) by an offset and a drift (a line fitted to course minus heading:
the z-gyro bias's drift out of the guess). A piecewise correction that jumps between stretches contradicts the
gyros and sent the smoother into a heading spinning at 7000 deg/h. A platform that never gives a course keeps its
propagated heading. The guess assumes the platform moves forward (body x along the track).
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter

from dgcal.fields.frames import R_body_to_ned_from_rph, rph_from_R_body_to_ned
from dgcal.pos.smoother.heading_budget import track_course

MEDIAN_SAMPLES = 9      # course corrections median-filtered over this many stretch epochs (outlier courses out)
MIN_DRIFT_SPAN_S = 60.0  # courses spanning longer than this also give the heading's drift (the z-gyro bias)


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


def level_heading_increments(imu, t_key: np.ndarray, R_level: np.ndarray) -> np.ndarray:
    """Heading (rad) at the keyframes from 0 at the first, the gyro increments (body FRD, rad) projected on the nav
    down axis of the levelled attitude R_level (K,3,3) at the start of each keyframe interval: the rotation about the
    vertical, free of the tilt the horizontal gyro biases would otherwise turn into heading."""
    i = np.clip(np.searchsorted(t_key, imu.t, side="left") - 1, 0, len(t_key) - 1)   # the interval of each sample
    d_psi = np.einsum("ni,ni->n", imu.dtheta, R_level[i, 2, :])
    cum = np.concatenate([[0.0], np.cumsum(d_psi)])
    return cum[np.searchsorted(imu.t, t_key, side="right")] - cum[np.searchsorted(imu.t, t_key[0], side="right")]


def course_alignment(t: np.ndarray, psi_rel: np.ndarray, course: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """The offset (and, over more than MIN_DRIFT_SPAN_S, the drift) that turns the relative heading psi_rel onto the
    track's course at the usable epochs: a line in time fitted to the unwrapped differences, the points beyond 3
    robust sigmas dropped once; the aligned heading (rad) at every t."""
    tu = t[ok]
    c = np.unwrap(np.angle(np.exp(1j * (course[ok] - psi_rel[ok]))))
    c = median_filter(c, size=min(MEDIAN_SAMPLES, len(c)), mode="nearest")
    use = np.ones(len(c), bool)
    drift = tu[-1] - tu[0] > MIN_DRIFT_SPAN_S
    for _ in range(2):
        if drift:
            coef = np.polyfit(tu[use] - tu[0], c[use], 1)
            fit = np.polyval(coef, tu - tu[0])
        else:
            fit = np.full(len(c), np.median(c[use]))
        r = c - fit
        mad = 1.4826 * np.median(np.abs(r[use] - np.median(r[use])))
        use = np.abs(r) <= max(3.0 * mad, np.radians(5.0))
        if use.sum() < 3:
            break
    if drift:
        return psi_rel + np.polyval(coef, t - tu[0])
    return psi_rel + fit[0]


def slow_platform_attitude(imu, t_key: np.ndarray, R_body_to_nav: np.ndarray, p_ant_nav: np.ndarray,
                           sigma_h_m: float) -> np.ndarray:
    """The initial R_body_to_nav (K,3,3) of a slow platform (module doc): levelled by the accelerometers, its
    heading the gyros' rotation about the vertical aligned with the course of the antenna track p_ant_nav (K,3,
    nav m; fixes of horizontal sigma sigma_h_m) where that gives one, else the propagated heading kept."""
    R = level_attitude(imu, t_key, R_body_to_nav)
    psi_rel = level_heading_increments(imu, t_key, R)
    course, _, ok = track_course(t_key, p_ant_nav, psi_rel, sigma_h_m)
    if ok.sum() < 3:
        return R
    psi = course_alignment(t_key, psi_rel, course, ok)
    rph = rph_from_R_body_to_ned(R)
    return R_body_to_ned_from_rph(rph[:, 0], rph[:, 1], np.degrees(psi))
