"""Forward-only (filter-equivalent) solution for comparison: a gtsam incremental fixed-lag smoother (ISAM2
that marginalises states older than a few seconds) fed one keyframe at a time; the state of keyframe k is
read right after its update, before any later data — what an (iterated) Kalman filter would give.

The same factors as the batch smoother are used (pos.smoother.build_problem), so any difference between the
two solutions is the benefit of smoothing. Innovations: the GNSS factors' errors at the predicted state.
"""
from __future__ import annotations

import numpy as np

from pos.smoother import NavSolution, Problem, add_marginals, solution_values
from pos.smoother_factors import B, CLK, DRIFT, V, X, ZERO


def forward_solution(problem: Problem, relinearize_threshold: float = 0.05, relinearize_skip: int = 10,
                     progress: bool = False) -> NavSolution:
    """Filtered keyframe states and covariances (each from the data up to and including its own epoch)."""
    import gtsam
    prm = gtsam.ISAM2Params()
    prm.setRelinearizeThreshold(relinearize_threshold)
    prm.relinearizeSkip = relinearize_skip
    prm.setFactorization("QR")  # the clock variables in seconds make Cholesky break down
    isam = gtsam.ISAM2(prm)
    K = len(problem.t_key)
    init = problem.values
    p = np.empty((K, 3))
    v = np.empty((K, 3))
    R = np.empty((K, 3, 3))
    bias = np.empty((K, 6))
    clock = {s: np.empty(K) for s in problem.systems}
    drift = np.zeros(K)
    innov: dict = {}
    prev = None
    it = range(K)
    if progress:
        from tqdm import tqdm
        it = tqdm(it, desc="forward", unit="epoch", leave=False)
    for k in it:
        graph = gtsam.NonlinearFactorGraph()
        vals = gtsam.Values()
        if k == 0:
            for f in problem.prior_factors:
                graph.add(f)
            vals.insert(X(0), init.atPose3(X(0)))
            vals.insert(V(0), init.atPoint3(V(0)))
            vals.insert(B(0), init.atConstantBias(B(0)))
            for s in problem.systems:
                vals.insert(CLK(s, 0), init.atDouble(CLK(s, 0)))
            if problem.systems:
                vals.insert(DRIFT(0), init.atDouble(DRIFT(0)))
            if init.exists(ZERO()):
                vals.insert(ZERO(), 0.0)
        else:
            b_prev = gtsam.imuBias.ConstantBias(prev["bias"][:3], prev["bias"][3:])
            ns = problem.pims[k - 1].predict(gtsam.NavState(gtsam.Rot3(prev["R"]), prev["p"], prev["v"]), b_prev)
            vals.insert(X(k), ns.pose())
            vals.insert(V(k), ns.velocity())
            vals.insert(B(k), b_prev)
            dt = problem.t_key[k] - problem.t_key[k - 1]
            for s in problem.systems:
                vals.insert(CLK(s, k), prev["clock"][s] + prev["drift"] * dt)
            if problem.systems:
                vals.insert(DRIFT(k), prev["drift"])
            graph.add(problem.imu_factors[k - 1])
            for f in problem.clock_factor_groups[k - 1] if problem.clock_factor_groups else []:
                graph.add(f)
        # innovations: GNSS errors at the prediction (needs the previous clock too for Doppler)
        pred = gtsam.Values(vals)
        if k > 0 and init.exists(ZERO()):
            pred.insert(ZERO(), 0.0)
        for kind, f in problem.epoch_factors[k]:
            graph.add(f)
            if all(pred.exists(key) for key in f.keys()):
                e = float(np.atleast_1d(f.unwhitenedError(pred))[0])
                w = float(np.atleast_1d(f.whitenedError(pred))[0])
                innov.setdefault(kind, []).append((k, e, e / w if w else np.nan))
        isam.update(graph, vals)
        pose = isam.calculateEstimatePose3(X(k))
        p[k], R[k] = pose.translation(), pose.rotation().matrix()
        v[k] = isam.calculateEstimatePoint3(V(k))
        bias[k] = isam.calculateEstimateConstantBias(B(k)).vector()
        for s in problem.systems:
            clock[s][k] = isam.calculateEstimateDouble(CLK(s, k))
        if problem.systems:
            drift[k] = isam.calculateEstimateDouble(DRIFT(k))
        prev = {"p": p[k], "R": R[k], "v": v[k], "bias": bias[k], "drift": drift[k],
                "clock": {s: clock[s][k] for s in problem.systems}}
    sol = NavSolution(problem.frame, problem.t_key.copy(), p, v, R, bias, clock, drift,
                      n_sat=problem.n_sat.copy(), gnss_update=problem.gnss_update.copy())
    # covariances of the filter: information of the factors up to each epoch, at the filtered states
    add_marginals(sol, problem, solution_values(sol, problem), filtered=True)
    sol.residuals = {kind: tuple(np.array(c) for c in zip(*rows)) for kind, rows in innov.items()}
    sol.info = {"mode": "forward"}
    return sol
