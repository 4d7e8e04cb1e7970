"""Forward-only (filter) solution for comparison with the smoother: an iterated extended Kalman filter in
information form built from the smoother's own factors.

At epoch k the filtered Gaussian of keyframe k-1 (mean and information, all its variables) is combined with
the factors that reach keyframe k (IMU k-1 -> k, clock process, the GNSS of epoch k); the two-keyframe
problem is solved by Gauss-Newton about the IMU prediction (relinearised each iteration), and keyframe k-1
is marginalised out (Schur complement). Each state therefore uses only the data up to its own epoch, and
the filter linearises about its own estimates, as an EKF does. The smoother uses the same factors plus the
future, so the difference between the two is the benefit of smoothing.
Innovations: the GNSS factor errors at the IMU prediction, before the update.
"""
from __future__ import annotations

import gtsam
import numpy as np

from dgcal.pos.smoother.batch import NavSolution, Problem, read_states
from dgcal.pos.smoother.covariance import KeyframeBlocks
from dgcal.pos.smoother.factors import CLK, DRIFT, ZERO, B, V, X


def _dense_system(graph, vals, key_order: list, has_zero: bool, scale: np.ndarray):
    """Dense information matrix and vector of a small graph linearised at `vals`, columns in `key_order`
    (ZERO, a pinned constant, last and dropped), scaled so the clock variables are in metres."""

    order = gtsam.Ordering()
    for key in key_order:
        order.push_back(key)
    if has_zero:
        order.push_back(ZERO())
    Hb = graph.linearize(vals).augmentedHessian(order)
    m = len(scale)
    H = Hb[:m, :m] * scale[:, None] * scale[None, :]
    eta = Hb[:m, -1] * scale
    return H, eta


def _step_factors(problem: Problem) -> list:
    """Factors of the graph grouped by the latest keyframe they touch."""
    K = len(problem.t_key)
    where = KeyframeBlocks(K, problem.systems).where
    out: list = [[] for _ in range(K)]
    g = problem.graph
    for i in range(g.size()):
        f = g.at(i)
        ks = [where[key][0] for key in f.keys() if where.get(key) is not None]
        out[max(ks) if ks else 0].append(f)
    return out


def _flat(keys_block) -> list:
    xk, vk, bk, ck, dk = keys_block
    return [xk, vk, bk, *ck] + ([dk] if dk is not None else [])


def _retract(vals, keys_block, dx, systems):
    """Apply a block correction (pose 6, vel 3, bias 6, clocks, drift; clocks in s) to gtsam Values."""
    xk, vk, bk, ck, dk = keys_block
    vals.update(xk, vals.atPose3(xk).retract(dx[:6]))
    vals.update(vk, vals.atPoint3(vk) + dx[6:9])
    b = vals.atConstantBias(bk).vector() + dx[9:15]
    vals.update(bk, gtsam.imuBias.ConstantBias(b[:3], b[3:]))
    for j, key in enumerate(ck):
        vals.update(key, vals.atDouble(key) + dx[15 + j])
    if dk is not None:
        vals.update(dk, vals.atDouble(dk) + dx[15 + len(ck)])


def _local(vals_a, vals_b, keys_block, n):
    """Local coordinates of block values b relative to a (clocks in s)."""
    xk, vk, bk, ck, dk = keys_block
    d = np.zeros(n)
    d[:6] = vals_a.atPose3(xk).localCoordinates(vals_b.atPose3(xk))
    d[6:9] = vals_b.atPoint3(vk) - vals_a.atPoint3(vk)
    d[9:15] = vals_b.atConstantBias(bk).vector() - vals_a.atConstantBias(bk).vector()
    for j, key in enumerate(ck):
        d[15 + j] = vals_b.atDouble(key) - vals_a.atDouble(key)
    if dk is not None:
        d[15 + len(ck)] = vals_b.atDouble(dk) - vals_a.atDouble(dk)
    return d


def forward_solution(problem: Problem, values=None, iterations: int = 3) -> NavSolution:
    """Filtered keyframe states and covariances (each from the data up to and including its own epoch).

    `values` is not needed (the filter linearises about its own estimates; kept so the smoothed solution's
    values can be passed uniformly); the filter starts from the problem's initial values at the first epoch.
    """

    K = len(problem.t_key)
    systems = problem.systems
    n = KeyframeBlocks(1, systems).n
    steps = _step_factors(problem)
    has_zero = problem.values.exists(ZERO())

    def keys(k):
        return (X(k), V(k), B(k), [CLK(s, k) for s in systems], DRIFT(k) if systems else None)

    def insert_block(vals, k, pose, vel, bias, clk, drift):
        vals.insert(X(k), pose)
        vals.insert(V(k), vel)
        vals.insert(B(k), bias)
        for s in systems:
            vals.insert(CLK(s, k), float(clk[s]))
        if systems:
            vals.insert(DRIFT(k), float(drift))

    out = gtsam.Values()
    P = np.empty((K, n, n))
    innov: dict = {}
    nis: dict = {}
    Lam = None
    scale = KeyframeBlocks(1, systems).scale
    for k in range(K):
        vals = gtsam.Values()
        if has_zero:
            vals.insert(ZERO(), 0.0)
        if k == 0:
            init = problem.values
            insert_block(vals, 0, init.atPose3(X(0)), init.atPoint3(V(0)), init.atConstantBias(B(0)),
                         {s: init.atDouble(CLK(s, 0)) for s in systems},
                         init.atDouble(DRIFT(0)) if systems else 0.0)
            nb = 1
        else:
            pose0, vel0, b0 = out.atPose3(X(k - 1)), out.atPoint3(V(k - 1)), out.atConstantBias(B(k - 1))
            clk0 = {s: out.atDouble(CLK(s, k - 1)) for s in systems}
            dr0 = out.atDouble(DRIFT(k - 1)) if systems else 0.0
            insert_block(vals, k - 1, pose0, vel0, b0, clk0, dr0)
            ns = problem.pims[k - 1].predict(gtsam.NavState(pose0.rotation(), pose0.translation(), vel0), b0)
            dt = problem.t_key[k] - problem.t_key[k - 1]
            insert_block(vals, k, ns.pose(), ns.velocity(), b0, {s: clk0[s] + dr0 * dt for s in systems}, dr0)
            nb = 2
            prior_vals = gtsam.Values(vals)
        graph = gtsam.NonlinearFactorGraph()
        for f in steps[k]:
            graph.add(f)
        for kind, f in problem.epoch_factors[k]:  # innovations at the prediction
            e = np.atleast_1d(f.unwhitenedError(vals))
            sig = _sigmas(f)
            for j in range(len(e)):
                innov.setdefault(kind, []).append((k, e[j], sig[j]))
        order = [key for i in range(nb) for key in _flat(keys(k - nb + 1 + i))]
        sc = np.tile(scale, nb)
        if nb == 2 and problem.epoch_factors[k]:
            _normalised_innovations(problem, k, vals, order, has_zero, sc, Lam, n, nis)
        for _ in range(iterations):
            H, eta = _dense_system(graph, vals, order, has_zero, sc)
            if nb == 2:
                d0 = _local(vals, prior_vals, keys(k - 1), n) / scale  # prior mean relative to vals, metres
                H[:n, :n] += Lam
                eta[:n] += Lam @ d0
            dx = np.linalg.solve(H, eta)
            for i in range(nb):
                _retract(vals, keys(k - nb + 1 + i), dx[i * n:(i + 1) * n] * scale, systems)
            if np.max(np.abs(dx)) < 1e-4:
                break
        # marginal information of keyframe k (at the last linearisation point)
        H, _ = _dense_system(graph, vals, order, has_zero, sc)
        if nb == 2:
            H[:n, :n] += Lam
            Lam = H[n:, n:] - H[n:, :n] @ np.linalg.solve(H[:n, :n], H[:n, n:])
        else:
            Lam = H
        Lam = 0.5 * (Lam + Lam.T)
        Pk = np.linalg.inv(Lam)
        P[k] = 0.5 * (Pk + Pk.T) * scale[:, None] * scale[None, :]
        xk, vk, bk, ck, dk = keys(k)
        out.insert(xk, vals.atPose3(xk))
        out.insert(vk, vals.atPoint3(vk))
        out.insert(bk, vals.atConstantBias(bk))
        for key in ck:
            out.insert(key, vals.atDouble(key))
        if dk is not None:
            out.insert(dk, vals.atDouble(dk))
    sol = read_states(problem, out)
    sol.cov_pose = P[:, :6, :6].copy()
    sol.cov_vel = P[:, 6:9, 6:9].copy()
    sol.cov_block = P
    sol.residuals = {kind: tuple(np.array(c) for c in zip(*rows)) for kind, rows in innov.items()}
    sol.info = {"mode": "forward",
                "nis": {kind: tuple(np.array(c) for c in zip(*rows)) for kind, rows in nis.items()}}
    return sol


def _normalised_innovations(problem: Problem, k: int, vals, order: list, has_zero: bool, sc: np.ndarray, Lam,
                            n: int, out: dict) -> None:
    """Normalised innovation squared of every GNSS factor of keyframe k at the IMU prediction:
    b' (A P A' + I)^-1 b with A, b the factor's whitened Jacobian and error and P the predicted covariance of
    keyframes k-1 and k (the filtered k-1 and the IMU and clock factors to k). Appends (k, NIS, dim) per kind."""
    graph = gtsam.NonlinearFactorGraph()
    graph.add(problem.imu_factors[k - 1])
    if k - 1 < len(problem.clock_factor_groups):
        for f in problem.clock_factor_groups[k - 1]:
            graph.add(f)
    H, _ = _dense_system(graph, vals, order, has_zero, sc)
    H[:n, :n] += Lam
    try:
        Pj = np.linalg.inv(0.5 * (H + H.T))
    except np.linalg.LinAlgError:
        return
    by_kind: dict = {}
    for kind, f in problem.epoch_factors[k]:
        g, present = by_kind.setdefault(kind, (gtsam.NonlinearFactorGraph(), set()))
        g.add(f)
        present.update(int(key) for key in f.keys())
    for kind, (g, present) in by_kind.items():
        # one whitened Jacobian for all factors of the kind (columns in `order`, ZERO last and dropped)
        lin = g.linearize(vals)
        A_all, b = lin.jacobian(_restrict(present, order, has_zero))
        cols = _columns(present, order)
        Af = np.zeros((A_all.shape[0], 2 * n))
        Af[:, cols] = A_all[:, :len(cols)] * sc[cols]         # clock columns in metres, as P
        S = Af @ Pj @ Af.T + np.eye(A_all.shape[0])
        try:
            v = float(b @ np.linalg.solve(S, b))
        except np.linalg.LinAlgError:
            continue
        out.setdefault(kind, []).append((k, v, A_all.shape[0]))


def _restrict(present: set, keys: list, has_zero: bool):
    """An ordering of the keys a linearised graph has (state keys in the order of `keys`; ZERO last)."""
    o = gtsam.Ordering()
    for key in keys:
        if key in present:
            o.push_back(key)
    if has_zero and ZERO() in present:
        o.push_back(ZERO())
    return o


def _columns(present: set, keys: list) -> list:
    """Column indices (in the two-block layout of `keys`) of the present state keys, in order."""
    cols = []
    for j, key in enumerate(keys):
        dim = {ord("x"): 6, ord("b"): 6, ord("v"): 3}.get(gtsam.Symbol(key).chr(), 1)
        if key in present:
            cols.extend(range(_offset(keys, j), _offset(keys, j) + dim))
    return cols


def _offset(keys: list, j: int) -> int:
    return sum({ord("x"): 6, ord("b"): 6, ord("v"): 3}.get(gtsam.Symbol(key).chr(), 1) for key in keys[:j])


def _sigmas(f) -> np.ndarray:
    """Measurement sigmas of a factor's (possibly robust) Gaussian noise model."""
    nm = f.noiseModel()
    base = nm.noise() if hasattr(nm, "noise") else nm
    return np.atleast_1d(base.sigmas())
