"""A complete synthetic calibration campaign like seed 003, from one consistent truth.

Truth: a fixed-wing flight (`dgcal.sim.trajectory.simulate_true_trajectory`: take-off, orbit climbs, strips in opposite
headings at 300 m and 600 m above ground) -> its IMU data (`dgcal.sim.imu.simulate_imu`, ADIS16488 grade) ->
GNSS antenna positions (cm-level, PPK-like; or RINEX pseudoranges with `gnss_mode="tc"`) -> camera
events (`camera_events`, the exposure happening `delay_s` after the event) -> true camera poses at the
exposure times (trajectory at t_event + delay, lever arm, boresight) -> image measurements of ground
control, check and tie points through the true fraser7 camera (noisy, no rendering) -> plus the
measurements of a rotating coded-target plate photographed by the same camera (`dgcal.sim.camera_field`).

`dgcal simulate campaign --out DIR --seed N` writes what a user has after such a campaign:

    campaign.toml            the campaign file of `dgcal run`
    field/field.csv          target plate coordinates (plate frame, m); field/measurements.csv (px)
    flight/gcp.csv           control (role control) and check (role check) points, map CRS
    flight/measurements.csv  image measurements of ground and tie points (px)
    flight/measurements_gcp.csv   the ground-point measurements only
    flight/events.csv        camera events (GPS week, seconds of week)
    flight/imu.txt           IMU increments (KF-GINS text, body FRD)
    flight/gnss.csv          antenna positions (gnss.csv of `dgcal pos --mode spp`, cm-level), LC input
    flight/rover.rnx, base.rnx, nav.rnx   (gnss_mode "carrier", the default) rover and base RINEX with
                             dual-frequency code and carrier phase (`dgcal.sim.gnss.simulate_rover_base`)
    flight/imu_model.toml    (carrier) the IMU's error model: the preset with an orthogonal triad
    flight/rover.obs, nav.rnx     (gnss_mode "tc") simulated RINEX pseudoranges and navigation
    truth.json, truth/*      the true camera, mounting, delay, trajectory, EOPs

The campaign file's POS step is TC with carrier phase from the rover + base RINEX ("carrier"); "lc" makes it
LC from gnss.csv (written in every mode). Code-only TC ("tc") gives metre-level positions and hence dm-level
lever arms: the lever-arm (3 cm) and delay (2 ms) accuracy of a calibration needs carrier phase.
"""
from __future__ import annotations

import json
import math
import shutil
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.calib.camera.files import camera_json_dict
from dgcal.calib.camera.models import Fraser7
from dgcal.fields.constants import OMEGA_IE_E
from dgcal.fields.crs import LocalENU, MapGrid, ecef_to_geodetic
from dgcal.fields.errors import InputError
from dgcal.fields.frames import R_CAM_TO_BODY_NADIR, R_ecef_to_enu, R_enu_to_grid, opk_from_R_cam_to_map
from dgcal.fields.io.csv_tables import atomic_write, staged_dir, write_table
from dgcal.fields.processes import fork_map
from dgcal.fields.io.formats import (EOP, Measurements, Points, week_sow, write_eop, write_events, write_measurements,
                                     write_points, write_trajectory)
from dgcal.fields.targets.plate import TargetField, write_field
from dgcal.pos.gnss.carrier import write_rinex_carrier
from dgcal.pos.gnss.rinex import write_rinex_obs
from dgcal.pos.gnss.spp import GNSS_CSV_COLUMNS
from dgcal.pos.ins.imu_data import write_kf_gins
from dgcal.sim.camera_field import plan_shots, truth_projections
from dgcal.sim.gnss import DEFAULT_NAV, DEFAULT_T0_GPS, CarrierErrorModel, simulate_gnss, simulate_rover_base
from dgcal.sim.imu import simulate_imu
from dgcal.sim.trajectory import (FlightProfile, SmoothSteps, assemble_trajectory, camera_events,
                                  simulate_true_trajectory)


DEFAULT_CRS = "EPSG:32651"           # UTM 51N; the site lies 2.4 deg west of its central meridian (123 E)
SITE = (23.70, 120.60, 40.0)         # lat, lon (deg), ellipsoidal ground height (m): western Taiwan
LEVER_ARM_M = (0.12, -0.06, 0.18)    # IMU -> camera, body FRD (m), of the order of seed Table 1
BORESIGHT_DEG = (0.9, -0.6, 1.4)     # small rotations (x, y, z, deg) applied to the nominal mounting
LEVER_ARM_GNSS_M = (0.05, 0.0, -0.35)  # IMU -> GNSS antenna, body FRD (m), surveyed
BASE_OFFSET_ENU_M = (900.0, -600.0, 0.0)  # GNSS base station from the site centre, on the ground (m)


def campaign_camera() -> Fraser7:
    """A 20 mm lens on a 6000 x 4000 full-frame sensor (6 um pixels): f = 3333 px, mild barrel distortion."""
    w, h = 6000, 4000
    return Fraser7((w, h), [20.0 / 0.006, (w - 1) / 2 + 11.0, (h - 1) / 2 - 7.0,
                            -0.045, 0.018, 0.0, 3e-5, -2e-5, 0.25, 0.05])


def boresight_matrix(deg=BORESIGHT_DEG) -> np.ndarray:
    """R_cam_to_body: the nominal down-looking, image-top-forward mounting turned by small angles (deg)."""
    return Rotation.from_euler("xyz", deg, degrees=True).as_matrix() @ R_CAM_TO_BODY_NADIR


def terrain_up(e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Terrain height above the site's ground height (m) at local east/north (m): rolling, +-15 m."""
    return 9.0 * np.sin(e / 310.0) * np.cos(n / 420.0) + 5.0 * np.sin((e - 2 * n) / 190.0) + 0.004 * n


class _SpeedProfile:
    """A `dgcal.sim.trajectory.FlightProfile` whose airspeed changes smoothly: V(t) = speed + sum of smooth steps.

    Only `controls` and `attitude` depend on the speed; they are redefined here with V(t) and its rates
    (the flight-path pitch uses V(t)), everything else (positions by quadrature, specific force, angular
    rate, `TrueTrajectory.at`) follows from them exactly.
    """

    @staticmethod
    def make(base, steps):
        class Profile(FlightProfile):
            def controls(self, t):
                tau = np.asarray(t, float) - self.t0
                psi_i, r, rdot, _ = self.turn.evaluate(tau)
                up_i, vup, vupdot, vupddot = self.climb.evaluate(tau)
                _, dv, dvdot, dvddot = steps.evaluate(tau)
                V, Vd, Vdd = self.speed + dv, dvdot, dvddot
                psi = self.heading0 + psi_i
                c, s = np.cos(psi), np.sin(psi)
                v_l = np.stack([V * c, V * s, -vup], -1)
                a_l = np.stack([Vd * c - V * r * s, Vd * s + V * r * c, -vupdot], -1)
                j_l = np.stack([Vdd * c - 2 * Vd * r * s - V * rdot * s - V * r * r * c,
                                Vdd * s + 2 * Vd * r * c + V * rdot * c - V * r * r * s, -vupddot], -1)
                return dict(psi=psi, r=r, rdot=rdot, height=up_i, vup=vup, vupdot=vupdot, v_l=v_l, a_l=a_l,
                            j_l=j_l, V=V, Vdot=Vd)

            def attitude(self, c):
                # FlightProfile.attitude with V(t): evaluate it on a copy whose speed is the local V, after
                # correcting the pitch-rate term for dV/dt (thdot = (V vupdot - vup Vdot) / (V^2 + vup^2))
                V, Vd = c["V"], c["Vdot"]
                c2 = dict(c, vupdot=c["vupdot"] - c["vup"] * Vd / V)
                saved = self.speed
                try:
                    self.speed = V
                    R_body_to_l, w = FlightProfile.attitude(self, c2)
                finally:
                    self.speed = saved
                return R_body_to_l, w

        return Profile(base.lat0, base.lon0, base.h0, base.t0, base.p0_l, base.speed, base.heading0, base.turn,
                       base.climb, base.aoa_rad, base.crab_rad)


def _flight_with_speeds(speeds, **kw):
    """`dgcal.sim.trajectory.simulate_true_trajectory` with airspeed speeds[i] on the strips of height i (changed
    smoothly during the orbit climb before them); heights fly at different ground speeds, which separates the
    exposure delay from the along-track lever arm."""
    base = simulate_true_trajectory(speed=float(speeds[0]), **kw)
    climbs = [s for s in base.segments if s.kind == "climb"]
    a, T, d = [], [], []
    for i in range(1, len(speeds)):
        if i < len(climbs):
            a.append(climbs[i].t_start - base.profile.t0 + 5.0)
            T.append(min(20.0, climbs[i].t_end - climbs[i].t_start - 10.0))
            d.append(float(speeds[i]) - float(speeds[i - 1]))
    if not a:
        return base
    prof = _SpeedProfile.make(base.profile, SmoothSteps(a, T, d))
    t = base.t
    inc = prof.horizontal_increment(t[:-1], t[1:])
    p_l = np.zeros((len(t), 3))
    p_l[:, :2] = prof.p0_l[:2] + np.vstack([np.zeros(2), np.cumsum(inc, axis=0)])
    p_l[:, 2] = prof.p0_l[2] - prof.climb.evaluate(t - prof.t0)[0]
    traj = assemble_trajectory(prof, t, p_l, with_increments=True, rate_hz=base.rate_hz)
    traj.segments = base.segments
    return traj


def _camera_field(out: Path, camera, rng, n_images: int, noise_px: float) -> dict:
    """Target-plate measurements (no rendering): shots of dgcal.sim.camera_field, projected, noisy."""
    tf = TargetField()
    shots = plan_shots(n_images, camera, tf, rng)
    rows_img, rows_id, uv_all = [], [], []
    for shot in shots:
        ids, uv, _ = truth_projections(camera, tf, shot, [])
        rows_img += [shot.image] * len(ids)
        rows_id += list(ids)
        uv_all.append(uv)
    uv = np.vstack(uv_all)
    out.mkdir(parents=True, exist_ok=True)
    write_field(out / "field.csv", tf)
    write_measurements(out / "measurements.csv",
                       Measurements(np.array(rows_img, dtype=object), np.array(rows_id, dtype=object),
                                    uv + rng.normal(0, noise_px, uv.shape), np.full(uv.shape, noise_px)))
    write_table(out / "truth_measurements.csv", ["image", "id", "x", "y"],
                ([a, b, *p] for a, b, p in zip(rows_img, rows_id, uv)), fmt="%.5f")
    return {"n_images": len(shots), "n_observations": int(len(uv)), "noise_px": noise_px}


def _observe(camera, C_ecef, R_cam_to_ecef, names, ids, X_ecef, margin_px: float = 10.0):
    """Noise-free projections of points X_ecef into every image: (image, id, uv) rows."""
    w, h = camera.image_size
    rows_img, rows_id, uv_all = [], [], []
    for k in range(len(names)):
        Xc = (X_ecef - C_ecef[k]) @ R_cam_to_ecef[k]
        ok = Xc[:, 2] > 1.0
        uv = np.full((len(X_ecef), 2), np.nan)
        uv[ok] = camera.project(Xc[ok])
        ok &= (uv[:, 0] > margin_px) & (uv[:, 0] < w - 1 - margin_px) & (uv[:, 1] > margin_px) & \
              (uv[:, 1] < h - 1 - margin_px)
        j = np.nonzero(ok)[0]
        rows_img += [names[k]] * len(j)
        rows_id += list(ids[j])
        uv_all.append(uv[j])
    return np.array(rows_img, dtype=object), np.array(rows_id, dtype=object), np.vstack(uv_all)


def _gnss_rows(t, p_ant, v_ant, sig_enu, sig_v):
    """Rows of gnss.csv (the columns of `dgcal pos --mode spp`) for antenna positions with ENU sigmas."""
    llh = ecef_to_geodetic(p_ant)
    R_ecef_to_local_enu = R_ecef_to_enu(llh[:, 0], llh[:, 1])                  # (N,3,3)
    # ENU diag -> ECEF
    cov = np.einsum("nji,j,njk->nik", R_ecef_to_local_enu, np.asarray(sig_enu) ** 2, R_ecef_to_local_enu)
    s_ecef = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    week, sow = week_sow(t)
    nan = float("nan")
    rows = []
    for i in range(len(t)):
        rows.append([int(week[i]), float(sow[i]), *p_ant[i], *v_ant[i], *s_ecef[i], sig_v, sig_v, sig_v, *llh[i],
                     *sig_enu, nan, nan, nan, nan, 12, 1.8, 1.5, 0.9, 1.2, 1.0, ""])
    return rows


def simulate_campaign(out: str | Path, seed: int = 0, *, crs: str = DEFAULT_CRS, site=SITE,
                      heights_agl=(300.0, 600.0), n_strips: int = 4, strip_length_m: float = 1100.0,
                      strip_spacing_m: float = 220.0, strip_heading_deg: float = 35.0, speeds_mps=(20.0, 34.0),
                      event_distance_m: float = 70.0,
                      delay_s: float = -0.14, lever_arm_m=LEVER_ARM_M, boresight_deg=BORESIGHT_DEG,
                      lever_arm_gnss_m=LEVER_ARM_GNSS_M, imu_grade: str = "adis16488", imu_rate_hz: float = 100.0,
                      gnss_mode: str = "carrier", gnss_rate_hz: float = 1.0, gnss_sigma_enu=(0.02, 0.02, 0.04),
                      gnss_sigma_v: float = 0.03, sigma_pr: float = 0.5, noise_px: float = 0.3,
                      n_control: int = 12, n_check: int = 12, gcp_sigma=(0.01, 0.01, 0.02), n_tie: int = 1500,
                      field_images: int = 36, field_noise_px: float = 0.15, pos_extra: dict | None = None) -> dict:
    """Write a campaign into `out` (see the module doc); returns the truth dictionary (also truth.json)."""

    if gnss_mode not in ("lc", "tc", "carrier"):
        raise InputError(f"unknown GNSS mode {gnss_mode!r} (carrier, lc or tc)", field="gnss_mode")
    rng = np.random.default_rng(seed)
    lat0, lon0, h0 = site
    grid = MapGrid(crs)
    enu = LocalENU(lat0, lon0, h0)
    camera = campaign_camera()
    R_cam_to_body = boresight_matrix(boresight_deg)
    lever = np.asarray(lever_arm_m, float)
    lever_g = np.asarray(lever_arm_gnss_m, float)
    week0, sow0 = (int(v) for v in week_sow(DEFAULT_T0_GPS))  # inside the bundled navigation file (tc mode)

    # 1. the true flight, its IMU, the events and the true camera poses at the exposures
    traj = _flight_with_speeds(speeds_mps, kind="fixed-wing", lat0=lat0, lon0=lon0, h_ground=h0,
                               heights_agl=tuple(heights_agl), n_strips=n_strips, strip_length_m=strip_length_m,
                               strip_spacing_m=strip_spacing_m, strip_heading_deg=strip_heading_deg,
                               rate_hz=imu_rate_hz, gps_week=week0, gps_sow=float(sow0))
    # no triad misalignment: the IMU axes define the body frame, so the true boresight is well defined (a real
    # triad's non-orthogonality ends up in the calibrated boresight)
    imu, imu_err = simulate_imu(traj, imu_grade, seed=seed + 1, misalignment=False)
    events = camera_events(traj, distance_m=event_distance_m, delay_s=delay_s)
    at = traj.at(events.t + delay_s)
    C_ecef = at.p_ecef + np.einsum("nij,j->ni", at.R_body_to_ecef, lever)
    R_cam_to_ecef = at.R_body_to_ecef @ R_cam_to_body
    names = np.asarray(events.image, dtype=object)

    # 2. ground points on the terrain and their image measurements; the true EOPs
    gp = _ground_points(rng, enu, enu.from_ecef(C_ecef), heights_agl, n_strips, strip_length_m, strip_spacing_m,
                        strip_heading_deg, n_control, n_check, n_tie)
    ims = _image_measurements(rng, camera, C_ecef, R_cam_to_ecef, names, gp, noise_px)
    gp_map = grid.from_ecef(gp.gp_ecef)
    sig = np.tile(np.asarray(gcp_sigma, float), (len(gp.gp_ids), 1))
    gp_map_obs = gp_map + rng.normal(0, 1.0, gp_map.shape) * sig  # surveyed coordinates carry their sigmas
    C_map, opk = _true_eops(grid, C_ecef, R_cam_to_ecef)

    # 3. GNSS antenna: PPK-like positions (lc) or pseudoranges (tc)
    t_gnss, p_ant, v_ant = _antenna(traj, lever_g, gnss_rate_hz)

    with staged_dir(Path(out)) as tmp:
        fl = tmp / "flight"
        fl.mkdir()
        tr = tmp / "truth"
        tr.mkdir()
        # the draws from `rng` in their order; the big files, which draw nothing, written side by side after them
        field_info = _camera_field(tmp / "field", camera, rng, field_images, field_noise_px)
        write_points(fl / "gcp.csv", Points(gp.gp_ids, gp_map_obs, sig, gp.role), with_role=True)
        write_events(fl / "events.csv", events)
        _write_gnss_lc(fl / "gnss.csv", rng, grid, t_gnss, p_ant, v_ant, gnss_sigma_enu, gnss_sigma_v)
        writes = [partial(ims.write, fl, noise_px), partial(write_kf_gins, fl / "imu.txt", imu)]
        base_ecef = None
        if gnss_mode == "tc":
            obs = simulate_gnss(t_gnss, p_ant, v_ant, None, seed=seed + 2, sigma_pr=sigma_pr, systems=("G", "E"),
                                prepare=False)
            writes.append(partial(write_rinex_obs, fl / "rover.obs", obs))
            shutil.copyfile(DEFAULT_NAV, fl / "nav.rnx")
        elif gnss_mode == "carrier":
            base_ecef = enu.to_ecef(np.asarray(BASE_OFFSET_ENU_M, float)[None])[0]
            cs = simulate_rover_base(t_gnss, p_ant, v_ant, base_ecef, None, seed=seed + 2, systems=("G", "E"),
                                     n_freq=2, n_random_slips=4)
            writes += [partial(write_rinex_carrier, fl / "rover.rnx", cs.rover, marker="ROVER"),
                       partial(write_rinex_carrier, fl / "base.rnx", cs.base, marker="BASE")]
            shutil.copyfile(DEFAULT_NAV, fl / "nav.rnx")
        writes.append(partial(write_trajectory, tr / "trajectory.csv",
                              traj.as_trajectory(max(1, int(round(imu_rate_hz / 10))))))
        fork_map(writes)
        write_eop(tr / "eop.csv", EOP(names, C_map, opk))
        write_points(tr / "gcp.csv", Points(gp.gp_ids, gp_map, sig, gp.role), with_role=True)
        with atomic_write(tr / "camera.json") as fh:
            json.dump(camera_json_dict(camera), fh, indent=1)
        truth = {
            "simulator": "campaign", "seed": int(seed), "crs": crs, "site": {"lat": lat0, "lon": lon0, "h_ground": h0},
            "convergence_deg": float(grid.convergence_deg(lat0, lon0)),
            "lever_arm_m": lever.tolist(), "boresight_R_cam_to_body": R_cam_to_body.tolist(),
            "boresight_deg_about_nominal": list(boresight_deg), "delay_s": float(delay_s),
            "lever_arm_gnss_m": lever_g.tolist(),
            "camera": camera_json_dict(camera),
            "flight": {"heights_agl_m": list(heights_agl), "n_strips": n_strips, "strip_length_m": strip_length_m,
                       "strip_spacing_m": strip_spacing_m, "strip_heading_deg": strip_heading_deg,
                       "airspeed_mps": list(speeds_mps), "duration_s": float(traj.t[-1] - traj.t[0]),
                       "n_images": int(len(names)), "event_distance_m": event_distance_m,
                       "gsd_m": {f"{H:g}": float(H / camera["f"]) for H in heights_agl}},
            "imu": imu_err.as_dict() | {"rate_hz": imu_rate_hz},
            "gnss": _gnss_truth(gnss_mode, gnss_rate_hz, gnss_sigma_enu, gnss_sigma_v, sigma_pr, base_ecef),
            "image_noise_px": noise_px, "gcp_sigma_m": list(gcp_sigma),
            "n_control": n_control, "n_check": n_check, "n_tie_points": int(len(np.unique(ims.tie_id))),
            "n_observations": {"ground": int(len(ims.gp_image)), "tie": int(len(ims.tie_image))},
            "camera_field": field_info,
            "files": {"eop": "truth/eop.csv (true EOPs at the exposures, map CRS)",
                      "trajectory": "truth/trajectory.csv (true IMU trajectory, 10 Hz)",
                      "gcp": "truth/gcp.csv (error-free ground points)", "camera": "truth/camera.json"},
        }
        with atomic_write(tmp / "truth.json") as fh:
            json.dump(truth, fh, indent=1, default=float)
        grade_file = None
        if gnss_mode == "carrier":
            # the simulated triad is orthogonal (misalignment=False above): say so to the smoother, whose preset
            # would otherwise carry 0.02 deg misalignments as turn noise (conservative attitude sigmas)
            grade_file = "flight/imu_model.toml"
            with atomic_write(tmp / grade_file) as fh:
                fh.write(f'name = "{imu_grade} (orthogonal triad)"\nbase = "{imu_grade}"\n'
                         "[gyro]\nmisalign_deg = 0.0\n[accel]\nmisalign_deg = 0.0\n")
        _write_toml(tmp / "campaign.toml", crs, camera.image_size, gnss_mode, grade_file or imu_grade, lever_g,
                    pos_extra, base_ecef)
    return truth


def _antenna(traj, lever_g: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GPS times (s), true antenna positions (m) and velocities (m/s) in ECEF at `rate_hz` over the flight."""
    t_gnss = np.arange(math.ceil(traj.t[0]), traj.t[-1] + 1e-9, 1.0 / rate_hz)
    g_at = traj.at(t_gnss)
    p_ant = g_at.p_ecef + np.einsum("nij,j->ni", g_at.R_body_to_ecef, lever_g)
    w_eb_b = g_at.omega_ib_b - np.einsum("nji,j->ni", g_at.R_body_to_ecef, OMEGA_IE_E)
    v_ant = g_at.v_ecef + np.einsum("nij,nj->ni", g_at.R_body_to_ecef, np.cross(w_eb_b, lever_g))
    return t_gnss, p_ant, v_ant


def _gnss_truth(mode: str, rate_hz: float, sigma_enu, sigma_v: float, sigma_pr: float, base_ecef=None) -> dict:
    """The GNSS part of truth.json."""
    lc = {"rate_hz": rate_hz, "sigma_enu_m": list(sigma_enu), "sigma_v_mps": sigma_v}
    if mode == "lc":
        return {"mode": "lc", **lc}
    if mode == "carrier":
        return {"mode": "carrier", "rate_hz": rate_hz, "systems": ["G", "E"], "frequencies": 2,
                "base_ecef_m": np.asarray(base_ecef).tolist(), "errors": CarrierErrorModel().as_dict(),
                "gnss_csv": lc, "files": {"rover": "flight/rover.rnx", "base": "flight/base.rnx",
                                          "nav": "flight/nav.rnx", "lc": "flight/gnss.csv"}}
    return {"mode": "tc", "rate_hz": rate_hz, "sigma_pr_m": sigma_pr, "systems": ["G", "E"], "gnss_csv": lc}


@dataclass
class _Ground:
    """Control/check points (ids, roles) and tie points (ids) of the campaign, true ECEF coordinates (m)."""

    gp_ids: np.ndarray
    role: np.ndarray
    gp_ecef: np.ndarray
    tie_ids: np.ndarray
    tie_ecef: np.ndarray


def _ground_points(rng, enu: LocalENU, C_enu: np.ndarray, heights_agl, n_strips: int, strip_length_m: float,
                   strip_spacing_m: float, strip_heading_deg: float, n_control: int, n_check: int,
                   n_tie: int) -> _Ground:
    """Ground points on the terrain: control and check points on a jittered grid over the low block, tie points
    everywhere (C_enu: the projection centres in `enu`, m)."""
    low = C_enu[:, 2] < (heights_agl[0] + (heights_agl[1] if len(heights_agl) > 1 else 2 * heights_agl[0])) / 2
    lo, hi = C_enu[low, :2].min(0), C_enu[low, :2].max(0)
    ctr, half = (lo + hi) / 2, (hi - lo) / 2
    a = math.radians(strip_heading_deg)
    u_along = np.array([math.sin(a), math.cos(a)])     # (E, N) along the strips
    u_across = np.array([math.cos(a), -math.sin(a)])
    n_gp = n_control + n_check
    na = int(math.ceil(math.sqrt(n_gp * 1.6)))
    nc = int(math.ceil(n_gp / na))
    span_al = 0.38 * strip_length_m
    span_ac = 0.40 * strip_spacing_m * (n_strips - 1) + 60.0
    ga, gc = np.meshgrid(np.linspace(-span_al, span_al, na), np.linspace(-span_ac, span_ac, nc))
    en = (ga.ravel()[:, None] * u_along + gc.ravel()[:, None] * u_across)[:n_gp]
    en += ctr + rng.normal(0, 15.0, en.shape)
    gp_enu = np.column_stack([en, terrain_up(en[:, 0], en[:, 1])])
    order = rng.permutation(n_gp)
    role = np.empty(n_gp, dtype=object)
    role[order[:n_control]] = "control"
    role[order[n_control:]] = "check"
    gp_ids = np.array([("GCP" if role[i] == "control" else "CHK") + f"{i + 1:02d}" for i in range(n_gp)],
                      dtype=object)
    te = ctr + rng.uniform(-1, 1, (n_tie, 2)) * (half + 150.0)
    tie_enu = np.column_stack([te, terrain_up(te[:, 0], te[:, 1])])
    tie_ids = np.array([f"T{i + 1:05d}" for i in range(n_tie)], dtype=object)
    return _Ground(gp_ids, role, enu.to_ecef(gp_enu), tie_ids, enu.to_ecef(tie_enu))


@dataclass
class _ImageMeasurements:
    """Noisy image measurements (px) of the ground points and of the tie points seen at least twice."""

    gp_image: np.ndarray
    gp_id: np.ndarray
    gp_xy: np.ndarray
    tie_image: np.ndarray
    tie_id: np.ndarray
    tie_xy: np.ndarray

    def write(self, folder: Path, noise_px: float) -> None:
        """measurements_gcp.csv (ground points) and measurements.csv (all) with sigmas `noise_px` (px)."""
        n_g, n_t = len(self.gp_image), len(self.tie_image)
        write_measurements(folder / "measurements_gcp.csv",
                           Measurements(self.gp_image, self.gp_id, self.gp_xy, np.full((n_g, 2), noise_px)))
        write_measurements(folder / "measurements.csv",
                           Measurements(np.concatenate([self.gp_image, self.tie_image]),
                                        np.concatenate([self.gp_id, self.tie_id]),
                                        np.concatenate([self.gp_xy, self.tie_xy]), np.full((n_g + n_t, 2), noise_px)))


def _image_measurements(rng, camera, C_ecef, R_cam_to_ecef, names, gp: _Ground, noise_px: float) -> _ImageMeasurements:
    """The ground and tie points through the true camera at the true poses, with pixel noise `noise_px`."""
    gi, gid, guv = _observe(camera, C_ecef, R_cam_to_ecef, names, gp.gp_ids, gp.gp_ecef)
    ti, tid, tuv = _observe(camera, C_ecef, R_cam_to_ecef, names, gp.tie_ids, gp.tie_ecef)
    _, inverse, cnt = np.unique(tid, return_inverse=True, return_counts=True)
    keep = cnt[inverse] >= 2      # tie points seen at least twice
    ti, tid, tuv = ti[keep], tid[keep], tuv[keep]
    g_noisy = guv + rng.normal(0, noise_px, guv.shape)
    t_noisy = tuv + rng.normal(0, noise_px, tuv.shape)
    return _ImageMeasurements(gi, gid, g_noisy, ti, tid, t_noisy)


def _true_eops(grid: MapGrid, C_ecef: np.ndarray, R_cam_to_ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map projection centres (N,3) (m) and PATB omega/phi/kappa (N,3) (deg) straight from ECEF poses: camera frame
    -> grid axes (ENU at the centre turned by the meridian convergence), independently of dgcal.fields.world."""
    C_map = grid.from_ecef(C_ecef)
    llh_c = grid.to_geodetic(C_map)
    gamma = grid.convergence_deg(llh_c[:, 0], llh_c[:, 1])
    R_cam_to_grid = (R_enu_to_grid(gamma[:, None]).reshape(-1, 3, 3) @ R_ecef_to_enu(llh_c[:, 0], llh_c[:, 1])
                     @ R_cam_to_ecef)
    return C_map, opk_from_R_cam_to_map(R_cam_to_grid)


def _write_gnss_lc(path: Path, rng, grid: MapGrid, t_gnss, p_ant, v_ant, gnss_sigma_enu, gnss_sigma_v: float) -> None:
    """gnss.csv of PPK-like antenna positions and velocities, ENU noise `gnss_sigma_enu` (m), `gnss_sigma_v` (m/s)."""
    sg = np.asarray(gnss_sigma_enu, float)
    llh = grid.to_geodetic(grid.from_ecef(p_ant))
    R_ecef_to_local_enu = R_ecef_to_enu(llh[:, 0], llh[:, 1])
    noise_enu = rng.normal(0, 1, p_ant.shape) * sg
    p_obs = p_ant + np.einsum("nji,nj->ni", R_ecef_to_local_enu, noise_enu)
    v_obs = v_ant + rng.normal(0, gnss_sigma_v, v_ant.shape)
    write_table(path, GNSS_CSV_COLUMNS, _gnss_rows(t_gnss, p_obs, v_obs, sg, gnss_sigma_v), fmt="%.12g")


def _write_toml(path: Path, crs: str, image_size, gnss_mode: str, imu_grade: str, lever_g, pos_extra,
                base_ecef=None) -> None:
    w, h = image_size
    if gnss_mode == "lc":
        gn = 'gnss = "flight/gnss.csv"'
    elif gnss_mode == "tc":
        gn = 'rinex_obs = "flight/rover.obs"\nrinex_nav = "flight/nav.rnx"'
    else:
        b = ", ".join(f"{v:.4f}" for v in base_ecef)
        gn = ('rinex_obs = "flight/rover.rnx"       # rover: dual-frequency code and carrier phase\n'
              'rinex_nav = "flight/nav.rnx"\n'
              'rinex_base = "flight/base.rnx"      # base station: carrier phase against it (TC)\n'
              f'base_position = [{b}]   # base antenna, ECEF m\nfrequencies = 2\n'
              '# gnss = "flight/gnss.csv"          # with mode = "lc": LC from PPK-like positions instead')
    extra = "".join(f'\nset = {json.dumps([f"{k}={v}" for k, v in pos_extra.items()])}' if pos_extra else "")
    pos_mode = "lc" if gnss_mode == "lc" else "tc"
    text = f"""# dgcal calibration campaign (simulated by `dgcal simulate campaign`); paths relative to this file
name = "simulated seed-003 campaign"
crs = "{crs}"
truth = "truth.json"          # simulation only: the report compares the estimates with the truth

[camera]                      # camera intrinsics from the rotating target plate
field = "field/field.csv"
measurements = "field/measurements.csv"
image_size = [{w}, {h}]
model = "fraser7"

[triangulation]               # aerial triangulation over the control field
gcp = "flight/gcp.csv"
measurements = "flight/measurements.csv"

[pos]                         # GNSS/INS smoothing
mode = "{pos_mode}"
imu = "flight/imu.txt"
events = "flight/events.csv"
{gn}
imu_grade = "{imu_grade}"
lever_arm_gnss = [{", ".join(f"{v:g}" for v in lever_g)}]{extra}

[mount]                       # system calibration: the method to use and the ones to compare
method = "proposed"
compare = ["traditional", "iso"]
# iso adjusts the triangulation's image measurements (tie and ground points) with the POS as observations
# pos_common_fraction: the share of the POS error common to the flight in the sigmas (default 1, as dgcal mount's)

[check]                       # DG accuracy on the check points (here: the calibration flight itself)
gcp = "flight/gcp.csv"
measurements = "flight/measurements_gcp.csv"
events = "flight/events.csv"
"""
    with atomic_write(path) as fh:
        fh.write(text)
