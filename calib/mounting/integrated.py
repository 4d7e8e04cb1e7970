"""One-step integrated sensor orientation (ISO): a bundle adjustment of the control-field flight with the POS as
observations, estimating the lever arm, boresight and exposure delay in the same adjustment.

Unknowns (block frame L): per image the projection centre C_i and a rotation correction d_i
(R_cam_to_world,i = R0_i Exp(d_i)), the ground points (control points weighted by their sigmas, all others free
tie points; points with role `check` are never control), and the mounting x = [dt, l_b, theta_b].
Observations:
- image measurements (px, collinearity with the camera model, weighted by the pixel sigmas); selected
  intrinsics (`refine_intrinsics`) may be estimated too;
- control point coordinates (m);
- POS at every event, propagated over the delay as in the `proposed` method:
    C_i = r_imu,i + v_i dt + R_b,i Exp(omega_i dt) l_b,   R_cam_to_world,i = R_b,i Exp(omega_i dt) Exp(theta_b) R_hat,
  weighted by the POS covariance (position and attitude).
Solved with scipy `least_squares` (trust region, sparse finite-difference Jacobian grouped by its sparsity);
the covariance of the mounting comes from the full normal matrix, scaled by max(1, sigma0^2), plus
`pos_common_fraction` x the mean POS covariance taken as an error common to all epochs (bias-driven tilt,
GNSS biases of a smoothed MEMS POS do not average down over one flight): its effect on the mounting is the
sensitivity S = N^-1 J^T B of the estimate to a constant POS error (B: whitened POS residuals per unit
position error in L and attitude error about body axes), computed with the same Schur elimination.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix, lil_matrix

from dgcal.bundle.intersection import intersect
from dgcal.calib.mounting.common import BlockFrame, MountingResult, T, build_epochs, so3_exp, so3_log
from dgcal.calib.mounting.observability import observability_warnings
from dgcal.calib.mounting.joint import DEFAULT_POS_SIGMA, default_cov, calibrate_proposed
from dgcal.fields.crs import MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import EOP, Events, Measurements, Points, Trajectory
from dgcal.fields.frames import skew

DEFAULT_PIXEL_SIGMA = 0.5
DEFAULT_GCP_SIGMA = 0.02


def calibrate_iso(eop: EOP, grid: MapGrid, traj: Trajectory, events: Events, meas: Measurements, gcp: Points,
                  camera, *, fix_delay: bool = False, max_nfev: int = 30,
                  refine_intrinsics: tuple[str, ...] = (), pos_common_fraction: float = 0.0) -> MountingResult:
    """ISO mounting calibration; `eop` (e.g. a bundle or DG result) only initialises the image poses.
    `refine_intrinsics` names camera parameters (e.g. ("f", "cx", "cy")) estimated in the same adjustment.
    `pos_common_fraction` (0-1): share of the POS error variance common to all epochs of the flight (as in
    `calibrate_proposed`; 0 = independent per photo)."""
    if not 0.0 <= pos_common_fraction <= 1.0:
        raise InputError(f"pos_common_fraction must be within 0..1, got {pos_common_fraction}",
                         field="--pos-common-fraction")
    bad = [k for k in refine_intrinsics if k not in camera.PARAMS]
    if bad:
        raise InputError(f"camera model {camera.NAME} has no parameter {bad[0]!r} ({', '.join(camera.PARAMS)})",
                         field="--refine-intrinsics")
    cam = camera.copy()
    i_intr = [camera.PARAMS.index(k) for k in refine_intrinsics]
    n_intr = len(i_intr)
    frame = BlockFrame.at_map_points(grid, eop.xyz)
    ep = build_epochs(frame, eop, events, traj)
    init = calibrate_proposed(ep, fix_delay=fix_delay)
    img_names = [str(s) for s in ep.image]
    img_idx = {k: i for i, k in enumerate(img_names)}
    gid = {str(k): j for j, k in enumerate(gcp.ids)}
    keep = np.array([str(im) in img_idx for im in meas.image], bool)
    m = meas.subset(keep)
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
    X_ctrl = frame.map_to_world(gcp.xyz[ctrl_rows])
    s_ctrl = np.where(np.isfinite(gcp.sigma[ctrl_rows]), gcp.sigma[ctrl_rows], DEFAULT_GCP_SIGMA)
    M, K = len(img_names), len(pt_names)
    # initial points: control from the file, the others intersected from the initial poses
    res0 = intersect(camera, ep.C_world, ep.R_cam_to_world, obs_img, obs_pt, m.xy, sig_uv, K)
    X0 = np.where(res0.ok[:, None], res0.xyz, 0.0)
    X0[ctrl] = X_ctrl
    lonely = ~res0.ok & ~ctrl
    if lonely.any():
        raise InputError(f"{int(lonely.sum())} points are seen in fewer than 2 images (e.g. {np.array(pt_names)[lonely][0]!r})",
                         meas.path, field="id")
    R0 = ep.R_cam_to_world.copy()
    R_hat = init.R_cam_to_body.copy()
    pos = ep.pos
    C_pos = pos.cov if pos.cov is not None else default_cov(M, DEFAULT_POS_SIGMA[0], DEFAULT_POS_SIGMA[1:2] * 2
                                                             + DEFAULT_POS_SIGMA[2:])
    # POS residual weights, from the POS covariance through the model at the initial mounting
    G = np.zeros((M, 6, 6))
    R_b0 = pos.R_body_to_world @ so3_exp(pos.omega_b * init.delay_s)
    G[:, :3, :3] = -np.eye(3)
    G[:, :3, 3:] = R_b0 @ skew(init.lever_arm_m)
    G[:, 3:, 3:] = -R_hat.T
    W_pos = np.linalg.inv(np.linalg.cholesky(G @ C_pos @ T(G)))
    n_pose, n_pt = 6 * M, 3 * K
    i_mnt = n_pose + n_pt
    free_m = np.arange(1 if fix_delay else 0, 7)

    def unpack(x):
        C = x[:n_pose].reshape(M, 6)[:, :3]
        d = x[:n_pose].reshape(M, 6)[:, 3:]
        X = x[n_pose:i_mnt].reshape(K, 3)
        mt = np.zeros(7)
        mt[free_m] = x[i_mnt:i_mnt + len(free_m)]
        return C, d, X, mt

    def fun(x):
        C, d, X, mt = unpack(x)
        R = R0 @ so3_exp(d)
        Xc = np.einsum("nji,nj->ni", R[obs_img], X[obs_pt] - C[obs_img])
        Xc[:, 2] = np.maximum(Xc[:, 2], 1e-3)
        if n_intr:
            cam.params[i_intr] = x[i_mnt + len(free_m):]
        r_img = ((cam.project(Xc) - m.xy) / sig_uv).ravel()
        r_gcp = ((X[ctrl] - X_ctrl) / s_ctrl).ravel()
        dt, lever, theta = mt[0], mt[1:4], mt[4:7]
        R_b = pos.R_body_to_world @ so3_exp(pos.omega_b * dt)
        p = pos.r_imu_world + pos.v_world * dt + np.einsum("nij,j->ni", R_b, lever)
        Rc = R_b @ (so3_exp(theta) @ R_hat)
        e = np.column_stack([C - p, so3_log(T(Rc) @ R)])
        r_pos = np.einsum("nij,nj->ni", W_pos, e).ravel()
        return np.concatenate([r_img, r_gcp, r_pos])

    n_obs = len(obs_img)
    n_res = 2 * n_obs + 3 * int(ctrl.sum()) + 6 * M
    n_glob = len(free_m) + n_intr
    S = lil_matrix((n_res, i_mnt + n_glob), dtype=np.int8)
    if n_intr:
        S[:2 * n_obs, i_mnt + len(free_m):] = 1
    for k in range(n_obs):
        for r in (2 * k, 2 * k + 1):
            S[r, 6 * obs_img[k]:6 * obs_img[k] + 6] = 1
            S[r, n_pose + 3 * obs_pt[k]:n_pose + 3 * obs_pt[k] + 3] = 1
    row = 2 * n_obs
    for j in np.nonzero(ctrl)[0]:
        for a in range(3):
            S[row, n_pose + 3 * j + a] = 1
            row += 1
    for i in range(M):
        S[row:row + 6, 6 * i:6 * i + 6] = 1
        S[row:row + 6, i_mnt:i_mnt + len(free_m)] = 1
        row += 6
    x0 = np.concatenate([np.column_stack([ep.C_world, np.zeros((M, 3))]).ravel(), X0.ravel(),
                         np.r_[init.delay_s, init.lever_arm_m, 0, 0, 0][free_m], camera.params[i_intr]])
    sol = least_squares(fun, x0, jac_sparsity=S.tocsr(), method="trf", x_scale="jac", max_nfev=max_nfev,
                        xtol=1e-10, ftol=1e-10)
    dof = n_res - len(sol.x)
    sigma0_sq = float(2 * sol.cost / max(dof, 1))
    C, d, X, mt = unpack(sol.x)
    R_final = so3_exp(mt[4:7]) @ R_hat
    # d(whitened POS residual)/d(POS error common to all epochs), at the solution: the POS observation enters
    # the residual as in `calibrate_proposed` (position in L, attitude about body axes)
    R_bf = pos.R_body_to_world @ so3_exp(pos.omega_b * mt[0])
    Gf = np.zeros((M, 6, 6))
    Gf[:, :3, :3] = -np.eye(3)
    Gf[:, :3, 3:] = R_bf @ skew(mt[1:4])
    Gf[:, 3:, 3:] = -R_final.T
    B = np.zeros((n_res, 6))
    B[n_res - 6 * M:] = np.einsum("nij,njk->nik", W_pos, Gf).reshape(-1, 6)
    cof_glob, sens_glob = _global_covariance(csr_matrix(sol.jac), n_pose, K, len(free_m) + n_intr, rhs=B)
    cov_glob_random = cof_glob * max(1.0, sigma0_sq)
    cov_glob_common = pos_common_fraction * sens_glob @ C_pos.mean(axis=0) @ sens_glob.T
    cov_glob = cov_glob_random + cov_glob_common
    cov = np.zeros((7, 7))
    cov_random = np.zeros((7, 7))
    cov_common = np.zeros((7, 7))
    nf = len(free_m)
    cov[np.ix_(free_m, free_m)] = cov_glob[:nf, :nf]
    cov_random[np.ix_(free_m, free_m)] = cov_glob_random[:nf, :nf]
    cov_common[np.ix_(free_m, free_m)] = cov_glob_common[:nf, :nf]
    rpx = fun(sol.x)[:2 * n_obs].reshape(-1, 2) * sig_uv
    # POS residuals at the solution (as `proposed`); the image list also tells `covariance_for_flight` which
    # photos are this flight's, whose POS errors already carry the common part
    p_f = pos.r_imu_world + pos.v_world * mt[0] + np.einsum("nij,j->ni", R_bf, mt[1:4])
    e_f = np.column_stack([C - p_f, so3_log(T(R_bf @ R_final) @ (R0 @ so3_exp(d)))])
    per_epoch = {"image": img_names, "residual_position_m": e_f[:, :3].tolist(),
                 "residual_rotation_deg": np.degrees(e_f[:, 3:]).tolist()}
    res = MountingResult("iso", mt[1:4].copy(), R_final, 0.0 if fix_delay else float(mt[0]), cov, M, [],
                         list(ep.warnings) + observability_warnings(ep), per_epoch)
    corr = res.correlation()
    for i in range(7):
        for j in range(i + 1, 7):
            if np.isfinite(corr[i, j]) and abs(corr[i, j]) > 0.9:
                res.warnings.append(f"high correlation {corr[i, j]:+.3f} between {res.PARAM_NAMES[i]} and "
                                    f"{res.PARAM_NAMES[j]}")
    res.extra.update({"sigma0": float(np.sqrt(sigma0_sq)), "redundancy": int(dof),
                      "covariance_scaled_by": float(max(1.0, sigma0_sq)), "n_image_observations": int(n_obs),
                      "n_control_points": int(ctrl.sum()), "n_tie_points": int(K - ctrl.sum()),
                      "image_rms_px": float(np.sqrt(np.mean(rpx**2))), "iterations": int(sol.nfev),
                      "sigma_random": np.sqrt(np.diag(cov_random)).tolist(),
                      "sigma_pos_common_mode": np.sqrt(np.diag(cov_common)).tolist(),
                      "pos_common_fraction": float(pos_common_fraction),
                      "covariance_random": [[float(v) for v in row] for row in cov_random],
                      "covariance_model": "normal matrix of the bundle (scaled by max(1, sigma0^2)) plus "
                                          "pos_common_fraction x the mean POS covariance as an error common to all epochs",
                      "boresight_parameterisation": "unit quaternion with minimal 3-parameter multiplicative update",
                      "initialisation": {"method": "proposed", "delay_s": init.delay_s,
                                         "lever_arm_m": init.lever_arm_m.tolist()},
                      "skipped_images": ep.skipped})
    if n_intr:
        res.extra["intrinsics"] = {k: float(v) for k, v in zip(refine_intrinsics, sol.x[i_mnt + nf:])}
        res.extra["intrinsics_sigma"] = {k: float(v) for k, v in
                                         zip(refine_intrinsics, np.sqrt(np.diag(cov_glob)[nf:]))}
    xyz_map, opk = frame.world_to_eop(C, R0 @ so3_exp(d))
    res.extra["adjusted_eop"] = {"image": img_names, "xyz": xyz_map.tolist(), "opk_deg": opk.tolist()}
    return res


def _global_covariance(J, n_pose: int, n_points: int, n_glob: int, rhs: np.ndarray | None = None):
    """Covariance (cofactor) of the global parameters (mounting, intrinsics: the last `n_glob` columns) from a
    sparse Jacobian [poses | points | globals]: points eliminated by their 3x3 blocks, then poses (Schur).
    With `rhs` (residuals per unit of some disturbance, (n_res, k)) also returns the globals' sensitivity
    (N^-1 J^T rhs)[globals], (n_glob, k), through the same elimination."""
    i_pt = n_pose
    i_gl = n_pose + 3 * n_points
    Jc = J[:, np.r_[0:i_pt, i_gl:i_gl + n_glob]]   # poses and globals
    Jp = J[:, i_pt:i_gl]                             # points
    # block-diagonal point normals, inverted block by block
    Np = (Jp.T @ Jp).tocsr()
    blocks = np.zeros((n_points, 3, 3))
    for a in range(3):
        for b in range(3):
            blocks[:, a, b] = np.asarray(Np[np.arange(n_points) * 3 + a, np.arange(n_points) * 3 + b]).ravel()
    inv = np.linalg.inv(blocks)
    from scipy.sparse import block_diag
    Ainv = block_diag(list(inv), format="csr") if n_points else None
    Ncc = (Jc.T @ Jc).toarray()
    bc = None if rhs is None else np.asarray(Jc.T @ rhs)
    if n_points:
        W = (Jp.T @ Jc).tocsr()
        Ncc = Ncc - (W.T @ (Ainv @ W)).toarray()
        if rhs is not None:
            bc = bc - W.T @ (Ainv @ np.asarray(Jp.T @ rhs))
    # poses then globals: eliminate the poses
    P = Ncc[:n_pose, :n_pose]
    G = Ncc[:n_pose, n_pose:]
    PinvG = np.linalg.solve(P, G)
    S = Ncc[n_pose:, n_pose:] - G.T @ PinvG
    cof = np.linalg.inv(S)
    if rhs is None:
        return cof
    return cof, cof @ (bc[n_pose:] - PinvG.T @ bc[:n_pose])


def calibrate_iso_files(eop: EOP, grid: MapGrid, traj: Trajectory, events: Events, meas_path: Path,
                        gcp_path: Path, camera_path: Path, **kw) -> MountingResult:
    """`calibrate_iso` with measurements (CSV or ODM gcp_list.txt), ground points and camera read from files."""
    from dgcal.calib.camera.files import load_camera
    from dgcal.fields.io.formats import read_measurements, read_points
    try:
        from dgcal.fields.io.gcp_files import is_odm_gcp_list, read_odm_gcp_list
        meas = read_odm_gcp_list(meas_path)[2] if is_odm_gcp_list(meas_path) else read_measurements(meas_path)
    except ImportError:
        meas = read_measurements(meas_path)
    return calibrate_iso(eop, grid, traj, events, meas, read_points(gcp_path), load_camera(camera_path), **kw)
