"""Aerial triangulation pipeline: camera + ground points + image measurements -> EOPs with covariance.

`triangulate(...)` is what a Python user calls (and `dgcal triangulate` wraps). It
1. sorts measured ids into control (role control), check (role check) and tie points (not in the ground
   point file), and warns about anything it cannot use (ids without measurements, points seen once,
   images without measurements or that cannot be oriented) instead of dropping it silently;
2. moves everything into a local ENU frame at the control centroid (`dgcal.bundle.georef.Georef`);
3. orients images by PnP from control and growing through tie points, or from approximate EOPs;
4. runs the bundle adjustment (`dgcal.bundle.adjustment`), tests GCP measurements for blunders (standardised
   residuals), removes the worst one at a time while any exceeds the critical value, and re-adjusts;
5. intersects check points from the adjusted images and reports their errors in E, N, Up;
6. converts EOPs and their 6x6 covariances to the map CRS (grid-level PATB angles).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from dgcal.bundle.adjustment import BundleInput, BundleOptions, BundleResult, adjust
from dgcal.bundle.blunders import CRITICAL_W, Suspect, find_suspects, standardized
from dgcal.bundle.georef import Georef
from dgcal.bundle.resection import grow_orientation, relative_bootstrap
from dgcal.calib.camera.models import CameraModel
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import EOP, Measurements, Points

DEFAULT_SIGMA_PX = 0.5          # image measurement sigma when the file gives none
DEFAULT_GCP_SIGMA_M = (0.02, 0.02, 0.03)


@dataclass
class TriangulationOptions:
    """Choices of the triangulation: weights, intrinsics, robust loss, blunder handling, geoid."""

    sigma_px: float = DEFAULT_SIGMA_PX
    tie_sigma_px: float | None = None          # default: sigma_px
    gcp_sigma_m: tuple[float, float, float] = DEFAULT_GCP_SIGMA_M   # used where gcp file gives none
    fixed_gcps: bool = False
    refine: tuple[str, ...] = ()               # camera parameters to refine in flight
    loss: str = "huber"
    loss_scale: float = 3.0
    reject_blunders: bool = True
    critical_w: float = CRITICAL_W
    max_rejections: int = 10
    tie_outlier_sigma: float = 5.0             # tie observations beyond this many sigma0 are dropped
    geoid: float | str | None = None           # constant undulation (m) or PROJ vertical grid
    aposteriori: bool = True
    verbose: bool = False


@dataclass
class TriangulationResult:
    """Everything a report needs: EOPs in the map CRS, the adjustment, per-point and per-image figures."""

    eop: EOP                                   # map CRS, sigma (n,6) and cov (n,6,6) (m, deg)
    georef: Georef
    bundle: BundleResult
    camera: CameraModel
    images: list[str]
    point_ids: list[str]
    point_kind: np.ndarray                     # 'control' | 'tie' per adjusted point
    gcp: list[dict]
    check: list[dict]
    image_stats: list[dict]
    suspects: list[Suspect]
    warnings: list[str]
    unknown_ids: list[str]                     # measured ids absent from the ground point file
    summary: dict = field(default_factory=dict)
    R_world_to_cam: np.ndarray | None = None
    C_world: np.ndarray | None = None


def _warn(msgs: list[str], text: str, verbose: bool) -> None:
    msgs.append(text)
    if verbose:
        print("warning:", text)


def triangulate(camera: CameraModel, points: Points, meas: Measurements, crs: str | None,
                options: TriangulationOptions | None = None, image_size: tuple[int, int] | None = None,
                approx: EOP | None = None, centre_priors: EOP | None = None,
                all_images: list[str] | None = None) -> TriangulationResult:
    """Aerial triangulation: EOPs (map CRS, PATB deg) with covariance from ground points and measurements (px).

    `meas` holds GCP, check and tie measurements (ids not in `points` are tie points). `approx`
    (map CRS) gives approximate EOPs where known, `centre_priors` GNSS centres with sigmas (sX..sZ).
    `all_images` lists images that should be oriented (those without measurements are reported).
    """
    opt = options or TriangulationOptions()
    clock = {"start": time.perf_counter()}
    msgs: list[str] = []
    if image_size is not None and tuple(int(v) for v in image_size) != tuple(camera.image_size):
        raise InputError(f"image size {tuple(image_size)} differs from the camera's {tuple(camera.image_size)}",
                         field="--image-size")
    w_img, h_img = camera.image_size
    out = (meas.xy[:, 0] < -0.5) | (meas.xy[:, 1] < -0.5) | (meas.xy[:, 0] > w_img - 0.5) | (meas.xy[:, 1] > h_img - 0.5)
    if out.any():
        i = int(np.argmax(out))
        raise InputError(f"measurement ({meas.xy[i, 0]:.1f}, {meas.xy[i, 1]:.1f}) lies outside the "
                         f"{w_img}x{h_img} image", meas.path, None if meas.lines is None else int(meas.lines[i]), "x")
    pidx = points.index()
    ids = meas.id.astype(str)
    in_points = np.array([i in pidx for i in ids])
    role_of = {str(k): str(r) for k, r in zip(points.ids, points.role)}
    is_control = np.array([role_of.get(i) == "control" for i in ids])
    is_check = np.array([role_of.get(i) == "check" for i in ids])
    unknown_ids = sorted(set(ids[~in_points]))
    control_ids = [str(k) for k, r in zip(points.ids, points.role) if r == "control"]
    if not control_ids:
        raise InputError("no control points (role 'control') in the ground point file", points.path, field="role")
    measured = set(ids)
    for pid in points.ids:
        if str(pid) not in measured:
            _warn(msgs, f"ground point {pid} ({role_of[str(pid)]}) has no image measurements: not used", opt.verbose)
    counts = {}
    for i in ids:
        counts[i] = counts.get(i, 0) + 1
    for pid in control_ids:
        if counts.get(pid, 0) == 1:
            _warn(msgs, f"control point {pid} is measured in one image only: it constrains that image weakly "
                        "and its measurement cannot be checked for blunders", opt.verbose)

    # --- georeferencing: local ENU at the centroid of the measured control ------------------------
    ctrl_mask = np.array([str(c) in measured and role_of[str(c)] == "control" for c in points.ids], bool)
    if not ctrl_mask.any():
        raise InputError("none of the control points is measured in any image", meas.path, field="id")
    centre = points.xyz[ctrl_mask].mean(0)
    geo = Georef(crs, centre, opt.geoid, points.path)
    P_world = geo.to_world(points.xyz)
    if not np.isfinite(P_world).all():
        bad = int(np.argmax(~np.isfinite(P_world).all(1)))
        raise InputError(f"point {points.ids[bad]} is not a valid coordinate in CRS {crs}", points.path,
                         None if points.lines is None else int(points.lines[bad]), "x")
    spread = np.ptp(P_world[ctrl_mask], axis=0)
    if ctrl_mask.sum() > 2 and max(spread[:2]) > 5e4:
        raise InputError(f"control points span {max(spread[:2]) / 1e3:.0f} km in CRS {crs}: wrong CRS or "
                         "coordinate order?", points.path, field="--crs")

    # --- the adjustment's points: control + tie (check points are not adjusted) -------------------
    use = ~is_check
    used_ids = ids[use]
    uniq, cnt = np.unique(used_ids, return_counts=True)
    once = set(uniq[cnt < 2]) - set(control_ids)
    for pid in sorted(once):
        _warn(msgs, f"tie point {pid} is measured in one image only: not used", opt.verbose) \
            if pid in unknown_ids and len(once) <= 20 else None
    if len(once) > 20:
        _warn(msgs, f"{len(once)} tie points are measured in one image only: not used", opt.verbose)
    use &= ~np.array([i in once for i in ids], bool)
    images = list(dict.fromkeys((all_images or []) + meas.images()))
    img_index = {n: i for i, n in enumerate(images)}
    point_ids = list(dict.fromkeys(ids[use].tolist()))
    pt_index = {p: i for i, p in enumerate(point_ids)}
    kind = np.array(["control" if p in role_of else "tie" for p in point_ids], dtype=object)
    sel = np.nonzero(use)[0]
    oi = np.array([img_index[n] for n in meas.image[sel].astype(str)], int)
    op = np.array([pt_index[p] for p in ids[sel]], int)
    uv = meas.xy[sel]
    sig_default = np.where(kind[op] == "tie", opt.tie_sigma_px or opt.sigma_px, opt.sigma_px)
    sig = np.where(np.isfinite(meas.sigma[sel]), meas.sigma[sel], sig_default[:, None])
    m = len(point_ids)
    Xprior = np.full((m, 3), np.nan)
    Sprior = np.full((m, 3), np.nan)
    for j, p in enumerate(point_ids):
        if kind[j] == "control":
            r = pidx[p]
            Xprior[j] = P_world[r]
            s = points.sigma[r]
            Sprior[j] = 0.0 if opt.fixed_gcps else np.where(np.isfinite(s), s, opt.gcp_sigma_m)
    # --- initial orientation --------------------------------------------------------------------
    n = len(images)
    R0 = C0 = None
    if approx is not None:
        R0 = np.full((n, 3, 3), np.nan)
        C0 = np.full((n, 3), np.nan)
        a_idx = {str(k): i for i, k in enumerate(approx.image)}
        for name, i in img_index.items():
            if name in a_idx:
                Ra, Ca = geo.eop_to_world(approx.xyz[a_idx[name]][None], approx.opk[a_idx[name]][None])
                R0[i], C0[i] = Ra[0], Ca[0]
    clock["prepared"] = time.perf_counter()
    R, C, oriented, X0, okpt = grow_orientation(camera, n, oi, op, uv, Xprior, R0, C0)
    if not oriented[np.unique(oi)].all():
        boot = relative_bootstrap(camera, n, oi, op, uv, Xprior)
        if boot is not None and boot[2].sum() > oriented.sum():
            R, C, oriented, X0, okpt = boot
            _warn(msgs, "too few control points per image for resection: started from a relative orientation "
                        "scaled onto the control points", opt.verbose)
    for i in np.nonzero(~oriented)[0]:
        nm = int(np.sum(oi == i))
        _warn(msgs, f"image {images[i]} could not be oriented ({nm} usable measurements): left out"
              if nm else f"image {images[i]} has no measurements: left out", opt.verbose)
    nbad = int((~okpt).sum())
    if nbad:
        _warn(msgs, f"{nbad} tie point(s) could not be triangulated (too few oriented rays or angle < 1 deg): left out",
              opt.verbose)
    keep_obs = oriented[oi] & okpt[op]
    # compact to oriented images and initialised points
    img_keep = np.nonzero(oriented)[0]
    pt_keep = np.nonzero(okpt)[0]
    if len(img_keep) == 0:
        raise InputError("no image could be oriented: each needs >= 4 control points or tie points "
                         "shared with oriented images (or approximate EOPs)", meas.path)
    im_map = -np.ones(n, int)
    im_map[img_keep] = np.arange(len(img_keep))
    pt_map = -np.ones(m, int)
    pt_map[pt_keep] = np.arange(len(pt_keep))
    oi2, op2 = im_map[oi[keep_obs]], pt_map[op[keep_obs]]
    uv2, sig2 = uv[keep_obs], sig[keep_obs]
    src_rows = sel[keep_obs]                              # rows of `meas` behind each observation
    images_k = [images[i] for i in img_keep]
    pids_k = [point_ids[j] for j in pt_keep]
    kind_k = kind[pt_keep]
    cprior = csig = None
    if centre_priors is not None:
        cprior = np.full((len(images_k), 3), np.nan)
        csig = np.full((len(images_k), 3), np.nan)
        c_idx = {str(k): i for i, k in enumerate(centre_priors.image)}
        for i, name in enumerate(images_k):
            if name in c_idx:
                r = c_idx[name]
                cprior[i] = geo.to_world(centre_priors.xyz[r][None])[0]
                csig[i] = centre_priors.sigma[r, :3] if centre_priors.sigma is not None else 0.05
    inp = BundleInput(camera, images_k, R[img_keep], C[img_keep], pids_k, X0[pt_keep], oi2, op2, uv2, sig2,
                      Xprior[pt_keep], Sprior[pt_keep], cprior, csig, tuple(opt.refine))
    bopt = BundleOptions(loss=opt.loss, loss_scale=opt.loss_scale, aposteriori=opt.aposteriori, verbose=opt.verbose)
    clock["initialised"] = time.perf_counter()
    res = adjust(inp, bopt)
    clock["adjusted"] = time.perf_counter()
    # --- tie-point outliers (SIFT mismatches) then GCP blunders, one at a time ------------------
    active = np.ones(len(oi2), bool)
    if (kind_k == "tie").any() and np.isfinite(res.sigma0):
        e = np.linalg.norm(res.residuals_px / sig2, axis=1)
        bad = (kind_k[op2] == "tie") & (e > opt.tie_outlier_sigma * max(res.sigma0, 1.0))
        if bad.any():
            _warn(msgs, f"{int(bad.sum())} tie observation(s) beyond {opt.tie_outlier_sigma:g} sigma dropped", opt.verbose)
            active &= ~bad
            res = _readjust(inp, active, bopt, res)
    suspects: list[Suspect] = []
    for _ in range(opt.max_rejections if opt.reject_blunders else 1):
        act_idx = np.nonzero(active)[0]                  # full index of each observation of `res`
        ctrl_obs = np.nonzero(kind_k[res.obs_point] == "control")[0]
        found = find_suspects(res, ctrl_obs, images_k, pids_k, opt.critical_w)
        if not found:
            break
        if not opt.reject_blunders:
            suspects.extend(found)
            break
        worst = found[0]
        k_sub = next(k for k in ctrl_obs if images_k[res.obs_image[k]] == worst.image
                     and pids_k[res.obs_point[k]] == worst.point)
        worst.removed = True
        suspects.append(worst)
        active[act_idx[k_sub]] = False
        _warn(msgs, f"measurement of {worst.point} in {worst.image} rejected as a blunder "
                    f"(standardised residual {worst.w:.1f})", opt.verbose)
        res = _readjust(inp, active, bopt, res)
    clock["cleaned"] = time.perf_counter()
    # --- outputs ----------------------------------------------------------------------------
    geo_xyz, geo_opk = geo.eop_to_map(res.R_world_to_cam, res.C_world)
    cov_map = geo.eop_covariance_to_map(res.R_world_to_cam, res.C_world, res.cov_pose)
    sig_map = np.sqrt(np.clip(np.diagonal(cov_map, axis1=1, axis2=2), 0, None))
    eop = EOP(np.array(images_k, dtype=object), geo_xyz, geo_opk, sig_map, cov_map)
    a_oi, a_op = res.obs_image, res.obs_point   # observations of the final adjustment
    image_stats = []
    for i, name in enumerate(images_k):
        kk = np.nonzero(a_oi == i)[0]
        r = res.residuals_px[kk]
        image_stats.append({"image": name, "n_obs": int(len(kk)),
                            "n_control": int(np.sum(kind_k[a_op[kk]] == "control")),
                            "rms_px": float(np.sqrt(np.mean(np.sum(r ** 2, 1)))) if len(kk) else float("nan"),
                            "sigma": sig_map[i].tolist()})
    w_std, r_num = standardized(res, np.nonzero(kind_k[a_op] == "control")[0])
    ctrl_rows = np.nonzero(kind_k[a_op] == "control")[0]
    gcp_rep = []
    X_map = geo.to_map(res.X_world) if len(res.X_world) else np.zeros((0, 3))
    for j, pid in enumerate(pids_k):
        if kind_k[j] != "control":
            continue
        r = pidx[pid]
        kk = np.nonzero(a_op == j)[0]
        pos = np.searchsorted(ctrl_rows, kk)
        dloc = res.X_world[j] - P_world[r]
        R_lg = geo.R_world_to_grid_at(res.X_world[j][None])[0]
        gcp_rep.append({"id": pid, "n_images": int(len(kk)), "xyz": points.xyz[r].tolist(),
                        "adjusted": X_map[j].tolist(), "dENU_m": (R_lg @ dloc).tolist(),
                        "rms_px": float(np.sqrt(np.mean(np.sum(res.residuals_px[kk] ** 2, 1)))),
                        "measurements": [{"image": images_k[a_oi[k]], "residual_px": res.residuals_px[k].tolist(),
                                          "w": float(np.max(np.abs(w_std[p]))), "redundancy": float(r_num[p].min())}
                                         for k, p in zip(kk, pos)]})
    removed = {(s.image, s.point) for s in suspects if s.removed}
    for g in gcp_rep:
        for mm in g["measurements"]:
            mm["rejected"] = (mm["image"], g["id"]) in removed
    unknown_rep = []
    k_index = {p: j for j, p in enumerate(pids_k)}
    n_rays = np.bincount(a_op, minlength=len(pids_k))
    for pid in unknown_ids:
        if pid in k_index:
            j = k_index[pid]
            unknown_rep.append({"id": pid, "n_images": int(n_rays[j]), "xyz": X_map[j].tolist()})
        else:
            unknown_rep.append({"id": pid, "n_images": int(counts.get(pid, 0)), "xyz": None})
    check_rep = _check_points(camera, res, geo, points, meas, is_check, images_k, msgs, opt)
    summary = _summary(res, eop, images, images_k, gcp_rep, check_rep, unknown_rep, suspects, msgs, geo, kind_k)
    clock["done"] = time.perf_counter()
    names = list(clock)
    summary["timings_s"] = {f"{b}": round(clock[b] - clock[a], 3) for a, b in zip(names, names[1:])}
    if opt.verbose:
        print(f"sigma0 {res.sigma0:.3f}, {len(images_k)} images, {len(pids_k)} points, redundancy {res.redundancy}")
    return TriangulationResult(eop, geo, res, res.camera, images_k, pids_k, kind_k, gcp_rep, check_rep, image_stats,
                               suspects, msgs, unknown_ids, summary, res.R_world_to_cam, res.C_world)


def _readjust(inp: BundleInput, active: np.ndarray, bopt: BundleOptions, prev: BundleResult) -> BundleResult:
    """Re-run the adjustment on the active observations only, starting from the previous solution.

    Tie points left with fewer than two active rays are deactivated too (in place in `active`)."""
    free = ~np.isfinite(inp.point_prior).all(1) if inp.point_prior is not None else np.ones(len(inp.point_ids), bool)
    while True:
        cnt = np.bincount(inp.obs_point[active], minlength=len(inp.point_ids))
        lone = active & free[inp.obs_point] & (cnt[inp.obs_point] < 2)
        if not lone.any():
            break
        active &= ~lone
    sub = BundleInput(inp.camera, inp.images, prev.R_world_to_cam, prev.C_world, inp.point_ids, prev.X_world,
                      inp.obs_image[active], inp.obs_point[active], inp.obs_uv[active], inp.obs_sigma[active],
                      inp.point_prior, inp.point_prior_sigma, inp.center_prior, inp.center_prior_sigma, inp.refine,
                      inp.intrinsic_prior_sigma)
    return adjust(sub, bopt)


def _check_points(camera, res: BundleResult, geo: Georef, points: Points, meas: Measurements,
                  is_check: np.ndarray, images_k: list[str], msgs: list[str], opt) -> list[dict]:
    """Intersect check points from the adjusted images (dgcal.bundle.intersection, pixel and pose covariance);
    errors (intersected - given) and sigmas in grid E, N, Up."""
    from dgcal.bundle.intersection import intersect, propagate_pose_covariance
    im_idx = {n: i for i, n in enumerate(images_k)}
    pidx = points.index()
    rows = np.array([r for r in np.nonzero(is_check)[0] if str(meas.image[r]) in im_idx], int)
    ids = list(dict.fromkeys(meas.id[is_check].astype(str)))
    out = []
    if len(rows):
        pid_of = {p: j for j, p in enumerate(ids)}
        oi = np.array([im_idx[str(meas.image[r])] for r in rows])
        op = np.array([pid_of[str(meas.id[r])] for r in rows])
        sig = np.where(np.isfinite(meas.sigma[rows]), meas.sigma[rows], opt.sigma_px)
        R_c2w = np.swapaxes(res.R_world_to_cam, -1, -2)
        ir = intersect(camera, res.C_world, R_c2w, oi, op, meas.xy[rows], sig, n_points=len(ids))
        cov = ir.cov + propagate_pose_covariance(ir, res.cov_pose)
    for j, pid in enumerate(ids):
        n_rays = int(ir.n_rays[j]) if len(rows) else 0
        if not len(rows) or not ir.ok[j]:
            why = ("needs 2" if n_rays < 2 else "the rays do not intersect in front of the cameras")
            _warn(msgs, f"check point {pid} is measured in {n_rays} oriented image(s): {why}, not evaluated",
                  opt.verbose)
            out.append({"id": pid, "n_images": n_rays, "evaluated": False})
            continue
        X = ir.xyz[j]
        given = geo.to_world(points.xyz[pidx[pid]][None])[0]
        R_lg = geo.R_world_to_grid_at(X[None])[0]
        d = R_lg @ (X - given)
        s = np.sqrt(np.clip(np.diag(R_lg @ cov[j] @ R_lg.T), 0, None))
        out.append({"id": pid, "n_images": n_rays, "evaluated": True, "xyz": points.xyz[pidx[pid]].tolist(),
                    "intersected": geo.to_map(X[None])[0].tolist(), "dENU_m": d.tolist(), "sigma_ENU_m": s.tolist(),
                    "rms_px": float(ir.rms_px[j])})
    return out


def _summary(res, eop, images, images_k, gcp_rep, check_rep, unknown_rep, suspects, msgs, geo, kind_k) -> dict:
    ev = [c for c in check_rep if c.get("evaluated")]
    d = np.array([c["dENU_m"] for c in ev]) if ev else np.zeros((0, 3))
    g = np.array([c["dENU_m"] for c in gcp_rep]) if gcp_rep else np.zeros((0, 3))
    fin = np.isfinite(res.residuals_px).all(1)
    return {
        "crs": geo.crs_text or "local", "sigma0": res.sigma0, "redundancy": res.redundancy,
        "converged": bool(res.converged), "iterations": int(res.iterations),
        "n_images": len(images), "n_oriented": len(images_k), "n_control": len(gcp_rep),
        "n_tie_points": int(np.sum(kind_k == "tie")), "n_observations": int(fin.sum()),
        "rms_px": float(np.sqrt(np.mean(np.sum(res.residuals_px[fin] ** 2, 1)))),
        "control_rmse_m": {"E": _rms(g[:, 0]), "N": _rms(g[:, 1]), "U": _rms(g[:, 2])},
        "check_rmse_m": {"E": _rms(d[:, 0]), "N": _rms(d[:, 1]), "U": _rms(d[:, 2]),
                          "horizontal": _rms(np.hypot(d[:, 0], d[:, 1])) if len(d) else None, "n": len(d)},
        "median_sigma": {k: float(np.median(eop.sigma[:, j])) for j, k in
                         enumerate(("X_m", "Y_m", "Z_m", "omega_deg", "phi_deg", "kappa_deg"))},
        "camera": {"model": res.camera.NAME, "refined": list(res.refine), "params": res.camera.as_dict()},
        "n_unknown_ids": len(unknown_rep),
        "unknown_points": [u for u in unknown_rep if not str(u["id"]).startswith("tie_")][:200],
        "suspects": [s.as_dict() for s in suspects], "warnings": list(msgs),
    }


def _rms(v) -> float | None:
    v = np.asarray(v, float)
    return float(np.sqrt(np.mean(v ** 2))) if v.size else None
