"""`dgcal flow`: seed 001's GNSS + optic-flow attitude from a forward camera's frames (a video or a folder of images
with their GPS times) and the GNSS velocity: per frame pair the pseudo-roll/pitch/yaw, the focus of expansion
(FOE), pitch and yaw, their offsets from the pseudo attitude (angle of attack, drift angle), the height above
ground, all with sigmas, and seed 001's Table 2 statistics when a true trajectory is given.

Sigmas: roll = the pseudo-roll's, from the GNSS velocity noise (estimated from the data unless given) through
the derivative (`dgcal.pos.gnss.pseudo_attitude`); pitch and yaw from the FOE's delete-a-block jackknife
covariance, the pseudo-roll and the velocity noise (`dgcal.pos.lowcost.optic_flow.flow_attitude`).
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
from dgcal.pos.lowcost.optic_flow import R_CAM_TO_BODY_FORWARD, flow_attitude, mean_velocity
from dgcal.pos.lowcost.ukf_pos import read_true_trajectory

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
SEED001_TABLE2 = {"roll": {"mean_deg": -0.0276, "std_deg": 0.1981}, "pitch": {"mean_deg": -0.1400, "std_deg": 0.2872},
                  "yaw": {"mean_deg": 0.0934, "std_deg": 0.4210}}
ROW_COLUMNS = ("t_gps", "image1", "image2", "dt_s", "roll", "pitch", "yaw", "sigma_roll", "sigma_pitch", "sigma_yaw",
               "pseudo_roll", "pseudo_pitch", "pseudo_yaw", "angle_of_attack", "drift_angle", "foe_x", "foe_y",
               "sigma_foe_x", "sigma_foe_y", "agl_m", "sigma_agl_m", "n_tracks", "n_inliers")


@dataclass
class FlowOptions:
    """Inputs and settings of `dgcal flow`: the camera file, the GNSS velocity (CSV t_gps,vn,ve,vd or
    gps_week,gps_sow,vn,ve,vd, or a GNSS solution file with velocities), the frames (`images` folder with
    `frame_times` CSV image,t_gps — default frames.csv in or beside the folder — or a `video` whose frame 0 is
    at `video_start_gps`, at `fps` or the container's rate), the camera-to-body rotation (default: looking along
    body x), a pair every `pair_every_s` s of frames `frame_dt_s` apart, the GNSS velocity noise (m/s, None:
    estimated), the derivative window (s), the jackknife grid, a true trajectory and ground height (m, for AGL)."""

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
            if not d.is_dir():
                raise InputError("not a folder", d)
            files = {p.name: p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES}
            if not files:
                raise InputError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in the folder", d)
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
    rows, failed = [], []
    grid = np.arange(t0, t1, opts.pair_every_s)
    it = tqdm(grid, desc="flow pairs", unit="pair", leave=False) if opts.progress else grid
    agl_guess = None
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
        try:
            fa = flow_attitude(camera, frames.image(i), frames.image(j), tb - ta, rph1, w, vm, opts.R_cam_to_body,
                               sigma_roll_deg=s_roll, sigma_v_mps=pa.sigma_v_mps * gain, blocks=opts.blocks,
                               agl_guess_m=agl_guess)
        except (ValueError, np.linalg.LinAlgError) as exc:
            failed.append((ta, str(exc)))
            continue
        agl_guess = fa.agl_m
        sf = np.sqrt(np.clip(np.diag(fa.foe_cov), 0, None))
        rows.append({"t_gps": ta, "image1": frames.names[i], "image2": frames.names[j], "dt_s": tb - ta,
                     "roll": fa.roll, "pitch": fa.pitch, "yaw": fa.yaw, "sigma_roll": fa.sigma_roll,
                     "sigma_pitch": fa.sigma_pitch, "sigma_yaw": fa.sigma_yaw, "pseudo_roll": float(rph1[0]),
                     "pseudo_pitch": fa.pseudo_pitch, "pseudo_yaw": fa.pseudo_yaw,
                     "angle_of_attack": fa.pitch_offset, "drift_angle": fa.yaw_offset, "foe_x": float(fa.foe[0]),
                     "foe_y": float(fa.foe[1]), "sigma_foe_x": float(sf[0]), "sigma_foe_y": float(sf[1]),
                     "agl_m": fa.agl_m, "sigma_agl_m": fa.sigma_agl_m, "n_tracks": fa.n_tracks,
                     "n_inliers": fa.n_inliers})
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
