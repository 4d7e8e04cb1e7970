"""`dgcal flow`: seed 001's GNSS + optic-flow attitude from a forward camera's frames (a video or a folder of images
with their GPS times) and the GNSS velocity: per frame pair the pseudo-roll/pitch/yaw, the focus of expansion
(FOE), pitch and yaw, their offsets from the pseudo attitude (angle of attack, drift angle), the height above
ground, all with sigmas, and seed 001's Table 2 statistics when a true trajectory is given.

Sigmas: roll = the pseudo-roll's, from the GNSS velocity noise (estimated from the data unless given) through
the derivative (`dgcal.pos.gnss.pseudo_attitude`), plus what the flow's residual rotation says of the pseudo
roll-rate; pitch, yaw and AGL from the FOE's delete-a-block jackknife, the roll and the velocity noise
(`dgcal.pos.lowcost.optic_flow.flow_attitude`), raised toward the pair's formal variance times the run's median
jackknife/formal ratio (`pool_sigmas`).

A pair that cannot be trusted is listed as failed with its reason, never reported: its flow does not fit one focus
of expansion (residual RMS beyond the tracker's forward-backward bound: e.g. on the take-off run, where the ground
is too close to track), most of its tracks are outliers, or its height above ground disagrees with the GNSS
track and its neighbours (`track_gate`). The warp of a pair starts from the last trusted pair's height carried
along the GNSS track; a failed or rejected pair seeds nothing (`solve_pairs`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from dgcal.calib.camera.files import read_camera
from dgcal.fields.crs import R_ecef_to_ned_at
from dgcal.fields.errors import InputError
from dgcal.fields.io.csv_tables import read_table
from dgcal.fields.io import validate
from dgcal.fields.io.text_files import open_text
from dgcal.fields.io.formats import Trajectory
from dgcal.pos.gnss.pseudo_attitude import PseudoAttitude, pseudo_attitude
from dgcal.pos.gnss.solution_files import read_gnss_solution
from dgcal.pos.ins.interpolate import interpolate_trajectory
from dgcal.pos.lowcost.optic_flow import (FB_MAX_PX, R_CAM_TO_BODY_FORWARD, FlowAttitude, flow_attitude,
                                          mean_velocity, pool_sigmas, variance_ratios)
from dgcal.fields.io.image_folders import list_image_files
from dgcal.pos.lowcost.ukf_pos import read_true_trajectory

SEED001_TABLE2 = {"roll": {"mean_deg": -0.0276, "std_deg": 0.1981}, "pitch": {"mean_deg": -0.1400, "std_deg": 0.2872},
                  "yaw": {"mean_deg": 0.0934, "std_deg": 0.4210}}
ROW_COLUMNS = ("t_gps", "image1", "image2", "dt_s", "roll", "pitch", "yaw", "sigma_roll", "sigma_pitch", "sigma_yaw",
               "pseudo_roll", "pseudo_pitch", "pseudo_yaw", "angle_of_attack", "drift_angle", "foe_x", "foe_y",
               "sigma_foe_x", "sigma_foe_y", "agl_m", "sigma_agl_m", "n_tracks", "n_inliers", "residual_px",
               "parallax_px")


@dataclass
class FlowOptions:
    """Inputs and settings of `dgcal flow`: the camera file, the GNSS velocity (CSV t_gps,vn,ve,vd or
    gps_week,gps_sow,vn,ve,vd, or a GNSS solution file with velocities), the frames (`images` folder with
    `frame_times` CSV image,t_gps — default frames.csv in or beside the folder — or a `video` whose frame 0 is
    at `video_start_gps`, at `fps` or the container's rate), the camera-to-body rotation (default: looking along
    body x), a pair every `pair_every_s` s of frames `frame_dt_s` apart, the GNSS velocity noise (m/s, None:
    estimated), the derivative window (s), the jackknife grid, the slowest usable GNSS speed (m/s), the checks of
    a pair (`pair_gate`: residual RMS bound, px; parallax over residual) and against the GNSS track
    (`track_gate`: neighbours within s, k sigma), a true trajectory and ground height (m, for AGL)."""

    camera: Path
    gnss: Path
    images: Path | None = None
    video: Path | None = None
    frame_times: Path | None = None
    video_start_gps: float | None = None
    fps: float | None = None
    R_cam_to_body: np.ndarray = field(default_factory=lambda: R_CAM_TO_BODY_FORWARD.copy())
    pair_every_s: float = 2.0
    frame_dt_s: float = 0.5
    sigma_v_mps: float | None = None
    window_s: float = 0.8
    blocks: int = 5
    min_speed_mps: float = 5.0
    max_residual_px: float = FB_MAX_PX
    min_parallax_snr: float = 20.0
    track_window_s: float = 30.0
    track_k_sigma: float = 5.0
    truth: Path | None = None
    ground_height_m: float | None = None
    progress: bool = False


@dataclass
class FlowRun:
    """`dgcal flow`: one row per frame pair (ROW_COLUMNS, and true_*/err_* with a truth), the pairs that failed
    (time, reason), the pseudo attitude series, the Table 2 statistics (None without a truth) and the summary."""

    rows: list[dict]
    failed: list[tuple[float, str]]
    pseudo: PseudoAttitude
    table2: dict | None
    summary: dict


def read_gnss_velocity(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """GNSS velocity (t GPS s, NED m/s): CSV t_gps,vn,ve,vd or gps_week,gps_sow,vn,ve,vd, or a GNSS solution file
    (dgcal gnss.csv, RTKLIB .pos) with velocities."""
    path = Path(path)
    with open_text(path) as lines_in:
        head = next(lines_in, "").lower()
    names = [c.strip() for c in head.split(",")]
    if "vn" in names and ("t_gps" in names or "gps_sow" in names):
        timecols = ("t_gps",) if "t_gps" in names else ("gps_week", "gps_sow")
        tab = read_table(path, timecols + ("vn", "ve", "vd"))
        t = tab["t_gps"] if "t_gps" in names else tab["gps_week"] * 604800.0 + tab["gps_sow"]
        v = np.column_stack([tab["vn"], tab["ve"], tab["vd"]])
        lines = tab.lines
    else:
        sol = read_gnss_solution(path)
        if sol.v_ecef is None:
            raise InputError("the GNSS file has no velocities (vn,ve,vd or vx,vy,vz columns)", path)
        v = np.einsum("nij,nj->ni", R_ecef_to_ned_at(sol.p_ecef), sol.v_ecef)
        t, lines = sol.t, sol.lines if sol.lines is not None else np.arange(len(sol.t)) + 2
    bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1))
    if len(bad):
        raise InputError("velocity not a finite number", path, int(lines[bad[0]]), "vn")
    validate.values_in_range(v, -validate.MAX_SPEED_M_S, validate.MAX_SPEED_M_S, path, "vn", lines, unit="m/s")
    validate.gps_seconds_values(t, path, "t_gps" if "t_gps" in names else "gps_sow", lines)
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        raise InputError("time does not increase", path, int(lines[back[0] + 1]), "t_gps")
    if len(t) < 10:
        raise InputError(f"only {len(t)} GNSS velocity samples", path)
    return np.asarray(t, float), v


class Frames:
    """The frames of a folder (with times) or a video: `t` (GPS s), `names`, and `image(i)` (float32 grey 0..1)."""

    def __init__(self, opts: FlowOptions):
        self.video = None
        if (opts.images is None) == (opts.video is None):
            raise InputError("give exactly one of --images DIR or --video FILE", field="images")
        if opts.images is not None:
            d = Path(opts.images)
            files = {p.name: p for p in list_image_files(d)}
            ft = opts.frame_times or next((p for p in (d / "frames.csv", d.parent / "frames.csv") if p.is_file()),
                                          None)
            if ft is None:
                raise InputError("no frame times: give --frame-times CSV image,t_gps", d)
            tab = read_table(ft, ("image", "t_gps"))
            keep = [i for i, n in enumerate(tab["image"]) if str(n) in files]
            if len(keep) < 2:
                raise InputError(f"fewer than two of its images are in {d}", ft)
            self.names = [str(tab["image"][i]) for i in keep]
            self.t = tab["t_gps"][keep]
            self.paths = [files[n] for n in self.names]
        else:
            cap = cv2.VideoCapture(str(opts.video))
            if not cap.isOpened():
                raise InputError("cannot open the video", opts.video)
            fps = opts.fps or cap.get(cv2.CAP_PROP_FPS)
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            cap.release()
            if not fps or fps <= 0 or n < 2:
                raise InputError("the video has no frame rate or fewer than two frames (--fps?)", opts.video)
            if opts.video_start_gps is None:
                raise InputError("the GPS time of the video's first frame is needed", field="video_start_gps")
            self.video, self.fps = Path(opts.video), float(fps)
            self.t = opts.video_start_gps + np.arange(n) / self.fps
            self.names = [f"{self.video.name}#{k}" for k in range(n)]
        order = np.argsort(self.t)
        if np.any(np.diff(self.t[order]) <= 0):
            raise InputError("two frames share a time", opts.frame_times or opts.video)
        self._cache: dict[int, np.ndarray] = {}

    def image(self, i: int) -> np.ndarray:
        """Frame i as float32 grey (0..1)."""
        if i in self._cache:
            return self._cache[i]
        if self.video is None:
            img = cv2.imread(str(self.paths[i]), cv2.IMREAD_GRAYSCALE)
            if img is None:
                raise InputError("cannot read the image", self.paths[i])
        else:
            cap = cv2.VideoCapture(str(self.video))
            cap.set(cv2.CAP_PROP_POS_FRAMES, i)
            ok, img = cap.read()
            cap.release()
            if not ok:
                raise InputError(f"cannot read frame {i}", self.video)
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
        out = img.astype(np.float32) / 255.0
        if len(self._cache) > 8:
            self._cache.pop(next(iter(self._cache)))
        self._cache[i] = out
        return out


def _interp_angles(t: float, tt: np.ndarray, a_deg: np.ndarray) -> float:
    return float(np.degrees(np.interp(t, tt, np.unwrap(np.radians(a_deg)))) % 360.0)


def gnss_height_track(t: np.ndarray, v_ned: np.ndarray) -> np.ndarray:
    """Height (m) along the GNSS track relative to its first sample: the vertical velocity integrated (trapezoids)."""
    up = -np.asarray(v_ned, float)[:, 2]
    return np.r_[0.0, np.cumsum(0.5 * (up[1:] + up[:-1]) * np.diff(t))]


def pair_gate(fa: FlowAttitude, max_residual_px: float = FB_MAX_PX, min_inlier_fraction: float = 0.5,
              min_parallax_snr: float = 20.0) -> str | None:
    """Why a frame pair's solution cannot be trusted on its own evidence (None: it can): the focus-of-expansion fit's
    residual RMS beyond what tracking noise can give (the tracker drops tracks whose forward-backward round trip
    misses by more), most tracks outliers to it, too little parallax (the de-rotated flow's median under
    `min_parallax_snr` times the residual RMS: little translation, or a near-pure rotation, where the FOE and the
    depths are no longer linear in the tracking errors and their sigmas fall short), or sigmas that are not
    finite."""
    q = fa.quality
    if not q["rms_px"] <= max_residual_px:
        return (f"the flow does not fit one focus of expansion: residual RMS {q['rms_px']:.2f} px, more than tracking "
                f"noise ({max_residual_px:g} px)")
    if fa.n_inliers < min_inlier_fraction * fa.n_tracks:
        return f"only {fa.n_inliers} of {fa.n_tracks} tracks fit one focus of expansion"
    if not q["parallax_px"] >= min_parallax_snr * q["rms_px"]:
        return (f"too little parallax: de-rotated flow {q['parallax_px']:.2f} px, under {min_parallax_snr:g} times the "
                f"fit's residual ({q['rms_px']:.3f} px)")
    sig = (fa.sigma_roll, fa.sigma_pitch, fa.sigma_yaw, fa.sigma_agl_m)
    if not all(np.isfinite(sig)) or not np.isfinite(fa.agl_m):
        return "the sigmas are not finite"
    return None


def track_gate(t: np.ndarray, agl: np.ndarray, sigma_agl: np.ndarray, h_track: np.ndarray, window_s: float = 30.0,
               k_sigma: float = 5.0, min_neighbours: int = 4) -> list[str | None]:
    """Heights above ground checked against the GNSS track: each pair's ground height (track height minus its AGL)
    beside a robust straight line through its neighbours' within `window_s` s (terrain that rises or falls along
    the track), within `k_sigma` times its sigma and the neighbours' scatter about the line (1.4826 MAD) combined;
    a reason per pair (None: consistent, or fewer than `min_neighbours` neighbours to judge)."""
    g = h_track - agl
    out: list[str | None] = []
    for i in range(len(t)):
        nb = np.flatnonzero((np.abs(t - t[i]) <= window_s) & (np.arange(len(t)) != i))
        if len(nb) < min_neighbours:
            out.append(None)
            continue
        x, y = t[nb] - t[i], g[nb]
        use = np.ones(len(nb), bool)
        for _ in range(3):   # least squares, then without the neighbours 3.5 robust sigmas off the line
            c = np.polyfit(x[use], y[use], 1) if np.ptp(x[use]) > 0 else np.array([0.0, np.median(y[use])])
            r = y - np.polyval(c, x)
            spread = 1.4826 * float(np.median(np.abs(r[use])))
            use = np.abs(r) <= 3.5 * max(spread, 1e-9)
            if use.sum() < min_neighbours:
                break
        ref = float(c[1])
        tol = k_sigma * float(np.hypot(sigma_agl[i], spread))
        if abs(g[i] - ref) > tol:
            out.append(f"height above ground {agl[i]:.1f} +- {sigma_agl[i]:.1f} m disagrees with the GNSS track and "
                       f"the neighbouring pairs ({h_track[i] - ref:.1f} m)")
        else:
            out.append(None)
    return out


def solve_pairs(camera, frames, tv: np.ndarray, v: np.ndarray, pa: PseudoAttitude, opts: FlowOptions, t0: float,
                t1: float) -> tuple[list[dict], list[tuple[float, str]]]:
    """The frame pairs of [t0, t1] (a pair every `opts.pair_every_s` s), each solved, checked on its own
    (`pair_gate`) and against the GNSS track (`track_gate`); (rows, failed (time, reason)) in time order.

    The ground-plane warp of a pair starts from the height of the last pair that passed its own checks, carried
    along the GNSS track (its vertical velocity integrated); a pair that fails from it is solved again from plain
    tracking. A pair that fails a check never seeds another, and one seeded by a pair that the track check
    rejects afterwards is solved again."""
    h_all = gnss_height_track(tv, v)
    grid = np.arange(t0, t1, opts.pair_every_s)
    it = tqdm(grid, desc="flow pairs", unit="pair", leave=False) if opts.progress else grid
    done: list[dict] = []        # solved pairs: {"t", "fa", "args", "seed_from" (index into done or None)}
    failed: list[tuple[float, str]] = []

    def solve(args: dict, ok: list[int]) -> tuple[FlowAttitude | None, str | None, int | None]:
        """One pair seeded by the last pair of `ok` (if any; from plain tracking when that fails): the solution,
        why it is not to be trusted (None: it is) and the pair that seeded it."""
        seeds = [(None, None)]
        if ok:
            k = ok[-1]
            s = done[k]["fa"].agl_m + float(np.interp(args["ta"], tv, h_all) - np.interp(done[k]["t"], tv, h_all))
            if s > 0:
                seeds.insert(0, (s, k))
        reason = ""
        for seed, src in seeds:
            try:
                fa = flow_attitude(camera, frames.image(args["i"]), frames.image(args["j"]), args["tb"] - args["ta"],
                                   args["rph1"], args["w"], args["vm"], opts.R_cam_to_body, agl_guess_m=seed,
                                   **args["kw"])
            except (ValueError, np.linalg.LinAlgError) as exc:
                reason = str(exc)
                continue
            reason = pair_gate(fa, opts.max_residual_px, min_parallax_snr=opts.min_parallax_snr)
            if reason is None:
                return fa, None, src
        return None, reason, None

    ok: list[int] = []
    for tg in it:
        i = int(np.argmin(np.abs(frames.t - tg)))
        j = int(np.argmin(np.abs(frames.t - (frames.t[i] + opts.frame_dt_s))))
        ta, tb = float(frames.t[i]), float(frames.t[j])
        if j <= i or tb > tv[-1] or ta < tv[0]:
            continue
        k = int(np.argmin(np.abs(pa.t - ta)))
        if not pa.valid[k]:
            failed.append((ta, "GNSS speed too low"))
            continue
        rph1 = np.array([np.interp(ta, pa.t, pa.rph[:, 0]), np.interp(ta, pa.t, pa.rph[:, 1]),
                         _interp_angles(ta, pa.t, pa.rph[:, 2])])
        w = np.array([np.interp(0.5 * (ta + tb), pa.t, pa.omega_b[:, c]) for c in range(3)])
        vm, gain = mean_velocity(tv, v, ta, tb)
        s_roll = float(np.interp(ta, pa.t, pa.sigma_rph[:, 0]))
        args = {"i": i, "j": j, "ta": ta, "tb": tb, "rph1": rph1, "w": w, "vm": vm,
                "names": (frames.names[i], frames.names[j]),
                "kw": {"sigma_roll_deg": s_roll, "sigma_v_mps": pa.sigma_v_mps * gain, "blocks": opts.blocks,
                       "roll_lag_s": opts.window_s / 4}}
        fa, reason, src = solve(args, ok)
        if reason is not None:
            failed.append((ta, reason))
            continue
        done.append({"t": ta, "fa": fa, "args": args, "seed_from": src})
        ok.append(len(done) - 1)
    # the pairs' sigmas with the run's evidence, then the GNSS-track check; a pair seeded by a rejected one is solved
    # again (seeded by the last pair before it that is not rejected)
    ratios = variance_ratios([d["fa"] for d in done])
    for d in done:
        pool_sigmas(d["fa"], ratios)
    rejected: dict[int, str] = {}
    while True:   # ends: each round rejects pairs, or solves again pairs whose new seeds are not rejected
        keep = [n for n in range(len(done)) if n not in rejected]
        t_keep = np.array([done[n]["t"] for n in keep])
        why = track_gate(t_keep, np.array([done[n]["fa"].agl_m for n in keep]),
                         np.array([done[n]["fa"].sigma_agl_m for n in keep]), np.interp(t_keep, tv, h_all),
                         opts.track_window_s, opts.track_k_sigma)
        new = {n: r for n, r in zip(keep, why) if r is not None}
        rejected.update(new)
        again = [n for n in range(len(done)) if n not in rejected and done[n]["seed_from"] in rejected]
        if not new and not again:
            break
        for n in again:
            fa, reason, src = solve(done[n]["args"], [m for m in range(n) if m not in rejected])
            if reason is not None:
                rejected[n] = reason
            else:
                pool_sigmas(fa, ratios)
                done[n].update(fa=fa, seed_from=src)
    failed += [(done[n]["t"], r) for n, r in rejected.items()]
    return [_row(d["fa"], d["args"]) for n, d in enumerate(done) if n not in rejected], sorted(failed)


def _row(fa: FlowAttitude, args: dict) -> dict:
    """A pair's row of flow.csv (ROW_COLUMNS)."""
    sf = np.sqrt(np.clip(np.diag(fa.foe_cov), 0, None))
    return {"t_gps": args["ta"], "image1": args["names"][0], "image2": args["names"][1],
            "dt_s": args["tb"] - args["ta"],
            "roll": fa.roll, "pitch": fa.pitch, "yaw": fa.yaw, "sigma_roll": fa.sigma_roll,
            "sigma_pitch": fa.sigma_pitch, "sigma_yaw": fa.sigma_yaw, "pseudo_roll": float(args["rph1"][0]),
            "pseudo_pitch": fa.pseudo_pitch, "pseudo_yaw": fa.pseudo_yaw,
            "angle_of_attack": fa.pitch_offset, "drift_angle": fa.yaw_offset, "foe_x": float(fa.foe[0]),
            "foe_y": float(fa.foe[1]), "sigma_foe_x": float(sf[0]), "sigma_foe_y": float(sf[1]),
            "agl_m": fa.agl_m, "sigma_agl_m": fa.sigma_agl_m, "n_tracks": fa.n_tracks,
            "n_inliers": fa.n_inliers, "residual_px": fa.quality["rms_px"], "parallax_px": fa.quality["parallax_px"]}


def flow_attitude_run(opts: FlowOptions) -> FlowRun:
    """`dgcal flow`: read the inputs of `opts` and estimate the attitude of every frame pair (see the module doc)."""
    camera = read_camera(opts.camera)
    tv, v = read_gnss_velocity(opts.gnss)
    pa = pseudo_attitude(tv, v, window_s=opts.window_s, min_speed=opts.min_speed_mps,
                         sigma_v_mps="auto" if opts.sigma_v_mps is None else opts.sigma_v_mps)
    frames = Frames(opts)
    truth = read_true_trajectory(opts.truth) if opts.truth else None
    t0, t1 = max(frames.t[0], tv[0]), min(frames.t[-1], tv[-1]) - opts.frame_dt_s
    if t1 <= t0:
        raise InputError("the frames and the GNSS velocity do not overlap in time", opts.gnss)
    rows, failed = solve_pairs(camera, frames, tv, v, pa, opts, t0, t1)
    if not rows:
        raise InputError("no frame pair gave an attitude: " + (failed[0][1] if failed else "no pairs in the overlap"),
                         opts.images or opts.video)
    table2 = None
    if truth is not None:
        table2 = _truth_statistics(rows, truth, opts.ground_height_m)
    summary = flow_summary(rows, failed, pa, table2, opts)
    return FlowRun(rows, failed, pa, table2, summary)


def _truth_statistics(rows: list[dict], truth: Trajectory, ground_h: float | None) -> dict:
    """Seed 001 Table 2 (error mean and std, deg) and the normalised error RMS per axis against `truth`; AGL errors
    with a ground height. Adds true_* and err_* to the rows."""
    t = np.array([r["t_gps"] for r in rows])
    inside = (t >= truth.t[0]) & (t <= truth.t[-1])
    if inside.sum() < 2:
        raise InputError("the true trajectory does not cover the frame pairs", truth.path)
    st = interpolate_trajectory(truth, t[inside])
    k = np.flatnonzero(inside)
    for n, kk in enumerate(k):
        r = rows[kk]
        for a, name in enumerate(("roll", "pitch", "yaw")):
            r[f"true_{name}"] = float(st.rph[n, a])
            d = r[name] - st.rph[n, a]
            r[f"err_{name}"] = float((d + 180.0) % 360.0 - 180.0) if name == "yaw" else float(d)
        if ground_h is not None:
            r["true_agl_m"] = float(st.h[n] - ground_h)
            r["err_agl_m"] = r["agl_m"] - r["true_agl_m"]
    use = [rows[kk] for kk in k]
    out = {}
    for name in ("roll", "pitch", "yaw"):
        e = np.array([r[f"err_{name}"] for r in use])
        s = np.array([r[f"sigma_{name}"] for r in use])
        out[name] = {"mean_deg": float(e.mean()), "std_deg": float(e.std(ddof=1)) if len(e) > 1 else 0.0,
                     "rms_deg": float(np.sqrt(np.mean(e ** 2))),
                     "normalised_rms": float(np.sqrt(np.mean((e / s) ** 2)))}
    pe = np.array([r["pseudo_pitch"] - r["true_pitch"] for r in use])
    ye = np.array([(r["pseudo_yaw"] - r["true_yaw"] + 180.0) % 360.0 - 180.0 for r in use])
    out["pseudo_only"] = {"pitch_mean_deg": float(pe.mean()), "yaw_mean_deg": float(ye.mean())}
    if ground_h is not None:
        a = np.array([r["err_agl_m"] for r in use])
        ta = np.array([r["true_agl_m"] for r in use])
        out["agl"] = {"mean_error_m": float(a.mean()), "std_error_m": float(a.std(ddof=1)) if len(a) > 1 else 0.0,
                      "median_rel_error": float(np.median(np.abs(a) / ta))}
    out["n_pairs"] = int(len(use))
    out["seed001"] = SEED001_TABLE2
    return out


def flow_summary(rows: list[dict], failed: list, pa: PseudoAttitude, table2: dict | None, opts: FlowOptions) -> dict:
    """Numbers for flow.json."""
    med = {k: float(np.median([r[k] for r in rows])) for k in ("sigma_roll", "sigma_pitch", "sigma_yaw",
                                                             "angle_of_attack", "drift_angle", "agl_m",
                                                             "n_inliers")}
    return {"n_pairs": len(rows), "n_failed": len(failed), "failed": [{"t_gps": t, "reason": m} for t, m in failed],
            "pair_every_s": opts.pair_every_s, "frame_dt_s": opts.frame_dt_s,
            "gnss_velocity_sigma_mps": pa.sigma_v_mps, "median": med, "table2": table2}
