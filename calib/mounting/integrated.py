"""One-step integrated sensor orientation (ISO): a bundle adjustment of the control-field flight with the POS as
observations, estimating the lever arm, boresight and exposure delay in the same adjustment.

Unknowns (world frame of the block): every image's pose (C_world,i, R_cam_to_world,i), the ground points (control
points weighted by their sigmas, all others free tie points; points with role `check` are never control), and
the mounting x = [dt, l_b, theta_b].
Observations:
- image measurements (px, collinearity with the camera model, weighted by the pixel sigmas); selected
  intrinsics (`refine_intrinsics`) may be estimated too;
- control point coordinates (m);
- POS at every event, propagated over the delay as in the `proposed` method:
    C_world,i = r_imu_world,i + v_world,i dt + R_body_to_world,i Exp(omega_b,i dt) l_b,
    R_cam_to_world,i = R_body_to_world,i Exp(omega_b,i dt) Exp(theta_b) R_hat   (R_hat: the initial R_cam_to_body),
  weighted by the POS covariance (position and attitude).
Solved by the engine of `dgcal.bundle.solver` (image observations, control-point priors and a POS block per
epoch; poses follow `dgcal.fields.pose`); the covariance of the mounting comes from the full normal matrix,
scaled by max(1, sigma0^2), plus `pos_common_fraction` x the mean POS covariance taken as an error common to
all epochs (bias-driven tilt,
GNSS biases of a smoothed MEMS POS do not average down over one flight): its effect on the mounting is the
sensitivity S = N^-1 J^T B of the estimate to a constant POS error (B: whitened POS residuals per unit
position error in world axes and attitude error about body axes), computed with the same Schur elimination.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dgcal.bundle.intersection import intersect
from dgcal.bundle.solver.blocks import BlockEval, FunctionBlock, ImageObservations, PointPriors, State
from dgcal.bundle.solver.covariance import Covariance, normal_rhs
from dgcal.bundle.solver.lm import LMOptions, minimise, normals_at
from dgcal.bundle.solver.normals import Problem
from dgcal.calib.camera.files import load_camera
from dgcal.calib.mounting.common import POS_COMMON_FRACTION, MountingResult, build_epochs
from dgcal.calib.mounting.observability import observability_warnings
from dgcal.calib.mounting.plausibility import check_epochs, result_warnings
from dgcal.calib.mounting.joint import DEFAULT_POS_SIGMA, default_cov, calibrate_proposed
from dgcal.fields.crs import MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import EOP, Events, Measurements, Points, Trajectory, read_measurements, read_points
from dgcal.fields.io.gcp_files import is_odm_gcp_list, read_odm_gcp_list
from dgcal.fields.frames import skew
from dgcal.fields.pose import Poses, so3_exp, so3_log, so3_right_jacobian_inv
from dgcal.fields.pose import transpose as T
from dgcal.fields.world import World

DEFAULT_PIXEL_SIGMA = 0.5
DEFAULT_GCP_SIGMA = 0.02


def calibrate_iso(eop: EOP, grid: MapGrid, traj: Trajectory, events: Events, meas: Measurements, gcp: Points,
                  camera, *, fix_delay: bool = False, max_iterations: int = 30,
                  refine_intrinsics: tuple[str, ...] = (), pos_common_fraction: float = POS_COMMON_FRACTION,
                  critical_w: float = 4.0) -> MountingResult:
    """ISO mounting calibration; `eop` (e.g. a bundle or DG result) only initialises the image poses; image
    measurements whose w-test exceeds `critical_w` are rejected (listed in extra["rejected_observations"]).
    `refine_intrinsics` names camera parameters (e.g. ("f", "cx", "cy")) estimated in the same adjustment.
    `pos_common_fraction` (0-1): share of the POS error variance common to all epochs of the flight (as in
    `calibrate_proposed`; 0 = independent per photo)."""
    if not 0.0 <= pos_common_fraction <= 1.0:
        raise InputError(f"pos_common_fraction must be within 0..1, got {pos_common_fraction}",
                         field="pos_common_fraction")
    bad = [k for k in refine_intrinsics if k not in camera.PARAMS]
    if bad:
        raise InputError(f"camera model {camera.NAME} has no parameter {bad[0]!r} ({', '.join(camera.PARAMS)})",
                         field="refine_intrinsics")
    i_intr = [camera.PARAMS.index(k) for k in refine_intrinsics]
    world = World.at_map_points(grid, eop.xyz)
    ep = build_epochs(world, eop, events, traj)
    check_epochs(ep, eop.path)
    init = calibrate_proposed(ep, fix_delay=fix_delay)
    blk = _iso_block(camera, ep, meas, gcp, world)
    R_hat = init.R_cam_to_body.copy()
    C_pos, W_pos = _pos_weights(ep.pos, init.delay_s, init.lever_arm_m, R_hat)
    free_m = np.arange(1 if fix_delay else 0, 7)
    prob = _iso_problem(camera, blk, ep.pos, R_hat, W_pos, refine_intrinsics, free_m)
    x0 = np.r_[init.delay_s if not fix_delay else 0.0, init.lever_arm_m, 0, 0, 0, camera.params[i_intr]]
    start = State(Poses(ep.eop.R_world_to_cam.copy(), ep.eop.C_world), blk.X0, x0)
    lm = LMOptions(max_iterations=max_iterations, tol_chi2=1e-4, tol_rel=1e-12)
    sol = minimise(prob, start, lm)
    nrm = normals_at(prob, sol)
    rejected: list[dict] = []
    for _ in range(MAX_SNOOPING_ROUNDS):
        # data snooping on the image measurements: the worst measurement of each point whose w-test fails
        bad, w_all = _image_blunders(prob, nrm, blk, critical_w)
        if not len(bad):
            break
        rpx = nrm.evals[0].r[bad] * blk.sig_uv[bad]
        rejected += [{"image": str(blk.meas.image[k]), "id": str(blk.meas.id[k]), "residual_px": rpx[n].tolist(),
                      "w": float(w)} for n, (k, w) in enumerate(zip(bad, w_all[bad]))]
        keep = np.ones(len(blk.obs_img), bool)
        keep[bad] = False
        blk = blk.subset(keep)
        prob = _iso_problem(camera, blk, ep.pos, R_hat, W_pos, refine_intrinsics, free_m)
        sol = minimise(prob, sol.state, lm)
        nrm = normals_at(prob, sol)
    sigma0_sq = float(nrm.cost / max(int(nrm.redundancy), 1))
    mt = sol.state.globals[:7]
    R_cam_to_body = so3_exp(mt[4:7]) @ R_hat
    cov = _iso_covariance(prob, nrm, ep.pos, W_pos, C_pos, mt, R_cam_to_body, free_m, len(i_intr), sigma0_sq,
                          pos_common_fraction)
    res = _iso_result(ep, world, blk, prob, sol, nrm, cov, R_cam_to_body, fix_delay, refine_intrinsics,
                      pos_common_fraction, init)
    res.extra["rejected_observations"] = rejected
    if rejected:
        res.warnings.append(f"{len(rejected)} image measurement(s) rejected as blunders (w-test > {critical_w:g}): "
                            + ", ".join(f"{r['id']} in {r['image']}" for r in rejected[:5])
                            + (" ..." if len(rejected) > 5 else ""))
    res.warnings += result_warnings(res, ep)
    return res


MAX_SNOOPING_ROUNDS = 20


def _image_w(prob: Problem, nrm) -> np.ndarray:
    """|w| of every image measurement (the larger of its two coordinates; 0 where it cannot be tested)."""
    r = Covariance.at(prob, nrm).redundancy_numbers(0)
    w = np.abs(nrm.evals[0].r) / np.sqrt(np.clip(r, 1e-9, None))
    return np.where(r > 0.02, w, 0.0).max(1)


def _image_blunders(prob: Problem, nrm, blk: "_IsoBlock", critical: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the worst measurement of each point with a w-test above `critical` (several at once, one per
    point: a blunder also inflates the other rays of its own point, rarely those of others), and every
    measurement's |w|."""
    w = _image_w(prob, nrm)
    cand = np.flatnonzero(w > critical)
    if not len(cand):
        return cand, w
    order = cand[np.argsort(-w[cand])]
    _, first = np.unique(blk.obs_pt[order], return_index=True)
    return np.sort(order[first]), w


@dataclass
class _IsoBlock:
    """The images, points and measurements of the ISO adjustment, and the initial points (world, m)."""

    img_names: list[str]
    pt_names: list[str]
    meas: Measurements     # the measurements in images with an epoch
    obs_img: np.ndarray
    obs_pt: np.ndarray
    sig_uv: np.ndarray     # px
    ctrl: np.ndarray       # (K,) control point mask
    X_ctrl: np.ndarray     # control coordinates (world, m)
    s_ctrl: np.ndarray     # their sigmas (m)
    X0: np.ndarray         # (K,3) initial points (world, m)

    def subset(self, keep: np.ndarray) -> "_IsoBlock":
        """The block with only the measurements `keep` (the points stay, indices unchanged)."""
        return _IsoBlock(self.img_names, self.pt_names, self.meas.subset(keep), self.obs_img[keep],
                         self.obs_pt[keep], self.sig_uv[keep], self.ctrl, self.X_ctrl, self.s_ctrl, self.X0)


def _iso_block(camera, ep, meas: Measurements, gcp: Points, world: World) -> _IsoBlock:
    """Index the measurements of the epochs' images; control points from the file, the others intersected from the
    initial poses (InputError with fewer than 3 measured control points or a point seen once)."""
    img_names = [str(s) for s in ep.image]
    img_idx = {k: i for i, k in enumerate(img_names)}
    gid = {str(k): j for j, k in enumerate(gcp.ids)}
    m = meas.subset(np.array([str(im) in img_idx for im in meas.image], bool))
    pt_names = list(dict.fromkeys(str(k) for k in m.id))
    pt_idx = {k: j for j, k in enumerate(pt_names)}
    obs_img = np.array([img_idx[str(k)] for k in m.image], int)
    obs_pt = np.array([pt_idx[str(k)] for k in m.id], int)
    sig_uv = np.where(np.isfinite(m.sigma), m.sigma, DEFAULT_PIXEL_SIGMA)
    ctrl = np.array([k in gid and gcp.role[gid[k]] == "control" for k in pt_names], bool)
    if ctrl.sum() < 3:
        raise InputError(f"ISO needs at least 3 measured control points, found {int(ctrl.sum())}", gcp.path,
                         field="role")
    ctrl_rows = np.array([gid[k] for k in np.array(pt_names)[ctrl]], int)
    X_ctrl = world.to_world(gcp.xyz[ctrl_rows])
    s_ctrl = np.where(np.isfinite(gcp.sigma[ctrl_rows]), gcp.sigma[ctrl_rows], DEFAULT_GCP_SIGMA)
    res0 = intersect(camera, ep.eop.C_world, ep.eop.R_cam_to_world, obs_img, obs_pt, m.xy, sig_uv, len(pt_names))
    X0 = np.where(res0.ok[:, None], res0.xyz, 0.0)
    X0[ctrl] = X_ctrl
    lonely = ~res0.ok & ~ctrl
    if lonely.any():
        raise InputError(f"{int(lonely.sum())} points are seen in fewer than 2 images "
                         f"(e.g. {np.array(pt_names)[lonely][0]!r})", meas.path, field="id")
    return _IsoBlock(img_names, pt_names, m, obs_img, obs_pt, sig_uv, ctrl, X_ctrl, s_ctrl, X0)


def _pos_weights(pos, dt: float, lever: np.ndarray, R_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The POS covariance (M,6,6) (the defaults without one) and the POS residual weights W (M,6,6), from the POS
    covariance through the model at the initial mounting."""
    C_pos = pos.cov if pos.cov is not None else default_cov(len(pos.r_imu_world), DEFAULT_POS_SIGMA[0],
                                                             DEFAULT_POS_SIGMA[1:2] * 2 + DEFAULT_POS_SIGMA[2:])
    W_pos = np.linalg.inv(np.linalg.cholesky(_pos_G(pos, dt, lever, R_hat) @ C_pos @ T(_pos_G(pos, dt, lever, R_hat))))
    return C_pos, W_pos


def _iso_problem(camera, blk: _IsoBlock, pos, R_hat: np.ndarray, W_pos: np.ndarray,
                 refine_intrinsics: tuple[str, ...], free_m: np.ndarray) -> Problem:
    """The engine problem: image observations, control-point priors and the POS block (its last block); globals
    [dt, lever (3), theta (3)] then the refined intrinsics."""
    M, K = len(blk.img_names), len(blk.pt_names)
    n_glob = 7 + len(refine_intrinsics)
    pos_block = FunctionBlock(lambda st, jac: _pos_residuals(st, pos, R_hat, W_pos, jac), M, 6, name="pos")
    blocks = [ImageObservations(camera, blk.obs_img, blk.obs_pt, blk.meas.xy, blk.sig_uv, refine_intrinsics, 7),
              PointPriors.from_arrays(blk.X_ctrl, blk.s_ctrl, np.flatnonzero(blk.ctrl)), pos_block]
    glob_free = np.ones(n_glob, bool)
    glob_free[:7] = np.isin(np.arange(7), free_m)
    return Problem(blocks, M, K, n_glob, global_free=glob_free)


@dataclass
class _IsoCovariance:
    """Mounting covariances (7,7): total, random part, POS common-mode part; and of the free globals."""

    total: np.ndarray
    random: np.ndarray
    common: np.ndarray
    glob: np.ndarray


def _iso_covariance(prob: Problem, nrm, pos, W_pos: np.ndarray, C_pos: np.ndarray, mt: np.ndarray,
                    R_cam_to_body: np.ndarray, free_m: np.ndarray, n_intr: int, sigma0_sq: float,
                    pos_common_fraction: float) -> _IsoCovariance:
    """The normal matrix's covariance of the mounting (scaled by max(1, sigma0^2)) plus the response of the
    mounting to a POS error common to all epochs (position in world axes, attitude about body axes): the POS
    observation enters the residual as in `calibrate_proposed`."""
    M = len(pos.r_imu_world)
    cov_eng = Covariance.at(prob, nrm)
    B = np.einsum("nij,njk->nik", W_pos, _pos_G(pos, mt[0], mt[1:4], R_cam_to_body))
    b_c, b_x = normal_rhs(prob, nrm, len(prob.blocks) - 1, B)
    resp_c, _ = cov_eng.response(b_c, b_x)
    glob_cols = 6 * M + np.r_[free_m, 7 + np.arange(n_intr)]
    sens_glob = resp_c[glob_cols]
    cof_glob = cov_eng.Q_cc[np.ix_(glob_cols, glob_cols)]
    cov_glob_random = cof_glob * max(1.0, sigma0_sq)
    cov_glob_common = pos_common_fraction * sens_glob @ C_pos.mean(axis=0) @ sens_glob.T
    cov_glob = cov_glob_random + cov_glob_common
    out = _IsoCovariance(np.zeros((7, 7)), np.zeros((7, 7)), np.zeros((7, 7)), cov_glob)
    nf = len(free_m)
    for C7, Cg in ((out.total, cov_glob), (out.random, cov_glob_random), (out.common, cov_glob_common)):
        C7[np.ix_(free_m, free_m)] = Cg[:nf, :nf]
    return out


def _iso_result(ep, world: World, blk: _IsoBlock, prob: Problem, sol, nrm, cov: _IsoCovariance,
                R_cam_to_body: np.ndarray, fix_delay: bool, refine_intrinsics: tuple[str, ...],
                pos_common_fraction: float, init: MountingResult) -> MountingResult:
    """The mounting result: parameters, POS residuals per epoch, warnings, fit statistics and the adjusted EOPs."""
    g = sol.state.globals
    mt = g[:7]
    pos, poses = ep.pos, sol.state.poses
    dof = int(nrm.redundancy)
    sigma0_sq = float(nrm.cost / max(dof, 1))
    M, K = len(blk.img_names), len(blk.pt_names)
    Xc = poses.to_cam(sol.state.points[blk.obs_pt], blk.obs_img)
    rpx = prob.blocks[0].camera_at(g).project(Xc) - blk.meas.xy
    # POS residuals at the solution (as `proposed`); the image list also tells `covariance_for_flight` which
    # photos are this flight's, whose POS errors already carry the common part
    R_body_to_world = pos.R_body_to_world @ so3_exp(pos.omega_b * mt[0])
    p_f = pos.r_imu_world + pos.v_world * mt[0] + np.einsum("nij,j->ni", R_body_to_world, mt[1:4])
    R_cam_to_world_f = R_body_to_world @ R_cam_to_body
    e_f = np.column_stack([poses.C_world - p_f, so3_log(T(R_cam_to_world_f) @ poses.R_cam_to_world)])
    per_epoch = {"image": blk.img_names, "residual_position_m": e_f[:, :3].tolist(),
                 "residual_rotation_deg": np.degrees(e_f[:, 3:]).tolist()}
    res = MountingResult("iso", mt[1:4].copy(), R_cam_to_body, 0.0 if fix_delay else float(mt[0]), cov.total, M,
                         [], list(ep.warnings) + observability_warnings(ep), per_epoch)
    corr = res.correlation()
    for i in range(7):
        for j in range(i + 1, 7):
            if np.isfinite(corr[i, j]) and abs(corr[i, j]) > 0.9:
                res.warnings.append(f"high correlation {corr[i, j]:+.3f} between {res.PARAM_NAMES[i]} and "
                                    f"{res.PARAM_NAMES[j]}")
    res.extra.update({"sigma0": float(np.sqrt(sigma0_sq)), "redundancy": int(dof),
                      "covariance_scaled_by": float(max(1.0, sigma0_sq)),
                      "n_image_observations": int(len(blk.obs_img)),
                      "n_control_points": int(blk.ctrl.sum()), "n_tie_points": int(K - blk.ctrl.sum()),
                      "image_rms_px": float(np.sqrt(np.mean(rpx**2))), "iterations": int(sol.iterations),
                      "converged": bool(sol.converged), "stop_reason": sol.stop_reason,
                      "sigma_random": np.sqrt(np.diag(cov.random)).tolist(),
                      "sigma_pos_common_mode": np.sqrt(np.diag(cov.common)).tolist(),
                      "pos_common_fraction": float(pos_common_fraction),
                      "covariance_random": [[float(v) for v in row] for row in cov.random],
                      "covariance_model": "normal matrix of the bundle (scaled by max(1, sigma0^2)) plus "
                                          "pos_common_fraction x the mean POS covariance as an error common to "
                                          "all epochs",
                      "boresight_parameterisation": "unit quaternion with minimal 3-parameter multiplicative update",
                      "initialisation": {"method": "proposed", "delay_s": init.delay_s,
                                         "lever_arm_m": init.lever_arm_m.tolist()},
                      "skipped_images": ep.skipped})
    if refine_intrinsics:
        nf = len(cov.glob) - len(refine_intrinsics)
        res.extra["intrinsics"] = {k: float(v) for k, v in zip(refine_intrinsics, g[7:])}
        res.extra["intrinsics_sigma"] = {k: float(v) for k, v in
                                         zip(refine_intrinsics, np.sqrt(np.diag(cov.glob)[nf:]))}
    xyz_map, opk = world.poses_to_eop(poses)[:2]
    res.extra["adjusted_eop"] = {"image": blk.img_names, "xyz": xyz_map.tolist(), "opk_deg": opk.tolist()}
    return res


def _pos_G(pos, dt: float, lever: np.ndarray, R_cam_to_body: np.ndarray) -> np.ndarray:
    """(M,6,6) d(POS residual)/d(POS error): position error in world axes, attitude error about body axes."""
    M = len(pos.r_imu_world)
    G = np.zeros((M, 6, 6))
    G[:, :3, :3] = -np.eye(3)
    G[:, :3, 3:] = (pos.R_body_to_world @ so3_exp(pos.omega_b * dt)) @ skew(lever)
    G[:, 3:, 3:] = -R_cam_to_body.T
    return G


def _pos_prediction(pos, x: np.ndarray, R_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera centres (M,3) and R_cam_to_world (M,3,3) the POS predicts for mounting x = [dt, lever, theta]."""
    R_body_to_world = pos.R_body_to_world @ so3_exp(pos.omega_b * x[0])
    p = pos.r_imu_world + pos.v_world * x[0] + np.einsum("nij,j->ni", R_body_to_world, x[1:4])
    return p, R_body_to_world @ (so3_exp(x[4:7]) @ R_hat)


def _pos_residuals(state: State, pos, R_hat: np.ndarray, W_pos: np.ndarray, jacobians: bool) -> BlockEval:
    """Whitened POS residuals per epoch: W [C_world - p(x), Log(R_cam_to_world_pred(x)^T R_cam_to_world)], with the
    Jacobians d/d(pose) analytic (right Jacobian) and d/d(mounting) by central differences."""
    x = state.globals[:7]
    M = len(pos.r_imu_world)
    C_world, R_cam_to_world = state.poses.C_world, state.poses.R_cam_to_world

    def raw(xx):
        p, R_cam_to_world_pred = _pos_prediction(pos, xx, R_hat)
        return np.column_stack([C_world - p, so3_log(T(R_cam_to_world_pred) @ R_cam_to_world)])

    e = raw(x)
    r = np.einsum("nij,nj->ni", W_pos, e)
    ev = BlockEval(r, np.ones(M, bool))
    if not jacobians:
        return ev
    J_pose = np.zeros((M, 6, 6))
    J_pose[:, :3, :3] = np.eye(3)
    J_pose[:, 3:, 3:] = so3_right_jacobian_inv(e[:, 3:])   # Log(A Exp(d)) = Log(A) + Jr^-1 d
    J_glob = np.empty((M, 6, 7))
    for k in range(7):
        h = 1e-5 if k == 0 else 1e-6
        dx = np.zeros(7)
        dx[k] = h
        J_glob[:, :, k] = (raw(x + dx) - raw(x - dx)) / (2 * h)
    ev.pose, ev.J_pose = np.arange(M), W_pos @ J_pose
    ev.glob, ev.J_glob = np.arange(7), W_pos @ J_glob
    return ev


def calibrate_iso_files(eop: EOP, grid: MapGrid, traj: Trajectory, events: Events, meas_path: Path,
                        gcp_path: Path, camera_path: Path, **kw) -> MountingResult:
    """`calibrate_iso` with measurements (CSV or ODM gcp_list.txt), ground points and camera read from files."""
    meas = read_odm_gcp_list(meas_path)[2] if is_odm_gcp_list(meas_path) else read_measurements(meas_path)
    return calibrate_iso(eop, grid, traj, events, meas, read_points(gcp_path), load_camera(camera_path), **kw)
