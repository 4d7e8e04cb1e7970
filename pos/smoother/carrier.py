"""Double-difference carrier-phase and code factors of the TC smoother (one per keyframe, held linearised).

A keyframe's factor holds all its double differences (``dgcal.pos.gnss.dd.DDEpoch``: phase with the arcs'
integer ambiguities, and code) as measurements of the rover antenna's range differences,
``h_i(X) = |s_i - p(X)| - |s_ref - p(X)|`` with ``p(X) = ecef_T_nav (t + R lever)`` (ECEF m), the antenna at
the lever arm of the IMU pose X. The receiver clocks cancel; no state is added.

**Time-correlated errors** (multipath): each double difference's error is taken as a first-order
autoregressive sequence along its track (the same pair of arcs at consecutive keyframes) with coefficient
``rho = share * exp(-dt / tau)`` (``share``: the time-correlated share of the variance, which matches the
lag-one autocorrelation of white noise plus a Gauss-Markov error). A tracked row enters pre-whitened,
``(h_k - z_k) - rho (h_{k-1} - z_{k-1})``, so the factor spans keyframes k-1 and k (the block-tridiagonal
structure of the smoother is kept); its covariance is ``C * M`` with C the double-difference covariance
and ``M = 1 - rho^2`` unless both rows are new (1). With white errors the smoother would average the
epochs bridged by the IMU as independent and report sigmas several times too small.

Jacobians: Pose3 local coordinates [rotation, translation] (body axes): ``dp/dtheta = -R [lever]x``,
``dp/dt = R`` in nav axes, ``dh_i/dp = -(e_i - e_ref)`` with e the unit vectors antenna -> satellite.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import gtsam
import numpy as np

from dgcal.pos.gnss.dd import DDEpoch
from dgcal.pos.ins.nav_frame import NavFrame


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def range_differences(dd: DDEpoch, pose, lever_b: np.ndarray, frame: NavFrame) -> tuple[np.ndarray, np.ndarray]:
    """h (n,) m: |s_i - p| - |s_ref - p| at the antenna of `pose` (gtsam Pose3 in nav), and dh/dpose (n,6)."""
    M = pose.matrix()
    lever = np.asarray(lever_b, float)
    return _rows_at_antenna(dd.sat_pos, dd.ref_pos, _antenna_ecef(M[:3, :3], M[:3, 3], lever, frame),
                            frame.R_nav_to_ecef @ M[:3, :3], lever)


def _antenna_ecef(R_body_to_nav: np.ndarray, p: np.ndarray, lever: np.ndarray, frame: NavFrame) -> np.ndarray:
    """ECEF position (m) of the antenna at the lever arm of poses R_body_to_nav (...,3,3) and p (...,3) nav m."""
    return (p + np.einsum("...ij,j->...i", R_body_to_nav, lever)) @ frame.R_nav_to_ecef.T + frame.origin_ecef


def _rows_at_antenna(sat_pos: np.ndarray, ref_pos: np.ndarray, p_ant: np.ndarray, R_body_to_ecef: np.ndarray,
                     lever: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """h (n,) and dh/dpose (n,6) of rows with satellite and reference positions (n,3) ECEF m seen from the antenna
    at `p_ant` ((3,) or per row (n,3)), the body axes turned to ECEF by `R_body_to_ecef` ((3,3) or per row
    (n,3,3))."""
    di, dr = sat_pos - p_ant, ref_pos - p_ant
    ri = np.sqrt(np.einsum("ij,ij->i", di, di))
    rr = np.sqrt(np.einsum("ij,ij->i", dr, dr))
    # dh / d(body-axes translation) (n,3)
    G = ((dr / rr[:, None] - di / ri[:, None])[:, None, :] @ R_body_to_ecef)[:, 0]
    J = np.empty((len(ri), 6))
    J[:, 3:] = G
    J[:, :3] = G @ _skew(lever).T                                          # rows lever x g (np.cross is slow)
    return ri - rr, J


@dataclass
class DDFactorData:
    """What one keyframe's double-difference factor holds (also for residuals): the rows at keyframe k (float rows
    only where tracked), the previous keyframe's rows (or None), each row's index there (-1: new), its
    coefficient on the previous error (0 new, the AR coefficient for a tracked absolute row, 1 for a float row:
    a time difference) and the covariance of the combined rows."""

    k: int
    cur: DDEpoch
    prev: DDEpoch | None
    prev_index: np.ndarray
    rho: np.ndarray
    cov: np.ndarray

    @cached_property
    def whitener(self) -> np.ndarray:
        """W with W'W = cov^-1, W lower triangular (made once; every re-linearisation uses it)."""
        return np.linalg.inv(np.linalg.cholesky(self.cov))

    @cached_property
    def tracked(self) -> np.ndarray:
        """(n,) bool: the rows tracked from `prev` with a non-zero coefficient."""
        return (self.prev_index >= 0) & (self.rho != 0)

    @cached_property
    def spans_prev(self) -> bool:
        """The factor spans the previous keyframe too: some rows are whitened against its rows."""
        return self.prev is not None and bool(self.tracked.any())

    @cached_property
    def tracked_prev(self) -> tuple[DDEpoch, np.ndarray, np.ndarray]:
        """The rows of `prev` that `tracked` rows continue, the order taking them to those rows, their coefficients
        (made once; every re-linearisation uses them)."""
        pj = self.prev_index[self.tracked]
        taken = np.isin(np.arange(self.prev.n), pj)
        return self.prev.subset(taken), np.searchsorted(np.nonzero(taken)[0], pj), self.rho[self.tracked]

    def raw_residuals(self, pose, lever_b, frame) -> np.ndarray:
        """Unwhitened residuals h - z (m) of the rows at keyframe k (float rows: including their ambiguity)."""
        return range_differences(self.cur, pose, lever_b, frame)[0] - self.cur.z


def whitening(cur: DDEpoch, prev: DDEpoch | None, dt: float, phase: tuple[float, float],
              code: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows kept (float rows need their track at `prev`), their index in `prev` (-1 if new), their coefficient on
    the previous error and the covariance of the combined rows (see the module docstring).

    phase/code: (tau s, share) of the time-correlated errors (tau <= 0: white). With lag-one coefficients
    c_a, c_b of two rows and r the AR coefficient of their kind, the combined errors e_k - c e_{k-1} have the
    covariance C_ab (1 - (c_a + c_b) r + c_a c_b); the time differences of float rows are counted twice as
    uncertain (consecutive differences share an epoch, which is not modelled: never over-confident).
    """
    idx = np.full(cur.n, -1)
    if prev is not None:
        where = {tr: j for j, tr in enumerate(prev.track)}
        idx = np.array([where.get(tr, -1) for tr in cur.track], dtype=int)
    keep = (cur.mode == 0) | (idx >= 0)
    idx = idx[keep]
    kind = cur.kind[keep]
    mode = cur.mode[keep]
    r = np.zeros(len(idx))
    for kd, (tau, share) in ((0, phase), (1, code)):
        if tau > 0 and share > 0 and np.isfinite(dt):
            r[kind == kd] = share * np.exp(-dt / tau)
    coef = np.where(idx < 0, 0.0, np.where(mode == 1, 1.0, r))
    sub = cur.subset(keep)
    C = sub.covariance()
    M = 1.0 - (coef[:, None] + coef[None, :]) * r[:, None] + coef[:, None] * coef[None, :]
    td = mode == 1
    M[np.ix_(td, td)] *= 2.0
    return keep, idx, coef, C * M


def _dd_model(X_prev: int | None, X_cur: int, data: DDFactorData, lever_b: np.ndarray, frame: NavFrame):
    """Keys, noise model and error function `error(values, jacobians: bool) -> (e (n,) m, [H (n,6) per key])` of
    one keyframe's double differences (keys X_prev (may be None) and X_cur)."""
    lever = np.asarray(lever_b, float)
    cur = data.cur
    tracked = data.tracked
    use_prev = X_prev is not None and data.spans_prev
    if use_prev:
        prev_rows, order, rho_t = data.tracked_prev
    keys = [X_prev, X_cur] if use_prev else [X_cur]

    def error(values, jacobians: bool):
        pose = values.atPose3(keys[-1])
        h, J = range_differences(cur, pose, lever, frame)
        e = h - cur.z
        H = []
        if use_prev:
            hp, Jp = range_differences(prev_rows, values.atPose3(keys[0]), lever, frame)
            e[tracked] -= rho_t * (hp - prev_rows.z)[order]
            if jacobians:
                Jprev = np.zeros((cur.n, 6))
                Jprev[tracked] = -rho_t[:, None] * Jp[order]
                H = [Jprev, J]
        elif jacobians:
            H = [J]
        return e, H

    return keys, data.cov, error


def dd_factor(X_prev: int | None, X_cur: int, data: DDFactorData, lever_b: np.ndarray, frame: NavFrame):
    """The gtsam CustomFactor of one keyframe's double differences (keys X_prev (may be None) and X_cur): exact,
    but gtsam hands every Python factor a copy of all the values at each evaluation (2 s an iteration for 900
    keyframes): the smoother uses `linear_dd_factor`."""
    keys, cov, model = _dd_model(X_prev, X_cur, data, lever_b, frame)

    def error(this, values, H):
        e, J = model(values, H is not None)
        if H is not None:
            for i, Ji in enumerate(J):
                H[i] = Ji
        return e

    return gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(cov), keys, error)


def linear_dd_factor(X_prev: int | None, X_cur: int, data: DDFactorData, lever_b: np.ndarray, frame: NavFrame,
                     values, model: tuple | None = None):
    """One keyframe's double differences linearised at `values` (a gtsam LinearContainerFactor: whitened Jacobian
    and residual, evaluated at other values through the poses' local coordinates). What the linearisation leaves
    out is second order: |dp|^2 / (2 range) in position (2.5e-8 m for 1 m) and |lever| |dtheta|^2 / 2 in attitude
    (1e-7 m for 0.03 deg at a 1 m lever arm), so the smoother re-linearises where the poses moved beyond those
    (`dgcal.pos.smoother.batch.relinearise_dd`). `model`: (keys, e, H) already evaluated at `values`
    (`linear_dd_factors` evaluates every keyframe's in one pass)."""
    if model is None:
        keys, _, error = _dd_model(X_prev, X_cur, data, lever_b, frame)
        e, H = error(values, True)
    else:
        keys, e, H = model
    # whiten as gtsam's Gaussian model does: R'R = C^-1 with R upper triangular
    W = data.whitener                              # W' W = C^-1
    args = []
    for key, Hi in zip(keys, H):
        args += [key, W @ Hi]
    jf = gtsam.JacobianFactor(*args, -(W @ e), gtsam.noiseModel.Unit.Create(len(e)))
    lin = gtsam.Values()
    for key in keys:
        lin.insert(key, values.atPose3(key))
    return gtsam.LinearContainerFactor(jf, lin)


def linear_dd_factors(dd: dict, lever_b: np.ndarray, frame: NavFrame, values, X, R_body_to_nav: np.ndarray,
                      p: np.ndarray) -> dict:
    """keyframe -> `linear_dd_factor` of every keyframe's DDFactorData in `dd`, linearised at `values` (whose
    keyframe poses are R_body_to_nav (K,3,3) and p (K,3) nav m): the range differences of all keyframes' rows,
    and of the previous keyframes' rows they are whitened against, in one pass instead of two calls per keyframe."""
    sets = []
    for k, data in dd.items():
        sets.append((data.cur, k, None))
        if data.spans_prev:
            sets.append((data.prev, k - 1, data.prev_index[data.tracked]))
    hj = iter(_range_differences_of_sets(sets, R_body_to_nav, p, np.asarray(lever_b, float), frame))
    out = {}
    for k, data in dd.items():
        h, J = next(hj)
        e = h - data.cur.z
        if data.spans_prev:
            hp, Jp = next(hj)
            tr, rho = data.tracked, data.rho[data.tracked]
            e[tr] -= rho * (hp - data.prev.z[data.prev_index[tr]])
            Jprev = np.zeros((data.cur.n, 6))
            Jprev[tr] = -rho[:, None] * Jp
            model = ([X(k - 1), X(k)], e, [Jprev, J])
        else:
            model = ([X(k)], e, [J])
        out[k] = linear_dd_factor(X(k - 1) if data.prev is not None else None, X(k), data, lever_b, frame, values,
                                  model)
    return out


def _range_differences_of_sets(sets: list, R_body_to_nav: np.ndarray, p: np.ndarray, lever: np.ndarray,
                               frame: NavFrame) -> list:
    """`range_differences` of many row sets, each (DDEpoch, keyframe, rows or None for all) at its keyframe's pose
    (R_body_to_nav (K,3,3), p (K,3) nav m), computed in one pass: [(h (n,), J (n,6))] in the order of `sets`."""
    if not sets:
        return []
    idx = [np.arange(e.n) if r is None else r for e, _, r in sets]
    sat = np.concatenate([e.sat_pos[i] for (e, _, _), i in zip(sets, idx)])
    ref = np.concatenate([e.ref_pos[i] for (e, _, _), i in zip(sets, idx)])
    kk = np.repeat([k for _, k, _ in sets], [len(i) for i in idx])
    h, J = _rows_at_antenna(sat, ref, _antenna_ecef(R_body_to_nav, p, lever, frame)[kk],
                            (frame.R_nav_to_ecef @ R_body_to_nav)[kk], lever)
    cut = np.cumsum([len(i) for i in idx])[:-1]
    return list(zip(np.split(h, cut), np.split(J, cut)))


def keyframe_dd_factors(t_key: np.ndarray, dd_at_key: list, lever_b, frame: NavFrame, phase_corr: tuple,
                        code_corr: tuple, X, values) -> dict:
    """keyframe -> (factor, DDFactorData) for every keyframe with double differences; rows tracked from the
    previous keyframe are whitened against it when it is the previous epoch (dt <= 2.5 median steps). The factors
    are linearised at `values` (`linear_dd_factors`)."""
    data_at = {}
    dt_nom = float(np.median(np.diff(t_key))) if len(t_key) > 1 else 1.0
    for k, cur in enumerate(dd_at_key):
        if cur is None or cur.n == 0:
            continue
        prev = dd_at_key[k - 1] if k > 0 else None
        dt = float(t_key[k] - t_key[k - 1]) if k > 0 else np.inf
        if prev is None or dt > 2.5 * dt_nom:
            prev = None
        keep, idx, coef, cov = whitening(cur, prev, dt, phase_corr, code_corr)
        if not keep.any():
            continue
        data_at[k] = DDFactorData(k, cur.subset(keep), prev, idx, coef, cov)
    factors = linear_dd_factors(data_at, lever_b, frame, values, X, *keyframe_poses(values, len(t_key)))
    return {k: (factors[k], data) for k, data in data_at.items()}


def keyframe_poses(values, K: int) -> tuple[np.ndarray, np.ndarray]:
    """R_body_to_nav (K,3,3) and p (K,3) nav m of the keyframe poses in `values` (its only Pose3 variables, X(k))."""
    poses = gtsam.utilities.extractPose3(values)
    return poses[:, :9].reshape(K, 3, 3), poses[:, 9:].copy()


def dd_errors(data: DDFactorData, values, X, lever_b, frame: NavFrame) -> np.ndarray:
    """Unwhitened errors (m) of keyframe `data.k`'s double-difference factor at `values` (what the factor
    whitens with `data.cov`)."""
    x_prev = X(data.k - 1) if data.prev is not None else None
    return _dd_model(x_prev, X(data.k), data, lever_b, frame)[2](values, False)[0]


def dd_residuals(data: DDFactorData, values, X, lever_b, frame: NavFrame) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (m) of a keyframe's double differences and their sigmas (m): absolute rows h - z with the noise
    sigma of the row, float rows as the time difference (h - z)_k - (h - z)_{k-1} with its sigma."""
    lever = np.asarray(lever_b, float)
    cur = data.cur
    e = data.raw_residuals(values.atPose3(X(data.k)), lever, frame)
    sig = np.sqrt(np.diag(cur.covariance()))
    td = cur.mode == 1
    if td.any():
        prev = data.prev.subset(np.isin(np.arange(data.prev.n), data.prev_index[td]))
        order = np.searchsorted(np.nonzero(np.isin(np.arange(data.prev.n), data.prev_index[td]))[0],
                                data.prev_index[td])
        ep = range_differences(prev, values.atPose3(X(data.k - 1)), lever, frame)[0] - prev.z
        e[td] -= ep[order]
        sig[td] = np.sqrt(np.diag(data.cov))[td]
    return e, sig


def atmosphere_position_covariance(dd: dict, sol, lever_b, iono_ppm: float, tropo_zenith_m: float):
    """Position covariance (K,3,3) m^2, nav axes, that the differential-atmosphere errors of the fixed phase double
    differences cause: per keyframe the weighted least-squares map of the rows onto the antenna position,
    A = (G' W G)^-1 G' W, applied to the rows' atmosphere covariance (`DDEpoch.atmosphere_covariance`);
    keyframes without enough fixed rows take the nearest keyframe's. None if no keyframe has them."""
    K = len(sol.t)
    P = np.full((K, 3, 3), np.nan)
    picked = [(k, data.cur, np.flatnonzero((data.cur.kind == 0) & (data.cur.mode == 0))) for k, data in dd.items()]
    picked = [p for p in picked if len(p[2]) >= 4]
    for c in range(0, len(picked), _BUDGET_CHUNK):   # keyframes at a time: memory chunk x rows^2
        part = picked[c:c + _BUDGET_CHUNK]
        ks = np.array([k for k, _, _ in part])
        P[ks] = _fixed_rows_budget(part, sol, np.asarray(lever_b, float), iono_ppm, tropo_zenith_m)
    have = np.nonzero(np.isfinite(P[:, 0, 0]))[0]
    if len(have) == 0:
        return None
    near = have[np.clip(np.searchsorted(have, np.arange(K)), 0, len(have) - 1)]
    prev = have[np.clip(np.searchsorted(have, np.arange(K)) - 1, 0, len(have) - 1)]
    pick = np.where(np.abs(prev - np.arange(K)) < np.abs(near - np.arange(K)), prev, near)
    return P[pick]


_BUDGET_CHUNK = 1024


def _fixed_rows_budget(part: list, sol, lever: np.ndarray, iono_ppm: float, tropo_zenith_m: float) -> np.ndarray:
    """(k, 3, 3) position covariance (m^2, nav axes) for keyframes `part` = [(k, DDEpoch, fixed phase rows)], NaN
    where the rows do not fix the position (cond > 1e8): the loop of `atmosphere_position_covariance` as one batch,
    the rows padded to the longest keyframe (padding: no geometry, unit weight, no atmosphere)."""
    n = np.array([len(i) for _, _, i in part])
    m, nk = int(n.max()), len(part)
    kb = np.repeat(np.arange(nk), n)
    pos = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    valid = np.zeros((nk, m), bool)
    valid[kb, pos] = True

    def padded(attr: str, fill=0.0) -> np.ndarray:
        v = np.concatenate([getattr(cur, attr)[i] for _, cur, i in part])
        out = np.full((nk, m) + v.shape[1:], fill, v.dtype)
        out[kb, pos] = v
        return out
    ks = np.array([k for k, _, _ in part])
    frame = sol.frame
    # d h / d p_nav of the rows (the body axes taken as the nav axes: the translation Jacobian is then in nav)
    _, J = _rows_at_antenna(np.concatenate([cur.sat_pos[i] for _, cur, i in part]),
                            np.concatenate([cur.ref_pos[i] for _, cur, i in part]),
                            _antenna_ecef(sol.R_body_to_nav[ks], sol.p_nav[ks], lever, frame)[kb], frame.R_nav_to_ecef,
                            lever)
    G = np.zeros((nk, m, 3))
    G[kb, pos] = J[:, 3:]
    group = np.where(valid, padded("group", -1), -1 - np.arange(m))
    same = (group[:, :, None] == group[:, None, :]) & valid[:, :, None] & valid[:, None, :]
    C = np.where(same, padded("var_ref")[:, :, None], 0.0)
    C[:, np.arange(m), np.arange(m)] += np.where(valid, padded("var_sat"), 1.0)
    GtW = np.swapaxes(G, 1, 2) @ np.linalg.inv(C)
    N = GtW @ G
    out = np.full((nk, 3, 3), np.nan)
    ok = np.linalg.cond(N) <= 1e8
    if not ok.any():
        return out
    A = np.linalg.solve(N[ok], GtW[ok])
    sgn = np.where(padded("kind") == 0, -1.0, 1.0)
    a, b = sgn * padded("kappa"), -sgn * padded("kappa_ref")             # the row's weight on its satellite, reference
    scale = (iono_ppm * 1e-6 * np.array([cur.base_dist_m for _, cur, _ in part]))[:, None]
    map_sat, map_ref = padded("map_sat"), padded("map_ref")
    vs, vr = (scale * map_sat) ** 2, (scale * map_ref) ** 2
    sat, ref = padded("sat", -1), padded("ref", -1)
    t = map_sat - map_ref

    def eq(x, y):
        return x[:, :, None] == y[:, None, :]
    Ca = (eq(sat, sat) * (a * vs)[:, :, None] * a[:, None, :] + eq(sat, ref) * (a * vs)[:, :, None] * b[:, None, :]
          + eq(ref, sat) * (b * vr)[:, :, None] * a[:, None, :] + eq(ref, ref) * (b * vr)[:, :, None] * b[:, None, :]
          + tropo_zenith_m ** 2 * t[:, :, None] * t[:, None, :])
    out[ok] = A @ Ca[ok] @ np.swapaxes(A, 1, 2)
    return out
