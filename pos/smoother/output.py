"""From keyframe states to the trajectory file: IMU-rate densification between keyframes and the conversion
of nav-frame states and covariances to geodetic position, local NED velocity, roll/pitch/heading and the
INTERFACES.md sigma columns.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.fields.crs import ecef_to_geodetic
from dgcal.fields.io.formats import Trajectory
from dgcal.fields.frames import rph_from_R_body_to_ned
from dgcal.pos.ins.nav_frame import NavFrame
from dgcal.pos.smoother.mechanisation import predict, preintegrate_means, so3_exp
from dgcal.pos.smoother.preintegration import rotation_compensated_accel, split_at_keyframes


def euler_rate_matrix(rph_deg: np.ndarray) -> np.ndarray:
    """d(roll, pitch, heading) / d(delta_theta_body) (N,3,3) for R_body_to_ned perturbed as R Exp(delta_theta)."""
    r, p = np.radians(rph_deg[:, 0]), np.radians(rph_deg[:, 1])
    sr, cr, tp, cp = np.sin(r), np.cos(r), np.tan(p), np.cos(p)
    z, o = np.zeros_like(r), np.ones_like(r)
    return np.stack([np.stack([o, sr * tp, cr * tp], -1),
                     np.stack([z, cr, -sr], -1),
                     np.stack([z, sr / cp, cr / cp], -1)], -2)


def to_trajectory(frame: NavFrame, t: np.ndarray, p_nav: np.ndarray, v_nav: np.ndarray,
                  R_body_to_nav: np.ndarray, cov_p_nav: np.ndarray | None = None,
                  cov_rot_b: np.ndarray | None = None) -> Trajectory:
    """Trajectory (geodetic, local NED velocity and attitude, sigmas in m and degrees) from nav-frame states.

    cov_p_nav (N,3,3) m^2 in nav axes; cov_rot_b (N,3,3) rad^2, right (body) rotation perturbation.
    """
    R_nav_to_ned = frame.R_nav_to_local_ned(p_nav)
    geo = ecef_to_geodetic(frame.to_ecef(p_nav))
    v_ned = np.einsum("nij,nj->ni", R_nav_to_ned, v_nav)
    R_body_to_ned = R_nav_to_ned @ R_body_to_nav
    rph = rph_from_R_body_to_ned(R_body_to_ned)
    sigma = None
    if cov_p_nav is not None and cov_rot_b is not None:
        Cp = R_nav_to_ned @ cov_p_nav @ np.swapaxes(R_nav_to_ned, 1, 2)
        J = euler_rate_matrix(rph)
        Ca = J @ cov_rot_b @ np.swapaxes(J, 1, 2)
        sigma = np.column_stack([np.sqrt(np.maximum(np.einsum("nii->ni", Cp), 0.0)),
                                 np.degrees(np.sqrt(np.maximum(np.einsum("nii->ni", Ca), 0.0)))])
    return Trajectory(t=np.asarray(t, float), lat=geo[:, 0], lon=geo[:, 1], h=geo[:, 2], v_ned=v_ned, rph=rph,
                      sigma=sigma)


def solution_trajectory(sol) -> Trajectory:
    """The keyframe states of a NavSolution as a Trajectory (with sigmas when covariances are present)."""
    cov_p = sol.cov_p_nav if sol.cov_pose is not None else None
    cov_r = sol.cov_pose[:, :3, :3] if sol.cov_pose is not None else None
    return to_trajectory(sol.frame, sol.t, sol.p_nav, sol.v_nav, sol.R_body_to_nav, cov_p, cov_r)


def output_times(t_key: np.ndarray, rate_hz: float) -> np.ndarray:
    """The keyframes (GPS s) plus the multiples of 1/rate_hz between them; a multiple within a thousandth of a
    step of a keyframe is the keyframe (at 1e9 s, float multiples of 0.1 s are off by up to a microsecond: a
    tolerance on the difference alone could drop the keyframe and misplace every later interval)."""
    step = 1.0 / rate_hz
    k0 = np.ceil(t_key[0] / step - 1e-6)
    n = int(np.floor(t_key[-1] / step - k0 + 1e-6)) + 1
    grid = (k0 + np.arange(max(n, 0))) * step
    grid = grid[(grid > t_key[0]) & (grid < t_key[-1])]
    j = np.clip(np.searchsorted(t_key, grid), 1, len(t_key) - 1)
    near = np.minimum(np.abs(grid - t_key[j - 1]), np.abs(grid - t_key[j]))
    return np.union1d(t_key, grid[near > 1e-3 * step])


def densify(sol, problem, imu, rate_hz: float) -> Trajectory:
    """The trajectory at `rate_hz` (plus the keyframes): IMU mechanisation from each keyframe with its estimated
    biases and its interval's gravity (as gtsam's preintegration and prediction compute it,
    `dgcal.pos.smoother.mechanisation`, every interval at once), the small closure error at the next keyframe spread
    linearly over the interval; sigmas interpolated linearly in variance between keyframes."""
    t_key = sol.t
    K = len(t_key)
    t_out = output_times(t_key, rate_hz)
    seg = split_at_keyframes(imu.t, imu.gyro_rad_s, imu.accel_m_s2, t_out, imu.dt[0])
    key_of = np.searchsorted(t_out, t_key - 1e-9)
    # each output sample's keyframe interval, and each piece's interval and place in it
    out_lane = np.clip(np.searchsorted(key_of, np.arange(len(t_out)), side="right") - 1, 0, K - 2)
    lane = np.repeat(out_lane[:-1], np.diff(seg.start))
    first = seg.start[key_of[:-1]]
    step = np.arange(len(seg.dt)) - first[lane]
    record = np.zeros(len(seg.dt), bool)
    record[seg.start[1:] - 1] = True          # the last piece before each output time
    b = sol.bias[lane]
    acc = rotation_compensated_accel(seg.gyro, seg.accel, seg.dt) - b[:, :3]
    (th, dp, dv), _ = preintegrate_means(seg.gyro - b[:, 3:], acc, seg.dt, lane, step, K - 1, record)
    T = np.cumsum(seg.dt)
    T = T[record] - np.r_[0.0, T][first][lane[record]]
    k = lane[record]
    gravity = np.array([p.n_gravity for p in problem.interval_params])[k]
    omega = problem.params.getOmegaCoriolis() if problem.params.getOmegaCoriolis() is not None else None
    R_body_to_nav_pred, Pp, Vp = predict(sol.R_body_to_nav[k], sol.p_nav[k], sol.v_nav[k], th, dp, dv, T, gravity,
                                         omega)
    P = np.empty((len(t_out), 3))
    Vv = np.empty((len(t_out), 3))
    R_body_to_nav_out = np.empty((len(t_out), 3, 3))
    # closure: spread the mismatch with the next keyframe linearly in time
    end = key_of[1:]
    dpk = sol.p_nav[1:] - Pp[end - 1]
    dvk = sol.v_nav[1:] - Vp[end - 1]
    drk = Rotation.from_matrix(np.swapaxes(R_body_to_nav_pred[end - 1], 1, 2) @ sol.R_body_to_nav[1:]).as_rotvec()
    i = np.arange(1, len(t_out))
    kk = out_lane[:-1]
    w = (t_out[i] - t_key[kk]) / (t_key[kk + 1] - t_key[kk])
    P[i] = Pp + w[:, None] * dpk[kk]
    Vv[i] = Vp + w[:, None] * dvk[kk]
    R_body_to_nav_out[i] = R_body_to_nav_pred @ so3_exp(w[:, None] * drk[kk])
    P[key_of], Vv[key_of], R_body_to_nav_out[key_of] = sol.p_nav, sol.v_nav, sol.R_body_to_nav
    cov_p = cov_r = None
    if sol.cov_pose is not None:
        cp, cr = sol.cov_p_nav, sol.cov_pose[:, :3, :3]
        cov_p = np.stack([np.stack([np.interp(t_out, t_key, cp[:, i, j]) for j in range(3)], -1)
                          for i in range(3)], -2)
        cov_r = np.stack([np.stack([np.interp(t_out, t_key, cr[:, i, j]) for j in range(3)], -1)
                          for i in range(3)], -2)
    return to_trajectory(sol.frame, t_out, P, Vv, R_body_to_nav_out, cov_p, cov_r)
