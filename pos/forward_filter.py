"""Forward-only (filter) solution for comparison with the smoother.

The smoother's factor graph, linearised about the smoothed trajectory, is solved recursively forward in
time with only the factors available at each epoch: a Kalman filter in information form (a linearised
filter about the final trajectory — what the first half of a forward-filter + RTS smoother computes).
The smoother is the same system with the backward pass added, so the difference between the two is the
benefit of smoothing. (An ISAM2 filter was tried: with the receiver clocks in seconds its Cholesky breaks
down, and with QR it is far slower than this recursion.)
Innovations: the GNSS factors' errors at the filtered state of the previous epoch propagated by the IMU.
"""
from __future__ import annotations

import numpy as np

from pos.smoother import NavSolution, Problem


def forward_solution(problem: Problem, values) -> NavSolution:
    """Filtered keyframe states and covariances (each from the data up to and including its own epoch).

    `values`: the linearisation point (the smoothed solution's gtsam Values).
    """
    import gtsam

    from pos.smoother import read_states
    from pos.smoother_covariance import KeyframeBlocks, forward_pass
    K = len(problem.t_key)
    blocks = KeyframeBlocks(K, problem.systems)
    dx, P = forward_pass(problem.graph, values, blocks)
    base = read_states(problem, values)
    sol = NavSolution(problem.frame, problem.t_key.copy(), base.p_nav.copy(), base.v_nav.copy(),
                      base.R_body_to_nav.copy(), base.bias.copy(), {s: c.copy() for s, c in base.clock.items()},
                      base.drift.copy(), n_sat=problem.n_sat.copy(), gnss_update=problem.gnss_update.copy())
    for k in range(K):
        pose = gtsam.Pose3(gtsam.Rot3(base.R_body_to_nav[k]), base.p_nav[k]).retract(dx[k, :6])
        sol.p_nav[k], sol.R_body_to_nav[k] = pose.translation(), pose.rotation().matrix()
        sol.v_nav[k] += dx[k, 6:9]
        sol.bias[k] += dx[k, 9:15]
        for j, s in enumerate(problem.systems):
            sol.clock[s][k] += dx[k, 15 + j]
        if problem.systems:
            sol.drift[k] += dx[k, 15 + len(problem.systems)]
    sol.cov_pose = P[:, :6, :6].copy()
    sol.cov_vel = P[:, 6:9, 6:9].copy()
    sol.cov_block = P
    sol.residuals = _innovations(problem, sol)
    sol.info = {"mode": "forward"}
    return sol


def _sigmas(f) -> np.ndarray:
    """Measurement sigmas of a factor's (possibly robust) Gaussian noise model."""
    nm = f.noiseModel()
    base = nm.noise() if hasattr(nm, "noise") else nm
    return np.atleast_1d(base.sigmas())


def _innovations(problem: Problem, fw: NavSolution) -> dict:
    """GNSS factor errors at the one-step IMU prediction from the previous filtered state."""
    import gtsam

    from pos.smoother_factors import B, CLK, DRIFT, V, X, ZERO
    out: dict = {}
    has_zero = problem.values.exists(ZERO())
    for k in range(1, len(fw.t)):
        if not problem.epoch_factors[k]:
            continue
        b = gtsam.imuBias.ConstantBias(fw.bias[k - 1, :3], fw.bias[k - 1, 3:])
        ns = problem.pims[k - 1].predict(gtsam.NavState(gtsam.Rot3(fw.R_body_to_nav[k - 1]), fw.p_nav[k - 1],
                                                       fw.v_nav[k - 1]), b)
        vals = gtsam.Values()
        vals.insert(X(k), ns.pose())
        vals.insert(V(k), ns.velocity())
        vals.insert(B(k), b)
        dt = fw.t[k] - fw.t[k - 1]
        for s in problem.systems:
            vals.insert(CLK(s, k), fw.clock[s][k - 1] + fw.drift[k - 1] * dt)
        if problem.systems:
            vals.insert(DRIFT(k), fw.drift[k - 1])
        if has_zero:
            vals.insert(ZERO(), 0.0)
        for kind, f in problem.epoch_factors[k]:
            e = np.atleast_1d(f.unwhitenedError(vals))
            sig = _sigmas(f)
            for j in range(len(e)):
                out.setdefault(kind, []).append((k, e[j], sig[j]))
    return {kind: tuple(np.array(c) for c in zip(*rows)) for kind, rows in out.items()}
