"""Forward-only solutions beside the smoother: the forward pass of its linearised problem, or an iterated filter.

`linear_forward_solution` runs the Kalman filter of the smoother's problem linearised at the smoothed solution
(`dgcal.pos.smoother.covariance.forward_innovations`): each keyframe from the data up to its epoch, with the
normalised innovations of every measurement kind; it is what the smoother's forward sweep computes, cheap and
consistent with the smoother by construction.

`forward_solution` (opt-in, `dgcal pos --forward-filter`): at epoch k the filtered Gaussian of keyframe k-1 (mean
and information, all its variables) is combined with the factors that reach keyframe k (IMU k-1 -> k, clock and
code-bias processes, the GNSS of epoch k); the two-keyframe problem is solved by Gauss-Newton about the IMU
prediction (relinearised each iteration), and keyframe k-1 is marginalised out (Schur complement). Each state
therefore uses only the data up to its own epoch, and the filter linearises about its own estimates, as an EKF
does; started from a poor attitude (a walker's first epochs) it can stay inconsistent for the whole record.
Innovations: the GNSS factor errors at the IMU prediction, before the update.
"""
from __future__ import annotations

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.pos.smoother.batch import NavSolution, Problem, read_states
from dgcal.pos.smoother.carrier import dd_errors
from dgcal.pos.smoother.covariance import forward_innovations
from dgcal.pos.smoother.fix_errors import fix_error_at, fix_white_sigma
from dgcal.pos.smoother.integrity import factor_table
from dgcal.pos.smoother.factors import CLK, DRIFT, FE, ZERO, B, V, X


def _dense_system(graph, vals, entries: list, has_zero: bool, scale: np.ndarray):
    """Dense information matrix and vector of a small graph linearised at `vals` in the layout of `entries`
    ((key, offset, dim) of the variables present; ZERO, a pinned constant, dropped), scaled so the clock
    variables are in metres; positions of the layout without a variable get unit information."""
    order = gtsam.Ordering()
    for key, _, _ in entries:
        order.push_back(key)
    if has_zero:
        order.push_back(ZERO())
    Hb = graph.linearize(vals).augmentedHessian(order)
    cols = _columns(entries)
    m = len(cols)
    N = len(scale)
    H = np.zeros((N, N))
    eta = np.zeros(N)
    H[np.ix_(cols, cols)] = Hb[:m, :m]
    eta[cols] = Hb[:m, -1]
    H *= scale[:, None] * scale[None, :]
    eta *= scale
    missing = np.ones(N, bool)
    missing[cols] = False
    H[missing, missing] = 1.0
    return H, eta


def _columns(entries: list) -> np.ndarray:
    """Layout positions of the variables of `entries`, in order."""
    return np.array([c for _, off, dim in entries for c in range(off, off + dim)], int)


def _step_factors(problem: Problem) -> list:
    """Factors of the graph grouped by the latest keyframe they touch."""
    K = len(problem.t_key)
    where = problem.blocks().where
    out: list = [[] for _ in range(K)]
    g = problem.graph
    for i in range(g.size()):
        f = g.at(i)
        ks = [where[key][0] for key in f.keys() if where.get(key) is not None]
        out[max(ks) if ks else 0].append(f)
    return out


def _retract(vals, entries: list, dx: np.ndarray) -> None:
    """Apply a correction in the block layout (clocks in s, code biases in m) to the variables of `entries`."""
    for key, off, dim in entries:
        d = dx[off:off + dim]
        c = gtsam.Symbol(key).chr()
        if c == ord("x"):
            vals.update(key, vals.atPose3(key).retract(d))
        elif c in (ord("v"), ord("f")):
            vals.update(key, vals.atVector(key) + d)
        elif c == ord("b"):
            b = vals.atConstantBias(key).vector() + d
            vals.update(key, gtsam.imuBias.ConstantBias(b[:3], b[3:]))
        else:
            vals.update(key, vals.atDouble(key) + float(d[0]))


def _local(vals_a, vals_b, entries: list, n: int) -> np.ndarray:
    """Local coordinates (block layout, clocks in s) of the variables of `entries` in b relative to a."""
    d = np.zeros(n)
    for key, off, _dim in entries:
        c = gtsam.Symbol(key).chr()
        if c == ord("x"):
            d[off:off + 6] = vals_a.atPose3(key).localCoordinates(vals_b.atPose3(key))
        elif c in (ord("v"), ord("f")):
            d[off:off + 3] = vals_b.atVector(key) - vals_a.atVector(key)
        elif c == ord("b"):
            d[off:off + 6] = vals_b.atConstantBias(key).vector() - vals_a.atConstantBias(key).vector()
        else:
            d[off] = vals_b.atDouble(key) - vals_a.atDouble(key)
    return d


def _copy(dst, src, entries: list) -> None:
    """Insert the variables of `entries` from Values `src` into `dst`."""
    for key, _, _ in entries:
        c = gtsam.Symbol(key).chr()
        if c == ord("x"):
            dst.insert(key, src.atPose3(key))
        elif c in (ord("v"), ord("f")):
            dst.insert(key, src.atVector(key))
        elif c == ord("b"):
            dst.insert(key, src.atConstantBias(key))
        else:
            dst.insert(key, src.atDouble(key))


def linear_forward_solution(problem: Problem, values, rows=None) -> NavSolution:
    """The forward (filtered) solution of the smoother's problem linearised at its solution `values`: each
    keyframe's states and covariance from the data up to its own epoch, and the normalised innovations of every
    measurement kind (`info["nis"]`), from one pass of `dgcal.pos.smoother.covariance.forward_innovations`.
    `rows`: the problem already linearised at `values` (`NavSolution.rows`).

    Linearised about the smoothed trajectory, it is the Kalman filter the smoother's forward sweep runs: cheap, and
    free of the divergence a filter started from a poor initial attitude can show (`forward_solution`, the
    iterated filter about its own estimates, is the opt-in alternative)."""
    layout = problem.blocks()
    graph = problem.graph
    tab = factor_table(problem)
    names = sorted({kd[0] for kd in tab.kinds if kd is not None})
    code = np.array([-1 if kd is None else names.index(kd[0]) for kd in tab.kinds], int)
    dims = np.diff(tab.start)
    dx, P, nis, innov = forward_innovations(graph, values, layout, np.repeat(code, dims), names, rows)
    sol = _retracted(read_states(problem, values), dx, layout)
    # innovations in measurement units: the whitened innovation times the row's sigma (exact for the independent
    # rows of the GNSS factors; for the correlated double differences of a keyframe, an approximation)
    out: dict = {}
    rec = np.isfinite(tab.sigma)
    for i in np.flatnonzero(~rec & (code >= 0)):
        kind, k = tab.kinds[i]
        sig = _dd_sigmas(problem, k) if kind == "dd" else _fix_sigmas(problem, k) if _is_lc_fix(problem, kind) \
            else _sigmas(graph.at(i))
        w = innov[tab.start[i]:tab.start[i + 1]]
        for j in range(len(w)):
            s = sig[min(j, len(sig) - 1)]
            out.setdefault(kind, []).append((k, w[j] * s, s))
    res = {kind: tuple(np.array(c) for c in zip(*r)) for kind, r in out.items()}
    i = np.flatnonzero(rec)
    kinds = np.array([tab.kinds[j][0] for j in i])
    ks = np.array([tab.kinds[j][1] for j in i], int)
    for kind in dict.fromkeys(kinds.tolist()):
        m = kinds == kind
        res[kind] = (ks[m], innov[tab.start[i[m]]] * tab.sigma[i[m]], tab.sigma[i[m]].copy())
    sol.residuals = {kind: res[kind] for kind in names if kind in res}
    sol.cov_pose = P[:, :6, :6].copy()
    sol.cov_vel = P[:, 6:9, 6:9].copy()
    sol.cov_block = P
    sol.info = {"mode": "forward", "nis": {kind: tuple(np.array(c) for c in zip(*r)) for kind, r in nis.items()}}
    return sol


def _retracted(sol: NavSolution, dx: np.ndarray, layout) -> NavSolution:
    """`sol` moved by block corrections dx (K,n): pose by gtsam's Pose3 chart (rotation R Exp(w), translation
    t + R v, to first order), velocity, IMU biases and clocks (s, s/s) additively; code biases are left out."""
    R_body_to_nav = sol.R_body_to_nav @ Rotation.from_rotvec(dx[:, :3]).as_matrix()
    p = sol.p_nav + np.einsum("kij,kj->ki", sol.R_body_to_nav, dx[:, 3:6])
    clock = {s: sol.clock[s] + dx[:, 15 + j] for j, s in enumerate(layout.systems)}
    drift = sol.drift + dx[:, 15 + len(layout.systems)] if layout.systems else sol.drift
    return NavSolution(sol.frame, sol.t, p, sol.v_nav + dx[:, 6:9], R_body_to_nav, sol.bias + dx[:, 9:15], clock,
                       drift, n_sat=sol.n_sat, gnss_update=sol.gnss_update)


def forward_solution(problem: Problem, values=None, iterations: int = 3) -> NavSolution:
    """Filtered keyframe states and covariances (each from the data up to and including its own epoch).

    `values` is not needed (the filter linearises about its own estimates; kept so the smoothed solution's
    values can be passed uniformly); the filter starts from the problem's initial values at the first epoch.
    """

    K = len(problem.t_key)
    systems = problem.systems
    layout = problem.blocks()
    n = layout.n
    entries_at = _entries_by_keyframe(layout, K)
    steps = _step_factors(problem)
    has_zero = problem.values.exists(ZERO())
    arcs = problem.code_bias

    out = gtsam.Values()
    P = np.empty((K, n, n))
    innov: dict = {}
    nis: dict = {}
    Lam = None
    scale = layout.scale
    for k in range(K):
        vals = gtsam.Values()
        if has_zero:
            vals.insert(ZERO(), 0.0)
        if k == 0:
            _copy(vals, problem.values, entries_at[0])
            nb = 1
        else:
            _copy(vals, out, entries_at[k - 1])
            pose0, vel0, b0 = out.atPose3(X(k - 1)), out.atPoint3(V(k - 1)), out.atConstantBias(B(k - 1))
            ns = problem.pims[k - 1].predict(gtsam.NavState(pose0.rotation(), pose0.translation(), vel0), b0)
            dt = problem.t_key[k] - problem.t_key[k - 1]
            vals.insert(X(k), ns.pose())
            vals.insert(V(k), ns.velocity())
            vals.insert(B(k), b0)
            if systems:
                dr0 = out.atDouble(DRIFT(k - 1))
                for s in systems:
                    vals.insert(CLK(s, k), out.atDouble(CLK(s, k - 1)) + dr0 * dt)
                vals.insert(DRIFT(k), dr0)
            for key, _, _ in entries_at[k]:
                c = gtsam.Symbol(key).chr()
                if c == ord("q"):
                    prev = arcs.previous(key, k)
                    phi = float(np.exp(-dt / arcs.tau_s))
                    vals.insert(key, phi * out.atDouble(prev) if prev is not None else 0.0)
                elif c == ord("f"):
                    # the fixes' error: decays towards zero by the Gauss-Markov process (sigma changes are slow)
                    first = k == problem.lc.span[0]
                    phi = float(np.exp(-dt / problem.lc.tau_s))
                    vals.insert(key, np.zeros(3) if first else phi * out.atVector(FE(k - 1)))
            nb = 2
            prior_vals = gtsam.Values(vals)
        graph = gtsam.NonlinearFactorGraph()
        for f in steps[k]:
            graph.add(f)
        for kind, f, _ in problem.epoch_factors[k]:  # innovations at the prediction
            if kind == "dd":
                e, sig = dd_errors(problem.dd[k], vals, X, problem.lever_arm_b, problem.frame), _dd_sigmas(problem, k)
            elif _is_lc_fix(problem, kind):
                e, sig = fix_error_at(problem.lc, k, vals)
            else:
                e, sig = np.atleast_1d(f.unwhitenedError(vals)), _sigmas(f)
            for j in range(len(e)):
                innov.setdefault(kind, []).append((k, e[j], sig[j]))
        ents = entries_at[k] if nb == 1 else entries_at[k - 1] + [(key, off + n, d) for key, off, d in entries_at[k]]
        sc = np.tile(scale, nb)
        if nb == 2 and problem.epoch_factors[k]:
            _normalised_innovations(problem, k, vals, ents, has_zero, sc, Lam, n, nis)
        for _ in range(iterations):
            H, eta = _dense_system(graph, vals, ents, has_zero, sc)
            if nb == 2:
                d0 = _local(vals, prior_vals, entries_at[k - 1], n) / scale  # prior mean relative to vals, metres
                H[:n, :n] += Lam
                eta[:n] += Lam @ d0
            dx = np.linalg.solve(H, eta) * sc
            _retract(vals, ents, dx)
            if np.max(np.abs(dx / sc)) < 1e-4:
                break
        # marginal information of keyframe k (at the last linearisation point)
        H, _ = _dense_system(graph, vals, ents, has_zero, sc)
        if nb == 2:
            H[:n, :n] += Lam
            Lam = H[n:, n:] - H[n:, :n] @ np.linalg.solve(H[:n, :n], H[:n, n:])
        else:
            Lam = H
        Lam = 0.5 * (Lam + Lam.T)
        Pk = np.linalg.inv(Lam)
        P[k] = 0.5 * (Pk + Pk.T) * scale[:, None] * scale[None, :]
        _copy(out, vals, entries_at[k])
    sol = read_states(problem, out)
    sol.cov_pose = P[:, :6, :6].copy()
    sol.cov_vel = P[:, 6:9, 6:9].copy()
    sol.cov_block = P
    sol.residuals = {kind: tuple(np.array(c) for c in zip(*rows)) for kind, rows in innov.items()}
    sol.info = {"mode": "forward",
                "nis": {kind: tuple(np.array(c) for c in zip(*rows)) for kind, rows in nis.items()}}
    return sol


def _entries_by_keyframe(layout, K: int) -> list:
    """Per keyframe, the (key, offset, dim) of its variables in the block layout (ZERO excluded)."""
    out: list = [[] for _ in range(K)]
    for key, loc in layout.where.items():
        if loc is not None:
            out[loc[0]].append((key, loc[1], loc[2]))
    for e in out:
        e.sort(key=lambda x: x[1])
    return out


def _normalised_innovations(problem: Problem, k: int, vals, ents: list, has_zero: bool, sc: np.ndarray, Lam,
                            n: int, out: dict) -> None:
    """Normalised innovation squared of every GNSS factor of keyframe k at the IMU prediction:
    b' (A P A' + I)^-1 b with A, b the factor's whitened Jacobian and error and P the predicted covariance of
    keyframes k-1 and k (the filtered k-1 and the IMU, clock and code-bias process factors to k). Appends
    (k, NIS, dim) per kind."""
    graph = gtsam.NonlinearFactorGraph()
    graph.add(problem.imu_factors[k - 1])
    groups = [problem.clock_factor_groups[k - 1]] if k - 1 < len(problem.clock_factor_groups) else []
    if k < len(problem.bias_factor_groups):
        groups.append(problem.bias_factor_groups[k])
    for g in groups:
        for f in g:
            graph.add(f)
    H, _ = _dense_system(graph, vals, ents, has_zero, sc)
    H[:n, :n] += Lam
    try:
        Pj = np.linalg.inv(0.5 * (H + H.T))
    except np.linalg.LinAlgError:
        return
    by_kind: dict = {}
    for kind, f, _ in problem.epoch_factors[k]:
        g, present = by_kind.setdefault(kind, (gtsam.NonlinearFactorGraph(), set()))
        g.add(f)
        present.update(int(key) for key in f.keys())
    for kind, (g, present) in by_kind.items():
        # one whitened Jacobian for all factors of the kind (columns in the order of `ents`, ZERO last, dropped)
        sub = [e for e in ents if e[0] in present]
        lin = g.linearize(vals)
        A_all, b = lin.jacobian(_restrict(sub, has_zero and ZERO() in present))
        cols = _columns(sub)
        Af = np.zeros((A_all.shape[0], 2 * n))
        Af[:, cols] = A_all[:, :len(cols)] * sc[cols]         # clock columns in metres, as P
        S = Af @ Pj @ Af.T + np.eye(A_all.shape[0])
        try:
            v = float(b @ np.linalg.solve(S, b))
        except np.linalg.LinAlgError:
            continue
        out.setdefault(kind, []).append((k, v, A_all.shape[0]))


def _restrict(entries: list, zero: bool):
    """An ordering of the keys of `entries` (and ZERO last)."""
    o = gtsam.Ordering()
    for key, _, _ in entries:
        o.push_back(key)
    if zero:
        o.push_back(ZERO())
    return o


def _dd_sigmas(problem: Problem, k: int) -> np.ndarray:
    """Sigmas (m) of keyframe k's double-difference rows as its factor combines them."""
    return np.sqrt(np.diag(problem.dd[k].cov))


def _is_lc_fix(problem: Problem, kind: str) -> bool:
    """Whether a factor of this kind is an LC fix with error states (`dgcal.pos.smoother.fix_errors`)."""
    return kind == "pos" and problem.lc is not None


def _fix_sigmas(problem: Problem, k: int) -> np.ndarray:
    """White sigmas (m) of the LC fix at keyframe k."""
    return fix_white_sigma(problem.lc, k)


def _sigmas(f) -> np.ndarray:
    """Measurement sigmas of a factor's (possibly robust) Gaussian noise model."""
    nm = f.noiseModel()
    base = nm.noise() if hasattr(nm, "noise") else nm
    return np.atleast_1d(base.sigmas())
