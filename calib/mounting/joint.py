"""Proposed mounting calibration (seed 003 eq. 10-11): exposure delay, lever arm and boresight in one weighted
least-squares adjustment.

Model per epoch i (the world frame of the block; t_e = event time, dt = delay, POS propagated over the delay; with a
full trajectory the POS is re-interpolated at t_e + dt between iterations, so the propagation only spans the last
correction and the constant-rate approximation leaves no bias):
    R_body_to_world(t_e + dt) = R_body_to_world,i Exp(omega_b,i dt)           (body angular rate from the POS)
    r_imu_world(t_e + dt)     = r_imu_world,i + v_world,i dt                       (POS velocity)
    C_world,i   = r_imu_world(t_e + dt) + R_body_to_world(t_e + dt) l_b
    R_cam_to_world,i = R_body_to_world(t_e + dt) R_cam_to_body
Boresight: a unit quaternion updated with a minimal 3-parameter multiplicative (left, body-axes) correction,
R_cam_to_body = Exp(theta_b) R_hat, so no unit-norm constraint is needed; the quaternion is reported.
Observations: the 3 position and 3 rotation residuals of each epoch, weighted by the full 6x6 covariance of
EOP (bundle) and POS (smoother) errors propagated through the model. Epochs failing a chi-square test
(6 dof, 99.9 %) against the robust scale are rejected and listed. Covariance: N^-1 scaled by
max(1, sigma0^2), so optimistic input sigmas do not give optimistic results, plus the effect of the POS
error common to all epochs (`common_mode_covariance`, weighted by `pos_common_fraction`): POS errors
driven by slowly varying states do not average down over one flight.
"""
from __future__ import annotations

import numpy as np
from scipy.special import gammaincinv   # not scipy.stats: its import alone takes 0.5-0.8 s of every `dgcal mount`

from dgcal.bundle.solver.blocks import BlockEval, FunctionBlock, State
from dgcal.bundle.solver.covariance import Covariance, normal_rhs
from dgcal.bundle.solver.lm import LMOptions, minimise
from dgcal.bundle.solver.normals import Problem, linearise
from dgcal.calib.mounting.common import POS_COMMON_FRACTION, Epochs, MountingResult
from dgcal.calib.mounting.two_step import calibrate_traditional
from dgcal.fields.errors import InputError
from dgcal.fields.frames import skew
from dgcal.fields.pose import Poses, so3_exp, so3_log, so3_right_jacobian, so3_right_jacobian_inv
from dgcal.fields.pose import transpose as T

DEFAULT_EOP_SIGMA = (0.05, np.radians(0.01))        # m, rad when the EOP file has no sigmas
DEFAULT_POS_SIGMA = (0.10, np.radians(0.02), np.radians(0.05))  # m, roll/pitch rad, heading rad


def default_cov(n: int, sp: float, sa: tuple) -> np.ndarray:
    """(n,6,6) diagonal covariance: position sigma sp (m), rotation sigmas sa (3, rad)."""
    C = np.zeros((n, 6, 6))
    C[:, [0, 1, 2], [0, 1, 2]] = sp**2
    C[:, [3, 4, 5], [3, 4, 5]] = np.asarray(sa, float) ** 2
    return C


def predict(ep: Epochs, x: np.ndarray, R_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predicted camera positions (N,3), `R_cam_to_world` (N,3,3) and body rotations at exposure for parameters
    x = [dt, l_b(3), theta_b(3)] around boresight R_hat."""
    dt, lever, theta = x[0], x[1:4], x[4:7]
    ddt = dt - ep.dt_ref  # the POS of `ep` is already at t_event + dt_ref
    R_body_to_world = ep.pos.R_body_to_world @ so3_exp(ep.pos.omega_b * ddt)
    p = ep.pos.r_imu_world + ep.pos.v_world * ddt + np.einsum("nij,j->ni", R_body_to_world, lever)
    return p, R_body_to_world @ (so3_exp(theta) @ R_hat), R_body_to_world


def residuals(ep: Epochs, x: np.ndarray, R_hat: np.ndarray) -> np.ndarray:
    """(N,6) residuals: position (m, world) and rotation Log(R_cam_to_world_pred^T R_cam_to_world_eop) (rad, camera
    frame)."""
    p, R_cam_to_world_pred, _ = predict(ep, x, R_hat)
    return np.column_stack([ep.eop.C_world - p, so3_log(T(R_cam_to_world_pred) @ ep.eop.R_cam_to_world)])


def residual_jacobian(ep: Epochs, x: np.ndarray, R_hat: np.ndarray) -> np.ndarray:
    """(N,6,7) d(residuals)/dx, x = [dt (s), l_b (m), theta_b (rad)]: position rows -dp/dx (world, m), rotation rows
    d Log(R_cam_to_world_pred^T R_cam_to_world_eop)/dx (camera frame, rad); R_body_to_world(dt) =
    R_body_to_world Exp(omega_b dt) about a fixed axis, so dR_body_to_world/dt = R_body_to_world [omega_b]x, and a
    change of theta_b moves R_cam_to_body by Exp(R_hat^T Jr(theta_b) d) on the right."""
    dt, lever, theta = x[0], x[1:4], x[4:7]
    w = ep.pos.omega_b
    R_body_to_world = ep.pos.R_body_to_world @ so3_exp(w * (dt - ep.dt_ref))
    R_cam_to_body = so3_exp(theta) @ R_hat
    e = so3_log(T(R_body_to_world @ R_cam_to_body) @ ep.eop.R_cam_to_world)
    Jl_inv = so3_right_jacobian_inv(-e)            # Log(Exp(a) Exp(e)) ~ e + Jl^-1(e) a
    J = np.zeros((len(ep), 6, 7))
    J[:, :3, 0] = -(ep.pos.v_world + np.einsum("nij,nj->ni", R_body_to_world, np.cross(w, lever)))
    J[:, :3, 1:4] = -R_body_to_world
    J[:, 3:, 0] = -np.einsum("nij,nj->ni", Jl_inv, np.einsum("ji,nj->ni", R_cam_to_body, w))
    J[:, 3:, 4:7] = -Jl_inv @ (R_hat.T @ so3_right_jacobian(theta))
    return J


def residual_covariance(ep: Epochs, x: np.ndarray, R_hat: np.ndarray) -> np.ndarray:
    """(N,6,6) covariance of the residuals from EOP and POS covariances (defaults when not given)."""
    n = len(ep)
    C_eop = ep.eop.cov if ep.eop.cov is not None else default_cov(n, DEFAULT_EOP_SIGMA[0], (DEFAULT_EOP_SIGMA[1],) * 3)
    C_pos = _pos_cov(ep)
    G = pos_error_jacobian(ep, x, R_hat)
    return C_eop + G @ C_pos @ T(G)


def pos_error_jacobian(ep: Epochs, x: np.ndarray, R_hat: np.ndarray) -> np.ndarray:
    """(N,6,6) d(residual)/d(POS error): position error in the world (m), attitude error about body axes (rad)."""
    n = len(ep)
    _, _, R_body_to_world = predict(ep, x, R_hat)
    R_cam_to_body = so3_exp(x[4:7]) @ R_hat
    G = np.zeros((n, 6, 6))
    G[:, :3, :3] = -np.eye(3)
    G[:, :3, 3:] = R_body_to_world @ skew(x[1:4])  # -(-R_body_to_world [l]x)
    G[:, 3:, 3:] = -R_cam_to_body.T
    return G


def _pos_cov(ep: Epochs) -> np.ndarray:
    if ep.pos.cov is not None:
        return ep.pos.cov
    return default_cov(len(ep), DEFAULT_POS_SIGMA[0], DEFAULT_POS_SIGMA[1:2] * 2 + DEFAULT_POS_SIGMA[2:])


def _epoch_block(ep: Epochs, R_hat: np.ndarray, W: np.ndarray) -> FunctionBlock:
    """The engine block of the per-epoch residuals, whitened by W (N,6,6) and linear in nothing but the 7
    mounting globals x = [dt, l_b, theta_b] (`residual_jacobian`)."""

    def fun(state: State, jacobians: bool) -> BlockEval:
        x = state.globals
        r = np.einsum("nij,nj->ni", W, residuals(ep, x, R_hat))
        ev = BlockEval(r, np.ones(len(ep), bool))
        if jacobians:
            ev.glob, ev.J_glob = np.arange(7), W @ residual_jacobian(ep, x, R_hat)
        return ev

    return FunctionBlock(fun, len(ep), 6, name="epochs")


def _problem(ep: Epochs, R_hat: np.ndarray, W: np.ndarray, fix_delay: bool) -> Problem:
    return Problem([_epoch_block(ep, R_hat, W)], 0, 0, 7, global_free=np.arange(7) >= (1 if fix_delay else 0))


def _no_poses(x: np.ndarray) -> State:
    return State(Poses(np.zeros((0, 3, 3)), np.zeros((0, 3))), np.zeros((0, 3)), np.asarray(x, float).copy())


def common_mode_covariance(ep: Epochs, x: np.ndarray, R_hat: np.ndarray, fix_delay: bool) -> np.ndarray:
    """(7,7) parameter covariance from the POS error that all epochs share.

    A smoothed trajectory's errors are driven by slowly varying states (accelerometer bias -> tilt,
    GNSS biases -> position), so they do not average down over the epochs of one flight the way the
    per-epoch weighting assumes: a constant POS pitch error is indistinguishable from boresight pitch.
    The mean POS covariance, taken as an error common to every epoch, is pushed through the
    estimator (x = N^-1 J^T W r): a conservative bound, since part of the POS error is random.
    """
    free = np.arange(1 if fix_delay else 0, 7)
    W = _whiten(residual_covariance(ep, x, R_hat))
    prob = _problem(ep, R_hat, W, fix_delay)
    nrm = linearise(prob, _no_poses(x))
    B = np.einsum("nij,njk->nik", W, pos_error_jacobian(ep, x, R_hat))
    b_c, b_x = normal_rhs(prob, nrm, 0, B)
    S = Covariance.at(prob, nrm).response(b_c, b_x)[0][free]
    C = np.zeros((7, 7))
    C[np.ix_(free, free)] = S @ _pos_cov(ep).mean(axis=0) @ S.T
    return C


def _whiten(C: np.ndarray) -> np.ndarray:
    """Per-epoch whitening matrices W with W C W^T = I."""
    Lc = np.linalg.cholesky(C)
    return np.linalg.inv(Lc)


def _solve(ep: Epochs, R_hat: np.ndarray, x0: np.ndarray, fix_delay: bool, iters: int = 20):
    """Weighted least squares with the weights of the residual covariance at the current solution: the engine
    solves for fixed weights, the weights and the boresight's reference R_hat are renewed until x settles."""
    x = x0.copy()
    free = np.arange(1 if fix_delay else 0, 7)
    for _ in range(iters):
        W = _whiten(residual_covariance(ep, x, R_hat))
        sol = minimise(_problem(ep, R_hat, W, fix_delay), _no_poses(x),
                       LMOptions(max_iterations=50, tol_chi2=1e-12, tol_rel=1e-16))
        step = sol.state.globals - x
        x = sol.state.globals.copy()
        R_hat = so3_exp(x[4:7]) @ R_hat
        x[4:7] = 0.0
        if np.max(np.abs(step[free])) < 1e-10:
            break
    W = _whiten(residual_covariance(ep, x, R_hat))
    e = residuals(ep, x, R_hat)
    Tstat = np.einsum("ni,ni->n", np.einsum("nij,nj->ni", W, e), np.einsum("nij,nj->ni", W, e))
    prob = _problem(ep, R_hat, W, fix_delay)
    Q = Covariance.at(prob, linearise(prob, _no_poses(x))).global_cofactors()
    Ninv = np.zeros((7, 7))
    Ninv[np.ix_(free, free)] = Q[np.ix_(free, free)]
    return x, R_hat, e, Tstat, Ninv


def _solve_robust(ep, x0, R_hat, keep, fix_delay, reject, limit):
    """Solve, test every epoch against the chi-square limit, re-solve until the kept set is stable."""
    for _ in range(10):
        sub = ep.subset(keep)
        if len(sub) < 3:
            raise InputError(f"only {len(sub)} usable epochs (images with both an EOP and an event) after "
                             "rejection: the adjustment needs at least 3", field="image")
        x, R_hat_s, e, Tstat, Ninv = _solve(sub, R_hat, x0, fix_delay)
        scale = max(1.0, float(np.median(Tstat) / chi2_quantile(0.5, 6)))
        # test every epoch (also rejected ones, so a wrongly rejected epoch can come back)
        W = _whiten(residual_covariance(ep, x, R_hat_s))
        e_all = np.einsum("nij,nj->ni", W, residuals(ep, x, R_hat_s))
        T_all = np.einsum("ni,ni->n", e_all, e_all)
        new_keep = (T_all / scale <= limit) if reject else np.ones(len(ep), bool)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
        x0, R_hat = x, R_hat_s
    return x, R_hat_s, keep, Tstat, Ninv, T_all


def chi2_quantile(p: float, dof: int) -> float:
    """The p-quantile of the chi-square distribution with `dof` degrees of freedom (scipy.stats.chi2.ppf, by the
    same special function)."""
    return float(2.0 * gammaincinv(dof / 2, p))


def calibrate_proposed(ep: Epochs, *, fix_delay: bool = False, reject: bool = True,
                       confidence: float = 0.999, pos_common_fraction: float = POS_COMMON_FRACTION) -> MountingResult:
    """Delay, lever arm and boresight by weighted least squares with outlier rejection (see module docstring).

    `pos_common_fraction` (0-1) is the share of the POS error variance common to all epochs of the
    flight (bias-driven tilt, GNSS biases); 0 treats POS errors as independent between photos (the seed's
    assumption), 1 as entirely common (conservative for a smoothed MEMS trajectory).
    """
    if not 0.0 <= pos_common_fraction <= 1.0:
        raise InputError(f"pos_common_fraction must be within 0..1, got {pos_common_fraction}",
                         field="pos_common_fraction")
    init = calibrate_traditional(ep)
    x0 = np.r_[0.0, init.lever_arm_m, 0, 0, 0]
    R_hat = init.R_cam_to_body
    keep = np.ones(len(ep), bool)
    limit = chi2_quantile(confidence, 6)
    for _outer in range(5):
        x, R_hat, keep, Tstat, Ninv, T_all = _solve_robust(ep, x0, R_hat, keep, fix_delay, reject, limit)
        # re-interpolate the POS at the new exposure times so the linear propagation only spans the last step
        if fix_delay or not ep.can_resample or abs(x[0] - ep.dt_ref) < 1e-5:
            break
        try:
            ep = ep.at_delay(float(x[0]))
        except InputError as exc:
            # an exposure time beyond the trajectory's end: keep the linear propagation for this solution
            ep.warnings.append(f"POS not re-interpolated at t_event + delay ({exc}); linear propagation used")
            break
        x0 = x
    R_hat_s = R_hat
    n = int(keep.sum())
    dof = 6 * n - (6 if fix_delay else 7)
    sigma0_sq = float(Tstat.sum() / max(dof, 1))
    cov_random = Ninv * max(1.0, sigma0_sq)
    cov_common = (pos_common_fraction * common_mode_covariance(ep.subset(keep), x, R_hat, fix_delay)
                  if pos_common_fraction > 0 else np.zeros((7, 7)))
    cov = cov_random + cov_common
    # per-epoch values with the delay applied (seed Fig. 22): what each epoch says about l_b and the boresight
    _, _, R_body_to_world = predict(ep, x, R_hat_s)
    r_imu_world = ep.pos.r_imu_world + ep.pos.v_world * (x[0] - ep.dt_ref)
    lever_i = np.einsum("nji,nj->ni", R_body_to_world, ep.eop.C_world - r_imu_world)
    ang_i = so3_log((T(R_body_to_world) @ ep.eop.R_cam_to_world) @ R_hat_s.T)
    e_full = residuals(ep, x, R_hat_s)
    per_epoch = {"image": [str(s) for s in ep.image], "t_event": ep.t_event.tolist(),
                 "lever_arm_m": lever_i.tolist(), "boresight_deg": np.degrees(ang_i).tolist(),
                 "residual_position_m": e_full[:, :3].tolist(),
                 "residual_rotation_deg": np.degrees(e_full[:, 3:]).tolist(),
                 "test_statistic": T_all.tolist(), "rejected": (~keep).tolist()}
    res = MountingResult("proposed", x[1:4].copy(), R_hat_s, 0.0 if fix_delay else float(x[0]), cov, n,
                         [str(s) for s in ep.image[~keep]], list(ep.warnings), per_epoch)
    res.extra.update({"sigma0": float(np.sqrt(sigma0_sq)), "redundancy": int(dof),
                      "covariance_scaled_by": float(max(1.0, sigma0_sq)),
                      "sigma_random": np.sqrt(np.diag(cov_random)).tolist(),
                      "sigma_pos_common_mode": np.sqrt(np.diag(cov_common)).tolist(),
                      "pos_common_fraction": float(pos_common_fraction),
                      "covariance_random": [[float(v) for v in row] for row in cov_random],
                      "covariance_model": "per-epoch EOP and POS errors (scaled by max(1, sigma0^2)) plus "
                                          "pos_common_fraction x the mean POS covariance as an error common to "
                                          "all epochs",
                      "boresight_parameterisation": "unit quaternion with minimal 3-parameter multiplicative update "
                                                    "R_cam_to_body = Exp(theta_b) R_hat (theta about body axes)",
                      "propagation": ("POS re-interpolated at t_event + delay (iterated); within an iteration "
                                      "position propagated with the POS velocity, attitude with the body angular rate")
                      if ep.can_resample else
                      "position propagated with the POS velocity; attitude held fixed "
                      "(no angular rate in an events file)",
                      "rejection_limit_chi2_6dof": float(limit)})
    if not reject:
        res.extra["rejection"] = "off"
    return res
