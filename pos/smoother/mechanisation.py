"""IMU mechanisation of many keyframe intervals at once, as gtsam computes it: tangent-space preintegration of
each interval's pieces (`TangentPreintegration`) and the prediction of a navigation state from it
(`NavState::correctPIM`, first-order Coriolis, `retract`).

Why not gtsam itself: densifying an hour at 10 Hz needs the preintegrated state after every one of 720,000 IMU
pieces and a prediction at 36,000 output times; one `integrateMeasurement` call per piece costs 5 us and the
covariance it also propagates is not needed there. Here the intervals are the vector dimension and the pieces of
an interval the (short) loop, so the cost is ~200 NumPy steps whatever the flight's length. The means equal
gtsam's to rounding (`tests/pos/smoother/test_pos_mechanisation.py`).

Frames: nav (NED, gtsam's navigation frame), body FRD; rates rad/s and m/s^2 (mean rates of each piece).
"""
from __future__ import annotations

import numpy as np

_SMALL = 1e-8   # rad: below it the series forms of the SO(3) functions (their float error would exceed theirs)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices (..., 3, 3) of vectors (..., 3)."""
    z = np.zeros_like(v[..., 0])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def so3_exp(theta: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3) (rad), Rodrigues' formula."""
    t2 = np.sum(theta * theta, axis=-1)
    t = np.sqrt(t2)
    small = t < _SMALL
    ts = np.where(small, 1.0, t)
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(ts) / ts)
    # 1 - cos written with the half angle: no cancellation for small angles
    b = np.where(small, 0.5 - t2 / 24.0, 2.0 * np.sin(0.5 * ts) ** 2 / ts ** 2)
    W = skew(theta)
    return np.eye(3) + a[..., None, None] * W + b[..., None, None] * (W @ W)


def apply_inv_dexp(theta: np.ndarray, v: np.ndarray) -> np.ndarray:
    """J_r(theta)^-1 v (..., 3): the tangent-space rate of a body rate v at rotation vector theta (gtsam's
    `DexpFunctor::applyInvDexp`): v + theta x v / 2 + c theta x (theta x v), c = 1/t^2 - (1 + cos t)/(2 t sin t)."""
    t2 = np.sum(theta * theta, axis=-1)
    t = np.sqrt(t2)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    c = np.where(small, 1.0 / 12.0 + t2 / 720.0, 1.0 / ts ** 2 - (1.0 + np.cos(ts)) / (2.0 * ts * np.sin(ts)))
    tv = np.cross(theta, v)
    return v + 0.5 * tv + c[..., None] * np.cross(theta, tv)


def _cross(a: tuple, b: tuple) -> tuple:
    """Cross product of vectors given as component arrays (x, y, z)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def preintegrate_means(gyro: np.ndarray, accel: np.ndarray, dt: np.ndarray, lane: np.ndarray, step: np.ndarray,
                       n_lanes: int, record: np.ndarray | None = None):
    """Tangent preintegration (theta, position, velocity; rad, m, m/s in the start body axes) of many intervals.

    Pieces (N,) with bias-corrected mean rates `gyro`, `accel` (N,3) and durations `dt` (N,) s belong to interval
    `lane` (N,) as its `step`-th piece (0, 1, ...). `record` (N,) bool marks the pieces after which the state is
    wanted. Returns (theta, p, v) after every recorded piece, in the order of the recorded pieces, and the same of
    every lane after its last piece.

    The lanes advance together, one piece per step (a lane out of pieces takes zero-length ones, which change
    nothing); vectors are kept as x, y, z component arrays, and each piece is gtsam's update: the specific force
    rotated by Exp(theta) (Rodrigues on the vector), theta advanced by J_r(theta)^-1 w dt."""
    L = int(step.max()) + 1 if len(step) else 0
    shape = (L, n_lanes)
    h = np.zeros(shape)
    h[step, lane] = dt
    w = [np.zeros(shape) for _ in range(3)]
    a = [np.zeros(shape) for _ in range(3)]
    for c in range(3):
        w[c][step, lane] = gyro[:, c]
        a[c][step, lane] = accel[:, c]
    rec = np.zeros(len(dt), bool) if record is None else np.asarray(record, bool)
    order = np.flatnonzero(rec)
    out_step, out_lane = step[order], lane[order]
    by_step = np.argsort(out_step, kind="stable")
    bounds = np.searchsorted(out_step[by_step], np.arange(L + 1))
    out = (np.empty((len(order), 3)), np.empty((len(order), 3)), np.empty((len(order), 3)))
    th = [np.zeros(n_lanes) for _ in range(3)]
    pp = [np.zeros(n_lanes) for _ in range(3)]
    vv = [np.zeros(n_lanes) for _ in range(3)]
    for s in range(L):
        t2 = th[0] * th[0] + th[1] * th[1] + th[2] * th[2]
        t = np.sqrt(t2)
        small = t < 1e-4
        ts = np.where(small, 1.0, t)
        sn, cs = np.sin(ts), np.cos(ts)
        A = np.where(small, 1.0 - t2 / 6.0, sn / ts)
        B = np.where(small, 0.5 - t2 / 24.0, 2.0 * np.sin(0.5 * ts) ** 2 / (ts * ts))
        C = np.where(small, 1.0 / 12.0 + t2 / 720.0, 1.0 / (ts * ts) - (1.0 + cs) / (2.0 * ts * sn))
        ac = (a[0][s], a[1][s], a[2][s])
        ta = _cross(th, ac)
        tta = _cross(th, ta)
        hs = h[s]
        half = 0.5 * hs * hs
        for c in range(3):
            an = ac[c] + A * ta[c] + B * tta[c]        # Exp(theta) a
            pp[c] += vv[c] * hs + an * half
            vv[c] += an * hs
        wc = (w[0][s], w[1][s], w[2][s])
        tw = _cross(th, wc)
        ttw = _cross(th, tw)
        th = [th[c] + (wc[c] + 0.5 * tw[c] + C * ttw[c]) * hs for c in range(3)]
        o = by_step[bounds[s]:bounds[s + 1]]
        if len(o):
            ln = out_lane[o]
            for q, src in enumerate((th, pp, vv)):
                out[q][o] = np.stack([src[0][ln], src[1][ln], src[2][ln]], axis=1)
    last = tuple(np.stack(x, axis=1) for x in (th, pp, vv))
    return out, last


def _exp_integrals(phi: np.ndarray):
    """For rotation vectors phi (...,3) = Omega T: J = (1/T) int_0^T Exp(Omega s) ds and
    N = (1/T^2) int_0^T int_0^s Exp(Omega r) dr ds, (...,3,3) each (the SO(3) left Jacobian and its integral)."""
    t2 = np.sum(phi * phi, axis=-1)
    t = np.sqrt(t2)
    small = t < 1e-3
    ts = np.where(small, 1.0, t)
    s, c = np.sin(ts), np.cos(ts)
    j1 = np.where(small, 0.5 - t2 / 24.0, (1.0 - c) / ts ** 2)
    j2 = np.where(small, 1.0 / 6.0 - t2 / 120.0, (ts - s) / ts ** 3)
    n2 = np.where(small, 1.0 / 24.0 - t2 / 720.0, (0.5 * ts ** 2 + c - 1.0) / ts ** 4)
    W = skew(phi)
    W2 = W @ W
    eye = np.eye(3)
    return eye + j1[..., None, None] * W + j2[..., None, None] * W2, 0.5 * eye + j2[..., None, None] * W + \
        n2[..., None, None] * W2


def predict(R_body_to_nav_0: np.ndarray, p0: np.ndarray, v0: np.ndarray, theta: np.ndarray, dp: np.ndarray,
            dv: np.ndarray, T: np.ndarray, gravity: np.ndarray, omega: np.ndarray | None = None):
    """Navigation states (R_body_to_nav (N,3,3), p (N,3) m, v (N,3) m/s) predicted from start states
    R_body_to_nav_0, p0, v0 over T (N,) s by preintegrated (theta, dp, dv) (N,3), with gravity (N,3) or (3,)
    m/s^2 constant in nav axes and the nav frame's rotation rate `omega` (3,) rad/s (None: a non-rotating frame).

    gtsam 4.3 predicts in a rotating nav frame exactly (Coriolis, centrifugal and the turning of the frame under
    the body during the interval): in the inertial frame that coincides with nav at the start the state moves by
    the preintegrated increments and the gravity (constant in nav, so turning in inertial axes), and the result is
    rotated back by Exp(-omega T)."""
    T = np.asarray(T, float)
    g = np.broadcast_to(np.asarray(gravity, float), p0.shape)
    w = np.zeros(3) if omega is None else np.asarray(omega, float)
    phi = T[:, None] * w
    J, N = _exp_integrals(phi)
    wp = np.cross(w, p0)
    vi = v0 + wp + np.einsum("nij,nj->ni", R_body_to_nav_0, dv) + T[:, None] * np.einsum("nij,nj->ni", J, g)
    pi = p0 + (v0 + wp) * T[:, None] + np.einsum("nij,nj->ni", R_body_to_nav_0, dp) + \
        (T * T)[:, None] * np.einsum("nij,nj->ni", N, g)
    R_inertial_to_nav = so3_exp(-phi)   # the inertial frame of the start to nav at the end
    p = np.einsum("nij,nj->ni", R_inertial_to_nav, pi)
    v = np.einsum("nij,nj->ni", R_inertial_to_nav, vi) - np.cross(w, p)
    return R_inertial_to_nav @ R_body_to_nav_0 @ so3_exp(theta), p, v
