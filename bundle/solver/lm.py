"""Levenberg-Marquardt on a `Problem`: damped Gauss-Newton steps through the Schur complement on the points.

Stopping: converged when no damped step lowers the cost (the minimum to machine precision), when a step lowers
chi^2 by less than `tol_chi2` (the parameters are then within a small fraction of their sigmas of the minimum)
or the cost by less than `tol_rel` relative; otherwise `max_iterations` ends the run unconverged, and the
result says so.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dgcal.bundle.solver.blocks import State
from dgcal.bundle.solver.normals import Normals, Problem, linearise, reduce, solve_normals


@dataclass
class LMOptions:
    """Damping schedule and stopping rules."""

    max_iterations: int = 100
    tol_chi2: float = 1e-3          # stop when a step gains less than this in chi^2 (cost / sigma0^2)
    tol_rel: float = 1e-10          # ... or less than this relative to the cost
    lambda0: float = 1e-4
    lambda_up: float = 10.0
    lambda_down: float = 10.0
    max_tries: int = 12             # damping increases per iteration before giving up
    tol_step: float = 0.0           # ... or when no camera-side parameter moves by this much of its sigma
    verbose: bool = False


@dataclass
class Solution:
    """The minimum found: state, cost, iteration count, convergence and why the iterations stopped."""

    state: State
    cost: float
    iterations: int
    converged: bool
    stop_reason: str
    history: list[float] = field(default_factory=list)


def minimise(problem: Problem, state: State, options: LMOptions | None = None) -> Solution:
    """Minimise the problem's robust cost from `state` (not modified)."""
    opt = options or LMOptions()
    state = state.copy()
    cost = problem.cost(state)
    history = [cost]
    lam = opt.lambda0
    reason = f"iteration limit ({opt.max_iterations})"
    converged = False
    it = 0
    for it in range(1, opt.max_iterations + 1):
        nrm = linearise(problem, state)
        improved = False
        for _ in range(opt.max_tries):
            try:
                red = reduce(nrm, lam)
                dc, dx = solve_normals(nrm, red, -nrm.g_c, -nrm.g_x)
            except np.linalg.LinAlgError:
                lam *= opt.lambda_up
                continue
            cand = problem.retract(state, dc, dx)
            new = problem.cost(cand)
            if np.isfinite(new) and new < cost:
                improved = True
                break
            lam *= opt.lambda_up
        if not improved:
            converged, reason = True, "no step lowers the cost"
            break
        gain = cost - new
        dof = max(nrm.redundancy, 1)
        gain_chi2 = gain / max(new / dof, 1e-300)
        rel = gain / max(cost, 1e-300)
        state, cost = cand, new
        history.append(cost)
        lam = max(lam / opt.lambda_down, 1e-12)
        # the step in units of each camera-side parameter's conditional sigma 1/sqrt(S_ii) (<= its sigma)
        moved = float(np.max(np.abs(dc) * red.scale, initial=0.0))
        if opt.verbose:
            print(f"  LM it {it}: cost {cost:.6g}, lambda {lam:.1e}, step {moved:.2g} sigma")
        if gain_chi2 < opt.tol_chi2:
            converged, reason = True, f"chi^2 gain {gain_chi2:.2g} < {opt.tol_chi2:g}"
            break
        if rel < opt.tol_rel:
            converged, reason = True, f"relative decrease {rel:.2g} < {opt.tol_rel:g}"
            break
        if moved < opt.tol_step:
            converged, reason = True, f"camera-side step {moved:.2g} sigma < {opt.tol_step:g}"
            break
    return Solution(state, cost, it, converged, reason, history)


def normals_at(problem: Problem, solution: Solution) -> Normals:
    """The undamped normal equations at a solution (for covariances and tests)."""
    return linearise(problem, solution.state)
