"""Simulate a mounting-calibration flight (and a mapping flight) with known lever arm, boresight and exposure delay.

A light, self-contained simulator for the mounting tests: straight strips in opposite headings at several
heights with wind (so ground speed and crab differ between headings), attitude wobble (angular rates),
smooth POS errors (smoother-like, Gaussian correlation, kernel 0.3 s), bundle-like EOP noise, a Fraser camera,
ground points (control and check) and their image measurements.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.calib.camera.files import write_camera_json
from dgcal.calib.camera.models import Fraser7
from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.crs import LocalENU, MapGrid
from dgcal.fields.frames import R_CAM_TO_BODY_NADIR, R_ENU_TO_NED, R_body_to_ned_from_rph
from dgcal.fields.io.csv_tables import atomic_write, staged_dir
from dgcal.fields.io.formats import (EOP, Events, Measurements, Points, Trajectory, write_eop, write_events,
                                     write_measurements, write_points, write_trajectory)
from dgcal.fields.pose import Poses, so3_exp, so3_log
from dgcal.fields.pose import transpose as T
from dgcal.fields.world import World




def default_boresight() -> np.ndarray:
    """A nominal down-looking camera (image top forward) misaligned by about a degree (like seed Table 1)."""
    return Rotation.from_euler("xyz", [1.3, -0.7, 0.4], degrees=True).as_matrix() @ R_CAM_TO_BODY_NADIR


def mounting_flight_camera() -> Fraser7:
    """A 20 mm lens on a 5616 x 3744 full-frame sensor (6.4 um pixels), like seed 003's EOS 5D Mark II."""
    return Fraser7((5616, 3744), np.array([3125.0, 2815.0, 1868.0, -0.02, 0.01, 0, 1e-5, -1e-5, 0, 0]))


@dataclass
class FlightSim:
    """One simulated flight: truth and the noisy files' contents."""

    world: World
    traj: Trajectory              # noisy POS with sigmas
    traj_true: Trajectory
    events: Events                # recorded event times (t_exposure - delay)
    t_exposure: np.ndarray
    eop: EOP                      # noisy bundle EOPs with sigmas (map CRS)
    eop_true: EOP
    measurements: Measurements    # image measurements of the ground points (px)
    heights: np.ndarray           # flying height of each image above ground (m)


@dataclass
class MountingSim:
    """A calibration flight, a mapping flight, ground points, camera and the true mounting."""

    crs: str
    camera: Fraser7
    lever_arm_m: np.ndarray
    R_cam_to_body: np.ndarray
    delay_s: float
    ground: Points
    calibration: FlightSim
    mapping: FlightSim
    noise: dict = field(default_factory=dict)

    def truth(self) -> dict:
        return {"lever_arm_m": self.lever_arm_m.tolist(), "boresight_R_cam_to_body": self.R_cam_to_body.tolist(),
                "delay_s": self.delay_s, "crs": self.crs, "noise": self.noise}


def _smooth_noise(rng, n: int, dt: float, width_s: float, sigma: np.ndarray) -> np.ndarray:
    """Stationary smooth random sequences (n, k): white noise convolved with a Gaussian kernel of standard
    deviation `width_s`, scaled to standard deviations `sigma` (k,). Smooth like a smoother's errors at the
    sample rate, yet independent between photos a few kernel widths apart."""
    sigma = np.asarray(sigma, float)
    half = int(np.ceil(4 * width_s / dt))
    tk = np.arange(-half, half + 1) * dt
    g = np.exp(-0.5 * (tk / width_s) ** 2)
    g /= np.sqrt(np.sum(g**2))
    w = rng.normal(0, 1, (n + 2 * half, len(sigma)))
    out = np.column_stack([np.convolve(w[:, j], g, mode="valid") for j in range(len(sigma))])
    return out * sigma


def _strips(heights, n_strips, length_m, spacing_m, azimuth_deg):
    out = []
    for h in heights:
        for k in range(n_strips):
            az = azimuth_deg + (180.0 if k % 2 else 0.0)
            offset = (k - (n_strips - 1) / 2) * spacing_m * h / heights[0]
            out.append((h, az, offset, length_m))
    return out


def simulate_mounting_flight(rng, world: World, camera, lever_arm_m, R_cam_to_body, delay_s: float,
                             ground_world: np.ndarray, ground_ids, *, heights=(300.0, 600.0), n_strips: int = 4,
                             length_m: float = 1200.0, spacing_m: float = 180.0, azimuth_deg: float = 30.0,
                             airspeed: float = 30.0, wind_en=(4.0, 5.0), photo_interval_s: float = 1.5,
                             rate_hz: float = 20.0, pos_sigma=(0.05, 0.05, 0.08, 0.01, 0.01, 0.03),
                             eop_sigma=(0.03, 0.03, 0.04, 0.003, 0.003, 0.002), pixel_sigma: float = 0.5,
                             t0: float = 2200 * SECONDS_PER_WEEK + 300000.0, tau_s: float = 0.3,
                             pos_common_fraction: float = 0.0) -> FlightSim:
    """Simulate one flight of straight strips (alternating headings) in the world; see the module docstring."""
    wind = np.array([wind_en[0], wind_en[1], 0.0])
    t_all, p_all, v_all, R_body_to_world_all = [], [], [], []
    t_exp, strip_h = [], []
    t = t0
    for h, az, offset, length in _strips(list(heights), n_strips, length_m, spacing_m, azimuth_deg):
        a = np.radians(az)
        u = np.array([np.sin(a), np.cos(a), 0.0])
        n = np.array([np.cos(a), -np.sin(a), 0.0])
        crab = -np.arcsin(np.clip(wind @ n / airspeed, -1, 1))
        vg = airspeed * np.cos(crab) + wind @ u
        dur = length / vg
        ts = np.arange(-3.0, dur + 3.0, 1.0 / rate_hz)
        ph = rng.uniform(0, 2 * np.pi, 3)
        p = (offset * n)[None] + (-length / 2 + vg * ts)[:, None] * u[None]
        p[:, 2] = h
        v = np.tile(vg * u, (len(ts), 1))
        roll = 1.5 * np.sin(2 * np.pi * ts / 6.0 + ph[0])
        pitch = 2.0 + 1.0 * np.sin(2 * np.pi * ts / 9.0 + ph[1])
        heading = az + np.degrees(crab) + 0.5 * np.sin(2 * np.pi * ts / 13.0 + ph[2])
        # the world is level at the block: ENU
        R_body_to_world_strip = R_ENU_TO_NED.T @ R_body_to_ned_from_rph(roll, pitch, heading)
        t_all.append(t + ts)
        p_all.append(p)
        v_all.append(v)
        R_body_to_world_all.append(R_body_to_world_strip)
        te = np.arange(0.5, dur - 0.5, photo_interval_s)
        t_exp.append(t + te)
        strip_h.append(np.full(len(te), h))
        t += ts[-1] + 30.0  # the turn is not simulated: a gap in the trajectory
    t_s, p_world, v_world, R_body_to_world = (np.concatenate(x) for x in (t_all, p_all, v_all, R_body_to_world_all))
    t_exp, heights_img = np.concatenate(t_exp), np.concatenate(strip_h)

    # truth at exposure times, analytically interpolated on the fine samples (rate_hz) would add error:
    # evaluate the strip model directly by re-sampling at exposure times
    def at(tq):
        i = np.clip(np.searchsorted(t_s, tq) - 1, 0, len(t_s) - 2)
        s = (tq - t_s[i]) / (t_s[i + 1] - t_s[i])
        pq = p_world[i] + s[:, None] * (p_world[i + 1] - p_world[i])  # straight constant-velocity strips: linear exact
        step = so3_log(T(R_body_to_world[i]) @ R_body_to_world[i + 1])
        return pq, R_body_to_world[i] @ so3_exp(s[:, None] * step)

    r_imu_world_x, R_body_to_world_x = at(t_exp)
    C_world = r_imu_world_x + np.einsum("nij,j->ni", R_body_to_world_x, lever_arm_m)
    R_cam_to_world = R_body_to_world_x @ R_cam_to_body
    names = np.array([f"IMG_{k:04d}.JPG" for k in range(len(t_exp))], dtype=object)
    xyz, opk, _ = world.poses_to_eop(Poses.from_cam_to_world(R_cam_to_world, C_world))
    eop_true = EOP(names, xyz, opk)
    es = np.tile(np.asarray(eop_sigma, float), (len(names), 1))
    es *= (heights_img / heights[0])[:, None]  # bundle accuracy degrades with height
    # position noise in metres along grid E, N, Up (also right for a geographic CRS, whose X, Y are degrees)
    n_grid = rng.normal(0, 1, xyz.shape) * es[:, :3]
    xyz_noisy = world.to_map(C_world + np.einsum("nji,nj->ni", world.R_world_to_grid_at(C_world), n_grid))
    eop = EOP(names, xyz_noisy, opk + rng.normal(0, 1, opk.shape) * es[:, 3:], es)
    events = Events(names, t_exp - delay_s)

    lat, lon, hh, v_ned, rph = world.world_to_pos(p_world, v_world, R_body_to_world)
    traj_true = Trajectory(t_s, lat, lon, hh, v_ned, rph)
    # smoother-like errors: a part common to the whole flight (bias-driven tilt, GNSS biases: it does not
    # average down over the photos) and a smooth part correlated over ~tau_s, independent between photos
    f = float(pos_common_fraction)
    err = (np.sqrt(1 - f) * _smooth_noise(rng, len(t_s), 1.0 / rate_hz, tau_s, np.asarray(pos_sigma, float))
           + np.sqrt(f) * rng.normal(0, 1, 6) * np.asarray(pos_sigma, float))
    p_noisy = p_world + err[:, [1, 0, 2]]  # s_lat_m is north, s_lon_m east (the world is ENU, level at the block)
    lat_n, lon_n, h_n, _, _ = world.world_to_pos(p_noisy, v_world, R_body_to_world)
    traj = Trajectory(t_s, lat_n, lon_n, h_n, v_ned + rng.normal(0, 0.02, v_ned.shape), rph + err[:, 3:],
                      np.tile(np.asarray(pos_sigma, float), (len(t_s), 1)))

    # image measurements of ground points from the true poses
    rows_im, rows_id, uv_all = [], [], []
    for k in range(len(names)):
        X_c = (ground_world - C_world[k]) @ R_cam_to_world[k]
        ok = X_c[:, 2] > 1.0
        uv = np.full((len(ground_world), 2), np.nan)
        uv[ok] = camera.project(X_c[ok])
        w, hgt = camera.image_size
        ok &= (uv[:, 0] > 20) & (uv[:, 0] < w - 20) & (uv[:, 1] > 20) & (uv[:, 1] < hgt - 20)
        for j in np.nonzero(ok)[0]:
            rows_im.append(names[k])
            rows_id.append(ground_ids[j])
            uv_all.append(uv[j] + rng.normal(0, pixel_sigma, 2))
    uv_all = np.array(uv_all).reshape(-1, 2)
    meas = Measurements(np.array(rows_im, dtype=object), np.array(rows_id, dtype=object), uv_all,
                        np.full(uv_all.shape, pixel_sigma))
    return FlightSim(world, traj, traj_true, events, t_exp, eop, eop_true, meas, heights_img)


def simulate_mounting(seed: int = 0, *, lever_arm_m=(-0.30, 0.12, 0.20), R_cam_to_body=None, delay_s: float = -0.14,
                      crs: str = "EPSG:32651", lat0: float = 23.0, lon0: float = 120.3, h0: float = 30.0,
                      n_ground: int = 49, calibration: dict | None = None, mapping: dict | None = None) -> MountingSim:
    """A calibration flight (300 m and 600 m, opposite headings) and a mapping flight over the same ground points."""
    rng = np.random.default_rng(seed)
    grid = MapGrid(crs)
    world = World(grid, LocalENU(lat0, lon0, h0))
    camera = mounting_flight_camera()
    R_cam_to_body = default_boresight() if R_cam_to_body is None else np.asarray(R_cam_to_body, float)
    lever = np.asarray(lever_arm_m, float)
    k = int(round(np.sqrt(n_ground)))
    g = np.linspace(-450, 450, k)
    gx, gy = np.meshgrid(g, g)
    ground_world = np.column_stack([gx.ravel(), gy.ravel(), rng.uniform(-5, 15, gx.size)])
    ground_world[:, :2] += rng.normal(0, 20, (gx.size, 2))
    ids = np.array([f"P{k:03d}" for k in range(len(ground_world))], dtype=object)
    role = np.array(["control" if (i % 4 == 0) else "check" for i in range(len(ids))], dtype=object)
    ground = Points(ids, world.to_map(ground_world), np.full((len(ids), 3), 0.01), role)
    cal = simulate_mounting_flight(rng, world, camera, lever, R_cam_to_body, delay_s, ground_world, ids,
                                   **(calibration or {}))
    mp = dict(heights=(450.0,), n_strips=4, spacing_m=250.0, azimuth_deg=100.0, wind_en=(-3.0, 6.0),
              t0=2200 * SECONDS_PER_WEEK + 310000.0)
    mp.update(mapping or {})
    mapf = simulate_mounting_flight(rng, world, camera, lever, R_cam_to_body, delay_s, ground_world, ids, **mp)
    noise = {"pos_sigma": [0.05, 0.05, 0.08, 0.01, 0.01, 0.03],
             "eop_sigma_300m": [0.03, 0.03, 0.04, 0.003, 0.003, 0.002],
             "pixel_sigma": 0.5, "pos_error_kernel_s": 0.3,
             "pos_common_fraction": (calibration or {}).get("pos_common_fraction", 0.0)}
    return MountingSim(crs, camera, lever, R_cam_to_body, float(delay_s), ground, cal, mapf, noise)


def write_mounting_sim(sim: MountingSim, out: Path) -> None:
    """Write the simulated files: calibration/ and mapping/ flights, ground.csv, camera.json, truth.json."""
    with staged_dir(out) as tmp:
        for name, fl in (("calibration", sim.calibration), ("mapping", sim.mapping)):
            d = tmp / name
            d.mkdir()
            write_trajectory(d / "trajectory.csv", fl.traj)
            write_events(d / "events.csv", fl.events)
            write_eop(d / "eop.csv", fl.eop)
            write_eop(d / "eop_true.csv", fl.eop_true)
            write_measurements(d / "measurements.csv", fl.measurements)
        write_points(tmp / "ground.csv", sim.ground, with_role=True)
        write_camera_json(tmp / "camera.json", sim.camera)
        with atomic_write(tmp / "truth.json") as fh:
            json.dump(sim.truth(), fh, indent=2)
