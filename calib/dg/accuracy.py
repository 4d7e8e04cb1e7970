"""DG accuracy on check points: seed 003 Table 2 statistics, improvement rates (Tables 4-5), ASPRS 2023
statistics and a predicted error budget from the covariances (Table 6), next to the achieved errors.

Errors are map-grid differences (E, N, Up) of DG-intersected check points minus their reference coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from dgcal.bundle.intersection import intersect, propagate_pose_covariance
from dgcal.calib.camera.files import load_camera
from dgcal.calib.dg.eop import dg_poses
from dgcal.calib.mounting.common import MountingResult, read_mounting_json
from dgcal.fields.crs import MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.frames import skew
from dgcal.fields.io.formats import Events, Measurements, Points, Trajectory, read_points
from dgcal.fields.processes import fork_map
from dgcal.pos.events import read_any_events
from dgcal.pos.ins.sbet import read_any_trajectory
from dgcal.fields.io.gcp_files import read_any_measurements
from dgcal.fields.pose import transpose as T
from dgcal.fields.world import World

ASPRS_MIN_CHECKPOINTS = 30


def error_stats(err_enu: np.ndarray) -> dict:
    """Seed Table 2: AVG, STD (n-1), RMS of E, N, U and their 2D/3D combinations (m)."""
    e = np.atleast_2d(np.asarray(err_enu, float))
    avg = e.mean(axis=0)
    std = e.std(axis=0, ddof=1) if len(e) > 1 else np.zeros(3)
    rms = np.sqrt(np.mean(e**2, axis=0))
    out = {"n": int(len(e))}
    for name, v in (("avg", avg), ("std", std), ("rms", rms)):
        out[name] = {"E": float(v[0]), "N": float(v[1]), "U": float(v[2]),
                     "2D": float(np.hypot(v[0], v[1])), "3D": float(np.linalg.norm(v))}
    return out


def improvement_rate(old: float, new: float) -> float:
    """Seed Tables 4-5: improvement of `new` over `old` in percent, (old - new) / new * 100."""
    return float((old - new) / new * 100.0)


def error_reduction(old: float, new: float) -> float:
    """The share of `old`'s RMS error that `new` removes, in percent: (old - new) / old * 100 (100: none left)."""
    return float((old - new) / old * 100.0) if old else float("nan")


def improvement_table(stats: dict[str, dict], reference: str) -> dict:
    """2D and 3D RMS improvement (%) of every method over `reference`: "2D"/"3D" as the seed's Tables 4-5
    ((old - new) / new, above 100 % once the error halves), "2D_reduction"/"3D_reduction" as (old - new) / old."""
    ref = stats[reference]["rms"]
    return {k: {"2D": improvement_rate(ref["2D"], s["rms"]["2D"]), "3D": improvement_rate(ref["3D"], s["rms"]["3D"]),
                "2D_reduction": error_reduction(ref["2D"], s["rms"]["2D"]),
                "3D_reduction": error_reduction(ref["3D"], s["rms"]["3D"])}
            for k, s in stats.items() if k != reference}


def asprs_2023(err_enu: np.ndarray, checkpoint_sigma: np.ndarray | None = None) -> dict:
    """ASPRS Positional Accuracy Standards, Ed. 2 (2023): RMSE_x, RMSE_y, RMSE_H, RMSE_V from check points, and
    the product accuracy including the check points' own survey accuracy (RMSE_H = sqrt(fit^2 + survey^2))."""
    e = np.atleast_2d(np.asarray(err_enu, float))
    rx, ry, rv = np.sqrt(np.mean(e**2, axis=0))
    out = {"n_checkpoints": int(len(e)), "RMSE_x": float(rx), "RMSE_y": float(ry),
           "RMSE_H": float(np.hypot(rx, ry)), "RMSE_V": float(rv), "warnings": []}
    if checkpoint_sigma is not None and np.isfinite(checkpoint_sigma).all():
        s = np.sqrt(np.mean(np.asarray(checkpoint_sigma, float) ** 2, axis=0))
        out["checkpoint_RMSE_H"] = float(np.hypot(s[0], s[1]))
        out["checkpoint_RMSE_V"] = float(s[2])
        out["product_RMSE_H"] = float(np.hypot(out["RMSE_H"], out["checkpoint_RMSE_H"]))
        out["product_RMSE_V"] = float(np.hypot(out["RMSE_V"], out["checkpoint_RMSE_V"]))
    if len(e) < ASPRS_MIN_CHECKPOINTS:
        out["warnings"].append(f"ASPRS 2023 asks for at least {ASPRS_MIN_CHECKPOINTS} check points; {len(e)} used")
    return out


@dataclass
class CheckResult:
    """DG check-point results: ids, DG coordinates and errors (map E, N, U), statistics and predicted budget."""

    ids: np.ndarray
    xyz_dg: np.ndarray
    xyz_ref: np.ndarray
    err_enu: np.ndarray
    n_rays: np.ndarray
    sigma_pred: np.ndarray  # (K,3) predicted sigma E, N, U of each check point (all sources)
    stats: dict
    asprs: dict
    budget: dict
    warnings: list[str] = field(default_factory=list)
    rejected: list[dict] = field(default_factory=list)   # check-point measurements left out as blunders

    def to_json(self) -> dict:
        return {"stats": self.stats, "asprs_2023": self.asprs, "budget": self.budget, "warnings": self.warnings,
                "rejected_measurements": self.rejected,
                "points": [{"id": str(i), "dg": x.tolist(), "ref": r.tolist(), "err_enu": e.tolist(),
                            "n_rays": int(n), "sigma_pred_enu": s.tolist()}
                           for i, x, r, e, n, s in zip(self.ids, self.xyz_dg, self.xyz_ref, self.err_enu,
                                                       self.n_rays, self.sigma_pred)]}


def straight_segment_time(traj: Trajectory, turn_rate_deg_s: float = 3.0, min_s: float = 5.0) -> float:
    """Median duration (s) of the straight stretches of a trajectory, between turns faster than
    `turn_rate_deg_s`; the whole span when it never turns.

    A GNSS/INS attitude error is held by the sensor biases between manoeuvres and re-estimated in each turn,
    so this is the correlation time of the POS errors along a photogrammetric flight."""
    t = np.asarray(traj.t, float)
    if len(t) < 3:
        return float(t[-1] - t[0]) if len(t) else 0.0
    psi = np.unwrap(np.radians(traj.rph[:, 2]))
    rate = np.degrees(np.abs(np.gradient(psi, t)))
    straight = rate < turn_rate_deg_s
    edges = np.flatnonzero(np.diff(np.r_[0, straight.astype(int), 0]))
    runs = [t[b - 1] - t[a] for a, b in zip(edges[::2], edges[1::2])]
    runs = [r for r in runs if r >= min_s]
    return float(np.median(runs)) if runs else float(t[-1] - t[0])


def _rms_sigma(cov_grid: np.ndarray) -> dict:
    """RMS over points of the predicted sigma E, N, U, 2D, 3D (m) from (K,3,3) covariances in grid axes."""
    v = np.mean(np.diagonal(cov_grid, axis1=1, axis2=2), axis=0)
    return {"E": float(np.sqrt(v[0])), "N": float(np.sqrt(v[1])), "U": float(np.sqrt(v[2])),
            "2D": float(np.sqrt(v[0] + v[1])), "3D": float(np.sqrt(v.sum()))}


def check_points_dg(grid: MapGrid, traj: Trajectory, events: Events, mount: MountingResult, camera,
                    meas: Measurements, points: Points, roles=("check",), min_rays: int = 2,
                    pos_correlation_time_s: float | str | None = "auto") -> CheckResult:
    """Intersect measured check points from DG EOPs and compare with their reference coordinates (map CRS).

    `pos_correlation_time_s` (s): in the predicted budget the POS errors of two images dt apart are correlated
    exp(-|dt|/tau); "auto" takes tau from the trajectory (`straight_segment_time`), None or 0 treats them as
    independent (optimistic: the rays of one strip share its error, they do not average it out)."""
    sel = np.isin(points.role, roles)
    pts = points.subset(sel)
    if len(pts.ids) == 0:
        raise InputError(f"no ground point with role {'/'.join(roles)}", points.path, field="role")
    pid = pts.index()
    ev_names = {str(k) for k in events.image}
    keep = np.array([str(i) in pid and str(im) in ev_names for i, im in zip(meas.id, meas.image)], bool)
    m = meas.subset(keep)
    if len(m) == 0:
        raise InputError("no measurement of a check point in an image with an event", meas.path, field="id")
    images = list(dict.fromkeys(str(k) for k in m.image))
    world = World.at_map_points(grid, pts.xyz)
    poses = dg_poses(world, traj, events, mount, images)
    img_idx = {k: j for j, k in enumerate(images)}
    ids_used = list(dict.fromkeys(str(k) for k in m.id))
    pt_idx = {k: j for j, k in enumerate(ids_used)}
    oi = np.array([img_idx[str(k)] for k in m.image])
    op = np.array([pt_idx[str(k)] for k in m.id])
    res, keep_obs = _screened_intersection(camera, poses, oi, op, m.xy, m.sigma, len(ids_used), min_rays)
    rejected = [{"image": str(m.image[k]), "id": str(m.id[k])} for k in np.flatnonzero(~keep_obs)]
    ok = res.ok
    warnings = []
    if rejected:
        warnings.append(f"{len(rejected)} check-point measurement(s) rejected as blunders (beyond "
                        f"{CHECK_OUTLIER_SIGMA:g} robust sigmas): " + ", ".join(f"{r['id']} in {r['image']}"
                                                                         for r in rejected[:8]))
    if (~ok).any():
        warnings.append(f"{int((~ok).sum())} check points seen in fewer than {min_rays} images: "
                        + ", ".join(np.array(ids_used)[~ok][:10]))
    if not ok.any():
        raise InputError(f"no check point is seen in {min_rays} or more images with events: nothing to check",
                         meas.path, field="id")
    ids = np.array(ids_used, dtype=object)[ok]
    X_world = res.xyz[ok]
    xyz_dg = world.to_map(X_world)
    xyz_ref = pts.xyz[[pid[k] for k in ids]]
    R_world_to_grid = world.R_world_to_grid_at(X_world)
    # errors as differences of map coordinates (grid E, N, height)
    err = xyz_dg - xyz_ref
    # predicted covariances per source, rotated into grid axes
    cov_mount = mount.covariance_for_flight(images)
    parts = {"image_measurements": res.cov[ok]}
    corr, tau = None, pos_correlation_time_s
    if tau == "auto":
        tau = straight_segment_time(traj)
    if poses.cam.cov is not None and tau:
        dt = np.abs(poses.t_exposure[:, None] - poses.t_exposure[None, :])
        corr = np.exp(-dt / float(tau))
    if poses.cam.cov is not None:
        Cp = poses.pos.cov
        Gp = _pos_to_pose(poses, mount)
        for name, sl in (("pos_position", slice(0, 3)), ("pos_attitude", slice(3, 6))):
            C = np.zeros_like(Cp)
            C[:, sl, sl] = Cp[:, sl, sl]
            parts[name] = propagate_pose_covariance(res, Gp @ C @ T(Gp), pose_corr=corr)[ok]
    for name, idx in (("delay", [0]), ("lever_arm", [1, 2, 3]), ("boresight", [4, 5, 6])):
        Cm = np.zeros((7, 7))
        Cm[np.ix_(idx, idx)] = cov_mount[np.ix_(idx, idx)]
        parts[name] = propagate_pose_covariance(res, None, poses.G_mount, Cm)[ok]
    parts_grid = {k: R_world_to_grid @ v @ T(R_world_to_grid) for k, v in parts.items()}
    # all sources together, with the mounting correlations
    total = res.cov[ok].copy()
    if poses.cam.cov is not None:
        total += propagate_pose_covariance(res, poses.cam.cov, pose_corr=corr)[ok]
    total += propagate_pose_covariance(res, None, poses.G_mount, cov_mount)[ok]
    total_grid = R_world_to_grid @ total @ T(R_world_to_grid)
    stats = error_stats(err)
    pred = _rms_sigma(total_grid)
    budget = {"sources": {k: _rms_sigma(v) for k, v in parts_grid.items()}, "predicted_rms": pred,
              "achieved_rms": stats["rms"],
              "ratio_achieved_to_predicted": {k: stats["rms"][k] / pred[k] if pred[k] > 0 else None
                                              for k in ("E", "N", "U", "2D", "3D")},
              "mean_flying_height_m": float(np.mean(poses.cam.C_world[:, 2] - X_world[:, 2].mean())),
              "mean_speed_m_s": float(np.mean(np.linalg.norm(poses.pos.v_world, axis=1))),
              "magnitudes": _magnitudes(traj, mount, m),
              "pos_correlation_time_s": float(tau) if tau else None,
              "pos_correlation_model": (f"exp(-|dt|/{float(tau):.0f} s) between images" if tau
                                        else "independent between images"),
              "mounting_covariance": ("random part (calibration flight: its POS common-mode error is counted "
                                      "once, in the POS term)") if cov_mount is not mount.cov else "full"}
    sig = np.sqrt(np.diagonal(total_grid, axis1=1, axis2=2))
    return CheckResult(ids, xyz_dg, xyz_ref, err, res.n_rays[ok], sig, stats,
                       asprs_2023(err, pts.sigma[[pid[k] for k in ids]]), budget, warnings, rejected)


CHECK_OUTLIER_SIGMA = 5.0   # check-point rays beyond this many robust sigmas are blunders


def _screened_intersection(camera, poses, oi: np.ndarray, op: np.ndarray, xy: np.ndarray, sigma: np.ndarray,
                           n_points: int, min_rays: int):
    """Intersect the check points, leaving out rays whose residual, standardised by its approximate redundancy
    (1 - 1.5/L for a point seen L times) and scaled by the median of all rays (DG pose errors make the rays
    disagree more than their pixel sigmas say), exceeds CHECK_OUTLIER_SIGMA; the worst ray of a point per
    round, until none. Returns the intersection of the kept rays and the kept mask."""
    keep = np.ones(len(oi), bool)
    sig = np.where(np.isfinite(sigma), sigma, 1.0)
    C_world, R_cam_to_world = poses.cam.C_world, poses.cam.R_cam_to_world
    while True:
        res = intersect(camera, C_world, R_cam_to_world, oi[keep], op[keep], xy[keep], sigma[keep], n_points, min_rays)
        L = np.bincount(op[keep], minlength=n_points)[op[keep]]
        e = np.linalg.norm(res.residuals_px / sig[keep], axis=1) / np.sqrt(np.clip(1 - 1.5 / np.maximum(L, 1),
                                                                                  0.1, 1))
        fin = np.isfinite(e)
        if fin.sum() < 6:
            return res, keep
        s_rob = float(np.median(e[fin])) / np.sqrt(2 * np.log(2))
        bad = fin & (e > CHECK_OUTLIER_SIGMA * s_rob) & (L > 2)     # two rays cannot tell which one is wrong
        if not bad.any():
            return res, keep
        rows = np.flatnonzero(keep)[bad]
        worst = {}
        for r, ev, p in zip(rows, e[bad], op[rows]):
            if p not in worst or ev > worst[p][1]:
                worst[p] = (r, ev)
        keep[[r for r, _ in worst.values()]] = False


def _magnitudes(traj: Trajectory, mount: MountingResult, meas: Measurements) -> dict:
    """The size of each error source (seed Table 6 'Magnitude' column)."""
    s = mount.sigmas
    out = {"delay": f"{s[0] * 1e3:.2f} ms", "lever_arm": "{:.3f} {:.3f} {:.3f} m".format(*s[1:4]),
           "boresight": "{:.4f} {:.4f} {:.4f} deg".format(*np.degrees(s[4:7]))}
    if traj.sigma is not None:
        ms = np.median(traj.sigma, axis=0)
        out["pos_position"] = "{:.3f} {:.3f} {:.3f} m (N, E, U)".format(*ms[:3])
        out["pos_attitude"] = "{:.4f} {:.4f} {:.4f} deg (roll, pitch, heading)".format(*ms[3:])
    sig = meas.sigma[np.isfinite(meas.sigma)]
    out["image_measurements"] = f"{np.median(sig):.2f} px" if sig.size else "1 px (default)"
    return out


def _pos_to_pose(poses, mount: MountingResult) -> np.ndarray:
    """d pose / d POS error [position (m, world), body rotation (rad)] per image (M,6,6)."""
    n = len(poses.image)
    G = np.zeros((n, 6, 6))
    G[:, :3, :3] = np.eye(3)
    G[:, :3, 3:] = -poses.pos.R_body_to_world @ skew(mount.lever_arm_m)
    G[:, 3:, 3:] = mount.R_cam_to_body.T
    return G


@dataclass
class CheckOptions:
    """Inputs and settings of `dgcal check`: mounting files (the first is the reference of the improvement
    rates), the flight's trajectory and events, check-point measurements, ground points, camera, map CRS."""

    mounting: tuple[Path, ...]
    trajectory: Path
    events: Path
    measurements: Path                 # dgcal CSV, ODM gcp_list.txt or MicMac XML
    gcp: Path                          # ground points; role `check` ones are used
    camera: Path
    crs: str
    all_points: bool = False           # control points are check points too
    pos_correlation_time_s: float | None = None  # s; None: from the trajectory (straight-strip duration)


@dataclass
class DgCheck:
    """DG check-point results per mounting (labelled by method) and the improvement rates over the first."""

    checks: dict[str, CheckResult]
    reference: str
    improvement: dict | None = None


def check_dg_files(opts: CheckOptions) -> DgCheck:
    """`dgcal check`: DG of the measured check points with every mounting file, errors (m, map E/N/U), seed
    Table 2 statistics, ASPRS 2023 and the predicted budget; improvement rates (%) over the first mounting."""
    tau = opts.pos_correlation_time_s
    if tau is not None and not tau >= 0:
        raise InputError(f"must be a time >= 0 s, not {tau}", field="pos_correlation_time")
    grid = MapGrid(opts.crs)
    events = read_any_events(opts.events)
    traj = read_any_trajectory(opts.trajectory, near_t=float(events.t[0]) if len(events) else None)
    meas = read_any_measurements(opts.measurements)[0]
    pts = read_points(opts.gcp)
    camera = load_camera(opts.camera)
    roles = ("check", "control") if opts.all_points else ("check",)
    labels: list[str] = []
    tasks = []
    for path in opts.mounting:
        m = read_mounting_json(path)
        label = m.method
        if label in labels:
            label = f"{m.method} ({Path(path).parent.name or Path(path).name})"
        labels.append(label)
        tasks.append(partial(check_points_dg, grid, traj, events, m, camera, meas, pts, roles,
                             pos_correlation_time_s="auto" if tau is None else tau))
    checks: dict[str, CheckResult] = dict(zip(labels, fork_map(tasks)))   # the mountings side by side
    names = list(checks)
    imp = improvement_table({k: v.stats for k, v in checks.items()}, names[0]) if len(names) > 1 else None
    return DgCheck(checks, names[0], imp)
