"""Forward-looking camera image stream over textured flat terrain (seed 001's vision model), rendered with
`dgcal.sim.render` from a true flight (`dgcal.sim.trajectory`), plus the GNSS/optic-flow attitude study of seed 001
(Table 1 settings: 90 x 90 deg field of view, 300 s flight; Table 2: roll/pitch/yaw error statistics).

World frame: local ENU at the site (`dgcal.fields.crs.LocalENU` at lat0, lon0, h_ground); the ground is the
plane z = 0 textured with multi-octave noise (blobs and edges from 4 m to 60 m).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from dgcal.calib.camera.models import Fraser7
from dgcal.fields.crs import LocalENU
from dgcal.fields.frames import R_NED_TO_ENU
from dgcal.fields.io.csv_tables import staged_dir
from dgcal.pos.gnss.pseudo_attitude import pseudo_attitude
from dgcal.calib.camera.files import write_camera
from dgcal.pos.lowcost.optic_flow import (R_CAM_TO_BODY_FORWARD, flow_attitude, mean_velocity, pool_sigmas,
                                          variance_ratios)
from dgcal.sim.render import Facet, RayGrid, render
from dgcal.sim.trajectory import TrueTrajectory, simulate_true_trajectory

PSEUDO_WINDOW_S = 0.8   # the pseudo attitude's derivative window (s), as `dgcal flow`'s default


def ground_texture(size_m: float = 6000.0, texel_m: float = 2.0, seed: int = 0) -> Facet:
    """A square textured ground facet (z = 0, centred on the origin) of multi-octave smoothed noise."""
    n = int(round(size_m / texel_m))
    rng = np.random.default_rng(seed)
    tex = np.zeros((n, n), np.float32)
    for scale_m, amp in ((60.0, 0.6), (24.0, 0.5), (10.0, 0.45), (4.0, 0.35)):
        k = max(1, int(round(scale_m / texel_m)))
        m = n // k + 2
        small = rng.standard_normal((m, m)).astype(np.float32)
        big = cv2.resize(small, (m * k, m * k), interpolation=cv2.INTER_CUBIC)[:n, :n]
        tex += amp * big
    tex = cv2.GaussianBlur(tex, (0, 0), 0.7)
    tex = (tex - tex.mean()) / (4 * tex.std()) + 0.5
    tex = np.clip(tex, 0.02, 0.98).astype(np.float32)
    half = size_m / 2
    return Facet(origin_w=np.array([-half, half, 0.0]), du_w=np.array([texel_m, 0.0, 0.0]),
                 dv_w=np.array([0.0, -texel_m, 0.0]), grey=tex)


def forward_camera(image_px: int = 240, fov_deg: float = 90.0):
    """A square pinhole camera (Fraser7, no distortion) with the given full field of view."""
    f = 0.5 * image_px / np.tan(np.radians(fov_deg) / 2)
    c = (image_px - 1) / 2
    return Fraser7.from_dict((image_px, image_px), {"f": f, "cx": c, "cy": c})


@dataclass
class ForwardCameraSim:
    """Renders frames of the forward camera at any time of a true flight."""

    truth: TrueTrajectory
    camera: object
    ground: Facet
    enu: LocalENU
    R_cam_to_body: np.ndarray
    rays: RayGrid
    sky: float = 0.85

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Camera centre (m, ENU) and R_cam_to_enu at GPS time t (camera at the IMU origin)."""
        s = self.truth.at(t)
        C_enu = self.enu.from_ecef(s.p_ecef[0])
        R_body_to_enu = R_NED_TO_ENU @ s.R_body_to_ned[0]
        return C_enu, R_body_to_enu @ self.R_cam_to_body

    def frame(self, t: float, noise: float = 0.0, rng: np.random.Generator | None = None) -> np.ndarray:
        """Grey image (float32 0..1) at GPS time t, with optional additive Gaussian noise."""
        C_enu, R_cam_to_enu = self.pose(t)
        R_enu_to_cam = R_cam_to_enu.T
        img = render(self.camera, R_enu_to_cam, -R_enu_to_cam @ C_enu, [self.ground], background=self.sky,
                     supersample=2, rays=self.rays)
        if noise > 0:
            img = img + (rng or np.random.default_rng()).standard_normal(img.shape).astype(np.float32) * noise
        return np.clip(img, 0.0, 1.0)


def make_forward_camera_sim(duration_s: float = 300.0, height_agl: float = 60.0, speed: float = 25.0,
                            bank_deg: float = 25.0, aoa_deg: float = 3.0, crab_deg: float = 4.0,
                            image_px: int = 240, fov_deg: float = 90.0, rate_hz: float = 50.0,
                            lat0: float = -27.5, lon0: float = 153.0, h_ground: float = 20.0,
                            seed: int = 0) -> ForwardCameraSim:
    """Seed 001-style flight (racetrack + orbits, coordinated turns, angle of attack and a wind crab angle)
    with a forward camera along the body x axis."""
    truth = simulate_true_trajectory("fixed-wing", lat0=lat0, lon0=lon0, h_ground=h_ground, heights_agl=(height_agl,),
                                     n_strips=2, strip_length_m=1200.0, strip_spacing_m=500.0, speed=speed,
                                     bank_deg=bank_deg, climb_rate=3.0, aoa_deg=aoa_deg, crab_deg=crab_deg,
                                     rate_hz=rate_hz, duration_s=duration_s)
    cam = forward_camera(image_px, fov_deg)
    return ForwardCameraSim(truth, cam, ground_texture(seed=seed), LocalENU(lat0, lon0, h_ground),
                            R_CAM_TO_BODY_FORWARD, RayGrid(cam))


def gnss_velocity(truth: TrueTrajectory, rate_hz: float = 10.0, sigma_mps: float = 0.02,
                  seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """GNSS Doppler velocities (NED, m/s) at `rate_hz` with white noise; (t, v_ned)."""
    rng = np.random.default_rng(seed)
    step = max(1, int(round(truth.rate_hz / rate_hz)))
    idx = np.arange(0, len(truth.t), step)
    return truth.t[idx].copy(), truth.v_ned[idx] + rng.standard_normal((len(idx), 3)) * sigma_mps


def flow_attitude_study(sim: ForwardCameraSim | None = None, pair_every_s: float = 5.0, frame_dt: float = 0.5,
                        min_agl_m: float = 30.0, image_noise: float = 0.005, seed: int = 0,
                        progress: bool = False) -> dict:
    """Seed 001 Table 2 on a simulated flight: per frame pair (every `pair_every_s` s once above `min_agl_m`)
    roll from pseudo-roll, pitch/yaw from pseudo attitude + FOE, AGL from flow; error statistics vs truth."""
    sim = sim or make_forward_camera_sim(seed=seed)
    tr = sim.truth
    tv, v = gnss_velocity(tr, seed=seed + 1)
    pa = pseudo_attitude(tv, v, window_s=PSEUDO_WINDOW_S, sigma_v_mps="auto")
    rng = np.random.default_rng(seed + 2)
    agl_true = np.array([sim.enu.from_ecef(p)[2] for p in tr.p_ecef[::int(tr.rate_hz)]])
    t_agl = tr.t[::int(tr.rate_hz)]
    t_start = t_agl[np.argmax(agl_true > min_agl_m)]
    times = np.arange(t_start, tr.t[-1] - frame_dt - 1.0, pair_every_s)
    rows, fas = [], []
    it = times
    if progress:
        it = tqdm(times, desc="flow pairs", unit="pair", leave=False)
    for t1 in it:
        t2 = t1 + frame_dt
        tm = 0.5 * (t1 + t2)
        k1 = int(np.argmin(np.abs(pa.t - t1)))
        rph1 = np.array([np.interp(t1, pa.t, pa.rph[:, 0]), np.interp(t1, pa.t, pa.rph[:, 1]),
                         np.degrees(np.interp(t1, pa.t, np.unwrap(np.radians(pa.rph[:, 2])))) % 360.0])
        w = np.array([np.interp(tm, pa.t, pa.omega_b[:, i]) for i in range(3)])
        v_mid, gain = mean_velocity(tv, v, t1, t2)  # the chord's velocity
        if not pa.valid[k1]:
            continue
        img1 = sim.frame(t1, image_noise, rng)
        img2 = sim.frame(t2, image_noise, rng)
        try:
            fa = flow_attitude(sim.camera, img1, img2, frame_dt, rph1, w, v_mid, sim.R_cam_to_body,
                               sigma_roll_deg=float(np.interp(t1, pa.t, pa.sigma_rph[:, 0])),
                               sigma_v_mps=pa.sigma_v_mps * gain, roll_lag_s=PSEUDO_WINDOW_S / 4)
        except ValueError:
            continue
        s = tr.at(t1)
        C_enu, _ = sim.pose(t1)
        fas.append(fa)
        rows.append({"t": float(t1), "roll": fa.roll, "pitch": fa.pitch, "yaw": fa.yaw,
                     "sigma_roll": fa.sigma_roll, "sigma_pitch": fa.sigma_pitch, "sigma_yaw": fa.sigma_yaw,
                     "pseudo_pitch": float(rph1[1]), "pseudo_yaw": float(rph1[2]),
                     "true_roll": float(s.rph[0, 0]), "true_pitch": float(s.rph[0, 1]),
                     "true_yaw": float(s.rph[0, 2]), "agl": fa.agl_m, "sigma_agl": fa.sigma_agl_m,
                     "true_agl": float(C_enu[2]), "n_tracks": fa.n_tracks, "n_inliers": fa.n_inliers})
    if not rows:
        raise RuntimeError("no usable frame pairs")
    ratios = variance_ratios(fas)   # the sigmas as `dgcal flow` gives them: pooled over the run
    for fa, r in zip(fas, rows):
        pool_sigmas(fa, ratios)
        r.update(sigma_pitch=fa.sigma_pitch, sigma_yaw=fa.sigma_yaw, sigma_agl=fa.sigma_agl_m)
    R = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    err = np.column_stack([R["roll"] - R["true_roll"], R["pitch"] - R["true_pitch"],
                           (R["yaw"] - R["true_yaw"] + 180.0) % 360.0 - 180.0])
    err_pseudo = np.column_stack([R["pseudo_pitch"] - R["true_pitch"],
                                  (R["pseudo_yaw"] - R["true_yaw"] + 180.0) % 360.0 - 180.0])
    agl_err = R["agl"] - R["true_agl"]
    table2 = {name: {"mean_deg": float(err[:, i].mean()), "std_deg": float(err[:, i].std(ddof=1))}
              for i, name in enumerate(("roll", "pitch", "yaw"))}
    zr = err[:, 0] / R["sigma_roll"]
    zp = err[:, 1] / R["sigma_pitch"]
    zy = err[:, 2] / R["sigma_yaw"]
    return {"n_pairs": len(rows), "frame_dt_s": frame_dt, "pair_every_s": pair_every_s,
            "duration_s": float(tr.t[-1] - tr.t[0]), "fov_deg": 90.0, "image_px": int(sim.camera.image_size[0]),
            "table2": table2,
            "pseudo_only": {"pitch_mean_deg": float(err_pseudo[:, 0].mean()),
                            "yaw_mean_deg": float(err_pseudo[:, 1].mean()),
                            "pitch_std_deg": float(err_pseudo[:, 0].std(ddof=1)),
                            "yaw_std_deg": float(err_pseudo[:, 1].std(ddof=1))},
            "normalised_error_rms": {"roll": float(np.sqrt(np.mean(zr ** 2))),
                                     "pitch": float(np.sqrt(np.mean(zp ** 2))),
                                     "yaw": float(np.sqrt(np.mean(zy ** 2)))},
            "agl": {"mean_error_m": float(np.mean(agl_err)), "std_error_m": float(np.std(agl_err, ddof=1)),
                    "median_rel_error": float(np.median(np.abs(agl_err) / R["true_agl"])),
                    "true_agl_range_m": [float(R["true_agl"].min()), float(R["true_agl"].max())]},
            "tracks_median": float(np.median(R["n_tracks"])), "seed001_table2": {
                "roll": {"mean_deg": -0.0276, "std_deg": 0.1981}, "pitch": {"mean_deg": -0.1400, "std_deg": 0.2872},
                "yaw": {"mean_deg": 0.0934, "std_deg": 0.4210}},
            "rows": rows}


def format_table2(rep: dict) -> str:
    """Seed 001 Table 2 layout (simulation and the seed's figures)."""
    t, s = rep["table2"], rep["seed001_table2"]
    out = [f"{'':22s}{'Roll':>9s}{'Pitch':>9s}{'Yaw':>9s}"]
    out.append(f"{'Error mean [deg]':22s}" + "".join(f"{t[k]['mean_deg']:9.4f}" for k in ("roll", "pitch", "yaw")))
    out.append(f"{'Error std [deg]':22s}" + "".join(f"{t[k]['std_deg']:9.4f}" for k in ("roll", "pitch", "yaw")))
    out.append(f"{'seed 001 mean [deg]':22s}" + "".join(f"{s[k]['mean_deg']:9.4f}" for k in ("roll", "pitch", "yaw")))
    out.append(f"{'seed 001 std [deg]':22s}" + "".join(f"{s[k]['std_deg']:9.4f}" for k in ("roll", "pitch", "yaw")))
    a = rep["agl"]
    out.append(f"AGL error mean {a['mean_error_m']:.2f} m, std {a['std_error_m']:.2f} m "
               f"(median |rel| {100 * a['median_rel_error']:.1f} %); {rep['n_pairs']} frame pairs")
    return "\n".join(out)


def write_forward_camera_dataset(out: str | Path, seed: int = 0, duration_s: float = 300.0, fps: float = 5.0,
                                 image_px: int = 240) -> int:
    """Render the forward camera's frames at `fps` (Hz) over a `duration_s` flight into out/frames with
    frames.csv (image,t_gps), camera.json, gnss_velocity.csv (NED m/s), truth_trajectory.csv and truth.json
    (with the ground's ellipsoidal height `h_ground`); returns the number of frames."""
    sim = make_forward_camera_sim(duration_s=duration_s, image_px=image_px, seed=seed)
    times = np.arange(sim.truth.t[0], sim.truth.t[-1], 1.0 / fps)
    rng = np.random.default_rng(seed)
    with staged_dir(out) as d:
        d = Path(d)
        (d / "frames").mkdir()
        rows = []
        for k, t in enumerate(tqdm(times, desc="frames", unit="frame")):
            name = f"frame_{k:05d}.png"
            cv2.imwrite(str(d / "frames" / name), np.rint(sim.frame(t, 0.005, rng) * 255).astype(np.uint8))
            rows.append(f"{name},{t:.4f}")
        (d / "frames.csv").write_text("image,t_gps\n" + "\n".join(rows) + "\n")
        tv, v = gnss_velocity(sim.truth, seed=seed + 1)
        np.savetxt(d / "gnss_velocity.csv", np.column_stack([tv, v]), delimiter=",", fmt="%.4f",
                   header="t_gps,vn,ve,vd", comments="")
        tr = sim.truth
        np.savetxt(d / "truth_trajectory.csv", np.column_stack([tr.t, tr.lat, tr.lon, tr.h, tr.v_ned, tr.rph]),
                   delimiter=",", fmt="%.9f", header="t_gps,lat,lon,h,vn,ve,vd,roll,pitch,heading", comments="")
        write_camera(d / "camera.json", sim.camera)
        (d / "truth.json").write_text(json.dumps({"camera": sim.camera.as_dict(), "image_size":
                                                  list(sim.camera.image_size),
                                                  "R_cam_to_body": sim.R_cam_to_body.tolist(), "seed": seed,
                                                  "h_ground": float(sim.enu.h0)},
                                                 indent=1))
    return len(times)
