"""Earth model (WGS84 J2 gravitation, earth rate) and a vectorised ECEF strapdown integrator.

Used to prove the flight simulator self-consistent: integrating its noise-free IMU increments must
reproduce the true trajectory. The integration runs in the inertial frame that coincides with ECEF at
the first epoch (no Coriolis terms): attitude by a parallel prefix product of the per-interval
rotations (two-sample coning correction), velocity increments with rotation and sculling corrections,
and gravitation by Picard iteration along the integrated path — every step vectorised with NumPy.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.fields.constants import A_WGS84, GM_WGS84, J2_WGS84, OMEGA_EARTH, OMEGA_IE_E


def gravitation_ecef(p_ecef: np.ndarray) -> np.ndarray:
    """Gravitational acceleration (m/s^2, no centrifugal term) of the J2 earth at ECEF points (m); (...,3)."""
    p = np.asarray(p_ecef, float)
    r2 = np.sum(p * p, axis=-1)
    r = np.sqrt(r2)
    z2r2 = p[..., 2] ** 2 / r2
    k = 1.5 * J2_WGS84 * A_WGS84 ** 2 / r2
    f = -GM_WGS84 / (r2 * r)
    g = np.empty_like(p)
    g[..., 0] = f * (1 + k * (1 - 5 * z2r2)) * p[..., 0]
    g[..., 1] = f * (1 + k * (1 - 5 * z2r2)) * p[..., 1]
    g[..., 2] = f * (1 + k * (3 - 5 * z2r2)) * p[..., 2]
    return g


def gravity_ecef(p_ecef: np.ndarray) -> np.ndarray:
    """Gravity (gravitation + centrifugal, m/s^2) at ECEF points (m), as felt in the earth-fixed frame."""
    p = np.asarray(p_ecef, float)
    return gravitation_ecef(p) + OMEGA_EARTH ** 2 * np.stack([p[..., 0], p[..., 1], 0 * p[..., 2]], -1)


def _Rz(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of quaternion arrays (x, y, z, w last, scipy's order)."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], -1)


def prefix_product(rots: Rotation) -> Rotation:
    """Cumulative products r0 * r1 * ... * rk for every k (Hillis-Steele scan, log2(N) vectorised passes)."""
    q = rots.as_quat()
    n = len(q)
    d = 1
    while d < n:
        q = np.concatenate([q[:d], _qmul(q[:-d], q[d:])])
        d *= 2
    return Rotation.from_quat(q)


def integrate_strapdown_ecef(t: np.ndarray, dtheta: np.ndarray, dvel: np.ndarray, p0_ecef: np.ndarray,
                             v0_ecef: np.ndarray, R0_body_to_ecef: np.ndarray, iterations: int = 12
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Integrate IMU increments (rad, m/s, body, over (t[k-1], t[k]]) from the state at t[0].

    Returns p_ecef (N,3) m, v_ecef (N,3) m/s and R_body_to_ecef (N,3,3) at every t. `dtheta[0]`,
    `dvel[0]` (the interval ending at t[0]) only feed the two-sample corrections of the first step.
    """
    t = np.asarray(t, float)
    dt = np.diff(t)
    tau = t - t[0]
    dth, dv = np.asarray(dtheta, float), np.asarray(dvel, float)
    # attitude body -> inertial (= ECEF at t[0]): coning-corrected rotation vector per interval
    phi = dth[1:] + np.cross(dth[:-1], dth[1:]) / 12.0
    steps = Rotation.concatenate([Rotation.from_matrix(R0_body_to_ecef), Rotation.from_rotvec(phi)])
    R_body_to_inertial = prefix_product(steps)
    # velocity increments in the inertial frame, resolved with the attitude at the interval start
    # second-order rotation term (1/6) dth x (dth x dv): without it turns leave an O(dt^2) velocity bias
    dv_b = (dv[1:] + 0.5 * np.cross(dth[1:], dv[1:]) + np.cross(dth[1:], np.cross(dth[1:], dv[1:])) / 6.0
            + (np.cross(dth[:-1], dv[1:]) + np.cross(dv[:-1], dth[1:])) / 12.0)
    dv_i = R_body_to_inertial[:-1].apply(dv_b)
    R_i_to_e = np.swapaxes(_Rz(OMEGA_EARTH * tau), -1, -2)  # ECEF rotates by +w*tau about z
    r0 = np.asarray(p0_ecef, float)
    v0_i = np.asarray(v0_ecef, float) + np.cross(OMEGA_IE_E, r0)
    sum_dv = np.vstack([np.zeros(3), np.cumsum(dv_i, axis=0)])
    # first guess: gravitation of the start point along the whole path, then Picard iterations
    r_i = r0 + v0_i * tau[:, None]
    for _ in range(iterations):
        g_i = np.einsum("nji,nj->ni", R_i_to_e, gravitation_ecef(np.einsum("nij,nj->ni", R_i_to_e, r_i)))
        g_int = np.vstack([np.zeros(3), np.cumsum(0.5 * (g_i[:-1] + g_i[1:]) * dt[:, None], axis=0)])
        v_i = v0_i + sum_dv + g_int
        r_new = r0 + np.vstack([np.zeros(3), np.cumsum(0.5 * (v_i[:-1] + v_i[1:]) * dt[:, None], axis=0)])
        change = np.max(np.abs(r_new - r_i))
        r_i = r_new
        if change < 1e-6:
            break
    p_e = np.einsum("nij,nj->ni", R_i_to_e, r_i)
    v_e = np.einsum("nij,nj->ni", R_i_to_e, v_i) - np.cross(OMEGA_IE_E, p_e)
    R_body_to_ecef = R_i_to_e @ R_body_to_inertial.as_matrix()
    return p_e, v_e, R_body_to_ecef
