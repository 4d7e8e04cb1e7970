"""IMU preintegration between keyframes for the gtsam smoother (CombinedImuFactor, nav = NED, earth rate).

The IMU increments are split at keyframe times (a sample straddling a keyframe is cut in two with the same
mean rate), and each piece is handed to gtsam's `integrateMeasurement` — the only per-sample work.
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from dgcal.fields.crs import ecef_to_geodetic
from dgcal.pos.ins.error_model import ImuErrorModel
from dgcal.pos.ins.nav_frame import NavFrame, normal_gravity


def preintegration_params(noise: ImuErrorModel, frame: NavFrame, earth_rotation: bool = True):
    """gtsam PreintegrationCombinedParams for a NED nav frame with normal gravity and (optionally) earth rate.

    `noise` is in the smoother's form (`ImuErrorModel.smoother_noise()`: bias random walks, no Gauss-Markov).
    """
    if noise.has_gauss_markov_bias:
        raise ValueError(f"IMU model {noise.name!r} has a Gauss-Markov bias: pass model.smoother_noise()")
    p = gtsam.PreintegrationCombinedParams.MakeSharedD(frame.gravity)
    I3 = np.eye(3)
    p.setGyroscopeCovariance(I3 * noise.gyro_arw ** 2)
    p.setAccelerometerCovariance(I3 * noise.accel_vrw ** 2)
    # integration error of the 200 Hz rectangle rule; small, keeps the information matrix well conditioned
    p.setIntegrationCovariance(I3 * 1e-9)
    p.setBiasOmegaCovariance(I3 * noise.gyro_bias_rw ** 2)
    p.setBiasAccCovariance(I3 * noise.accel_bias_rw ** 2)
    if earth_rotation:
        p.setOmegaCoriolis(frame.omega_ie_nav)
    return p


@dataclass
class ImuSegments:
    """IMU pieces split at keyframe times: mean rates (N,3), durations (N,), and for keyframe interval k the
    pieces `start[k]:start[k+1]`."""

    gyro: np.ndarray
    accel: np.ndarray
    dt: np.ndarray
    start: np.ndarray


def split_at_keyframes(t_imu: np.ndarray, gyro: np.ndarray, accel: np.ndarray, t_key: np.ndarray,
                       dt_first: float) -> ImuSegments:
    """Cut IMU intervals (ending at `t_imu`, GPS s, mean rates rad/s, m/s^2) at the keyframe times `t_key`."""
    t_imu = np.asarray(t_imu, float)
    t_start = np.empty_like(t_imu)
    t_start[0] = t_imu[0] - dt_first
    t_start[1:] = t_imu[:-1]
    if t_key[0] < t_start[0] - 1e-9 or t_key[-1] > t_imu[-1] + 1e-9:
        raise ValueError("keyframes outside the IMU time span")
    # all breakpoints inside the keyframe span
    inner = t_imu[(t_imu > t_key[0]) & (t_imu < t_key[-1])]
    bp = np.union1d(inner, t_key)
    bp = bp[np.concatenate([[True], np.diff(bp) > 1e-9])]
    mid = 0.5 * (bp[:-1] + bp[1:])
    idx = np.searchsorted(t_imu, mid, side="left")  # sample whose interval (t_{i-1}, t_i] holds mid
    idx = np.clip(idx, 0, len(t_imu) - 1)
    dt = np.diff(bp)
    key_pos = np.searchsorted(bp, t_key - 1e-9)
    return ImuSegments(gyro[idx], accel[idx], dt, key_pos)


SIGNED_TURNS = True   # the turn noise from the net manoeuvre within the window (False: from its absolute rates)
# the share of the gyro misalignment's turn-noise variance carried: the white-noise equivalent of a constant
# misalignment (m times the net rotation about the other axes, added up turn after turn as if independent)
# over-states what is left once GNSS and accelerometers see the attitude between turns; a quarter of it (half its
# sigma) makes roll/pitch/heading error/sigma 0.76-1.18 over the simulated 5-minute families (8 seeds each; the
# whole variance gave 0.66-1.11, the fixed wing's heading 0.66-0.76) and 1.10/0.99/1.02 on 20-minute multirotor
# TC flights (8 seeds; none of it 1.20/1.10/1.08, all of it 1.01/0.84/0.97: there it is a third of the roll
# variance, the tilt budget another); none of it gave up to 1.19 (5-minute TC) and 4.8 sigma (docs/pos_smoother.md)
GYRO_MISALIGN_SHARE = 0.25


def interval_params(noise: ImuErrorModel, frame: NavFrame, seg: ImuSegments, earth_rotation: bool = True,
                    window_s: float = 10.0) -> list:
    """Preintegration parameters per keyframe interval (one object each: `set_gravity` gives each interval its
    own gravity), with the scale/misalignment errors as turn noise.

    A scale error s and misalignment m make an error s*d_i + m*sum_{j!=i} d_j proportional to the rate itself
    (gyro: d = w, the earth rate is negligible) or to the specific force's deviation from its flight median (the
    gravity of level flight): it lasts as long as the manoeuvre and vanishes after it, so it is NOT a bias change
    (a bias allowed to jump at a turn entry stays wrong on the next straight line, which spoiled pitch 3x, and
    heading 30x on the last strip of a flight). It is added as white
    noise whose integral over the manoeuvre has the variance of the correlated error: an interval with
    deviation |d_k| gets density s^2 |d_k| A_k, A_k the net (signed) integral of d within `window_s` s around it,
    so a turn through an angle A within the window accumulates (s A)^2; a longer manoeuvre (continuous circling) is
    taken as correlated over the window only (a 180 deg turn at 13 deg/s gets ~90 % of (s A)^2). Net, because the
    error is the scale or misalignment times the net angle: a fixed wing's roll into a bank and out of it within
    the window leave none (with |d| integrated they counted twice the bank angle, on every turn).
    """
    K = len(seg.start) - 1
    turn = bool(noise.gyro_scale_sigma or noise.gyro_misalign_sigma or noise.accel_scale_sigma
                or noise.accel_misalign_sigma) and K >= 2
    out = [preintegration_params(noise, frame, earth_rotation) for _ in range(K)]
    if not turn:
        return out
    T = np.add.reduceat(seg.dt, seg.start[:-1])
    wbar = np.add.reduceat(seg.gyro * seg.dt[:, None], seg.start[:-1]) / T[:, None]
    fbar = np.add.reduceat(seg.accel * seg.dt[:, None], seg.start[:-1]) / T[:, None]
    t_mid = np.cumsum(T) - 0.5 * T

    def turn_density(x, s, m, centre):
        d = x - centre
        # the net (signed) manoeuvre within the window: a roll into a bank and out of it again cancel, as the error
        # they make does (a scale or misalignment error times the net angle)
        w = d if SIGNED_TURNS else np.abs(d)
        c = np.vstack([np.zeros((1, 3)), np.cumsum(w * T[:, None], axis=0)])
        lo = np.searchsorted(t_mid, t_mid - window_s, side="left")
        hi = np.searchsorted(t_mid, t_mid + window_s, side="right")
        aw = np.abs(d) * np.abs(c[hi] - c[lo])
        return s ** 2 * aw + m ** 2 * (aw.sum(1, keepdims=True) - aw)
    # the gyro's reference is zero rate, not the flight's median: a flight circling more than half its time
    # (a calibration orbit) has its circling rate as median, and its straight lines then got the turn noise
    # (heading sigmas 5x too large there)
    qg = turn_density(wbar, noise.gyro_scale_sigma, np.sqrt(GYRO_MISALIGN_SHARE) * noise.gyro_misalign_sigma, 0.0)
    qa = turn_density(fbar, noise.accel_scale_sigma, noise.accel_misalign_sigma, np.median(fbar, axis=0))
    for k, p in enumerate(out):
        p.setGyroscopeCovariance(np.diag(noise.gyro_arw ** 2 + qg[k]))
        p.setAccelerometerCovariance(np.diag(noise.accel_vrw ** 2 + qa[k]))
    return out


def keyframe_gravity(frame: NavFrame, p_nav: np.ndarray) -> np.ndarray:
    """Normal gravity (K,3) m/s^2 in nav axes at nav points p_nav (m): the local Down there, which tilts from nav
    Down by distance / earth radius (0.009 deg per km), times normal gravity at the point's latitude and height."""
    geo = ecef_to_geodetic(frame.to_ecef(p_nav)).reshape(-1, 3)
    gam = normal_gravity(geo[:, 0], geo[:, 2])
    down_nav = frame.R_nav_to_local_ned(p_nav).reshape(-1, 3, 3)[:, 2, :]
    return np.asarray(gam)[:, None] * down_nav


def interval_gravity(frame: NavFrame, p_nav_key: np.ndarray) -> np.ndarray:
    """Mean gravity (K-1,3) m/s^2, nav axes, of each keyframe interval of the track p_nav_key (K,3) m.

    gtsam takes gravity constant over an interval and applies it in the prediction (`PreintegrationParams`
    n_gravity), not in the preintegration: with each interval's own mean the velocity increment carries the
    integral of the varying gravity exactly for a linear variation (the position increment to g' T^3/12: 3e-6 m
    at 20 m/s), and the track can be corrected after the preintegration (`set_gravity`)."""
    g = keyframe_gravity(frame, p_nav_key)
    return 0.5 * (g[:-1] + g[1:])


def set_gravity(per_interval: list, gravity: np.ndarray) -> None:
    """Give each interval's parameters its gravity (K-1,3) m/s^2, in place: the factors built on them hold the
    same parameter objects and read gravity at every evaluation, so this needs no new preintegration."""
    for p, g in zip(per_interval, gravity):
        p.n_gravity = g


def rotation_compensated_accel(gyro: np.ndarray, accel: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Mean specific force (N,3) m/s^2, body FRD, re-expressed in the body axes at the START of each piece.

    gtsam's `integrateMeasurement` rotates a piece's specific force with the attitude at the start of the
    piece, whereas the body turns by gyro*dt during it: the velocity increment is then rotated by half a
    sample too little. In a coordinated turn that is an along-track error V r^2 dt/2 (0.5-0.9 mg at 100 Hz
    for 20-34 m/s and 13 deg/s) which the smoother reads as accelerometer bias, spoiling pitch. For constant
    rates over the piece the increment in start axes is f dt + (w x f) dt^2 / 2 to first order.
    """
    return accel + 0.5 * np.asarray(dt, float)[:, None] * np.cross(gyro, accel)


def preintegrate(params, seg: ImuSegments, biases, per_interval: list | None = None,
                 which: np.ndarray | None = None) -> list:
    """One PreintegratedCombinedMeasurements per keyframe interval (or per interval of `which`); `biases[k]` is
    the linearisation bias, `per_interval[k]` (optional) replaces `params` for interval k. The specific force is
    rotation compensated (`rotation_compensated_accel`)."""
    out = []
    gyro, dt = seg.gyro, seg.dt.tolist()          # Python floats: pybind takes them faster than numpy scalars
    accel = rotation_compensated_accel(seg.gyro, seg.accel, seg.dt)
    start = seg.start.tolist()
    for k in (range(len(start) - 1) if which is None else which):
        pk = per_interval[k] if per_interval is not None and per_interval[k] is not None else params
        pim = gtsam.PreintegratedCombinedMeasurements(pk, biases[k])
        f = pim.integrateMeasurement
        a, b = start[k], start[k + 1]
        for acc_j, gyro_j, dt_j in zip(accel[a:b], gyro[a:b], dt[a:b]):
            f(acc_j, gyro_j, dt_j)
        out.append(pim)
    return out


def bias_moved(noise: ImuErrorModel, seg: ImuSegments, bias_hat: np.ndarray, bias: np.ndarray,
               share: float = 0.01) -> np.ndarray:
    """Keyframe intervals (bool (K-1,)) whose preintegration must be redone about `bias` (K-1,6: accelerometer
    m/s^2, gyro rad/s) rather than corrected from its linearisation bias `bias_hat` to first order.

    gtsam's factor corrects a preintegration for a bias change d to first order (its bias Jacobians); what that
    misses is second order: ~(dg T)^2 / 2 in rotation and dg T (da T / 2 + dg T |f| T / 6) in velocity (dg gyro, da
    accelerometer change, f the specific force). An interval is redone when either exceeds `share` of the
    interval's own white noise (gyro ARW and accelerometer VRW over T): for an ADIS16488-class IMU that takes a
    gyro bias beyond ~0.05 deg/s (with a 1 mg accelerometer bias), a consumer IMU's always does.
    """
    T = np.add.reduceat(seg.dt, seg.start[:-1])
    f = np.linalg.norm(np.add.reduceat(seg.accel * seg.dt[:, None], seg.start[:-1]), axis=1) / T
    d = np.asarray(bias, float) - np.asarray(bias_hat, float)
    dg = np.linalg.norm(d[:, 3:], axis=1) * T
    da = np.linalg.norm(d[:, :3], axis=1) * T
    e_rot = 0.5 * dg ** 2
    e_vel = dg * (0.5 * da + dg * f * T / 6.0)
    return (e_rot > share * noise.gyro_arw * np.sqrt(T)) | (e_vel > share * noise.accel_vrw * np.sqrt(T))
