"""Kinematic GNSS rovers as they really move: UAV survey flights and cars, with what their antennas lose.

`dgcal simulate rover` (and the PPK / TC tests) draw a rover and a static base with `simulate_kinematic_rover`:

- **uav**: a survey flight of `dgcal.sim.trajectory` (fixed-wing 25 m/s or multirotor 10-15 m/s, coordinated
  turns at `bank_deg`, default 30 deg); the airframe hides every satellite less than `airframe_mask_deg` above the
  body's horizontal plane, so a bank takes the low satellites on the low wing's side away for the turn.
- **car**: stop-and-go along a street grid: legs of 80-300 m, 90 deg turns at 4-6 m/s, accelerations and braking
  at 2-4 m/s^2, stops of 5-20 s; buildings on both sides hide satellites below ``atan(urban |sin(az - heading)|)``
  (`urban` = building height / distance), so the mask turns with the car.

On top of the errors of `dgcal.sim.gnss.CarrierErrorModel` (multipath, atmosphere residuals): cycle slips where
real receivers lose them (per satellite and epoch with probability `slip_rate` while the UAV banks or the car
turns, on one frequency or all, half of them flagged by LLI), half-cycle ambiguities at new arcs, and receivers
without Doppler. Positions are the antenna's (ECEF m), times GPS seconds at `rate_hz`.
"""
from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.crs import LocalENU
from dgcal.fields.io.csv_tables import atomic_write, staged_dir, write_table
from dgcal.pos.gnss.carrier import write_rinex_carrier
from dgcal.sim.gnss import DEFAULT_T0_GPS, CarrierErrorModel, CarrierSimulation, load_nav, simulate_rover_base
from dgcal.sim.trajectory import simulate_true_trajectory

ROVER_KINDS = ("uav", "car")


@dataclass
class RoverPath:
    """A rover antenna's motion at the GNSS epochs: t (GPS s), position (ECEF m), velocity (ECEF m/s), heading
    (rad from north), roll (rad, right wing down positive) and `turning` (epochs where slips are likely)."""

    t: np.ndarray
    p_ecef: np.ndarray
    v_ecef: np.ndarray
    heading: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    turning: np.ndarray
    kind: str


def uav_path(t_gps: np.ndarray, kind: str = "fixed-wing", speed_mps: float | None = None, bank_deg: float = 30.0,
             lat0: float = 35.3, lon0: float = 139.5, h_ground: float = 40.0, height_agl: float = 120.0,
             n_strips: int = 6, strip_length_m: float = 800.0, strip_spacing_m: float = 100.0) -> RoverPath:
    """A survey flight (`dgcal.sim.trajectory.simulate_true_trajectory`, `kind` fixed-wing or multirotor) sampled at
    `t_gps`; orbits after the last strip fill the time. Turning: roll beyond 10 deg."""
    t = np.asarray(t_gps, float)
    week = int(t[0] // SECONDS_PER_WEEK)
    duration = float(t[-1] - t[0]) + 2.0
    traj = simulate_true_trajectory(kind, lat0=lat0, lon0=lon0, h_ground=h_ground, heights_agl=(height_agl,),
                                    n_strips=n_strips, strip_length_m=strip_length_m,
                                    strip_spacing_m=strip_spacing_m, speed=speed_mps, bank_deg=bank_deg,
                                    rate_hz=10.0, gps_week=week, gps_sow=t[0] - week * SECONDS_PER_WEEK - 1.0,
                                    duration_s=duration)
    st = traj.at(t)
    rph = np.radians(st.rph)
    return RoverPath(t, st.p_ecef, st.v_ecef, rph[:, 2], rph[:, 0], rph[:, 1], np.abs(rph[:, 0]) > np.radians(10.0),
                     "uav")


def car_path(t_gps: np.ndarray, seed: int = 0, lat0: float = 35.34, lon0: float = 139.52, h0: float = 45.0,
             cruise_mps: tuple[float, float] = (8.0, 14.0), accel_mps2: tuple[float, float] = (2.0, 4.0),
             turn_mps: float = 5.0, turn_radius_m: float = 12.0, stop_share: float = 0.4) -> RoverPath:
    """A car driving a street grid from (lat0, lon0, h0) for the span of `t_gps` (see the module doc), integrated
    at 20 Hz and sampled at `t_gps`. Turning: heading rate beyond 3 deg/s, or stopped-and-starting."""
    rng = np.random.default_rng(seed)
    t = np.asarray(t_gps, float)
    dt = 0.05
    n = int(np.ceil((t[-1] - t[0] + 2.0) / dt)) + 1
    tt = t[0] - 1.0 + dt * np.arange(n)
    v = np.zeros(n)
    psi = np.zeros(n)
    psi0 = rng.uniform(0, 2 * np.pi)
    k, speed, head = 0, 0.0, psi0
    wait = rng.uniform(5.0, 15.0)                               # standing at the start
    while k < n:
        # stand, accelerate to cruise, cruise, brake to the turn (or a stop), turn 90 deg
        for _ in range(int(wait / dt)):
            if k >= n:
                break
            v[k], psi[k] = 0.0, head
            k += 1
        cruise = rng.uniform(*cruise_mps)
        a = rng.uniform(*accel_mps2)
        leg = rng.uniform(80.0, 300.0)
        stop = rng.uniform() < stop_share
        v_end = 0.0 if stop else turn_mps
        s = 0.0
        while k < n and s < leg:
            brake = (speed ** 2 - v_end ** 2) / (2 * a)            # distance needed to brake to v_end
            if leg - s <= brake:
                speed = max(v_end, speed - a * dt)
            else:
                speed = min(cruise, speed + a * dt)
            s += speed * dt
            v[k], psi[k] = speed, head
            k += 1
        if stop:
            wait = rng.uniform(5.0, 20.0)
            speed = 0.0
            for _ in range(int(wait / dt)):
                if k >= n:
                    break
                v[k], psi[k] = 0.0, head
                k += 1
            speed = 0.0
            v_turn = max(turn_mps * 0.6, 2.0)
            while k < n and speed < v_turn:                      # pull away into the turn
                speed = min(v_turn, speed + a * dt)
                v[k], psi[k] = speed, head
                k += 1
        turn = np.pi / 2 * rng.choice([-1.0, 1.0])
        turned = 0.0
        while k < n and abs(turned) < abs(turn):
            sp = max(speed, 2.0)
            d = np.sign(turn) * sp / turn_radius_m * dt
            turned += d
            head += d
            v[k], psi[k] = sp, head
            k += 1
        wait = 0.0
    e = np.cumsum(v * np.sin(psi)) * dt
    nn = np.cumsum(v * np.cos(psi)) * dt
    up = 0.01 * nn                                                # a 1 % street slope
    enu = np.column_stack([e, nn, up])
    frame = LocalENU(lat0, lon0, h0)
    p = frame.to_ecef(enu)
    vel = np.gradient(p, dt, axis=0)
    rate = np.gradient(np.unwrap(psi), dt)
    acc = np.gradient(v, dt)
    turning = (np.abs(rate) > np.radians(3.0)) | ((v < 3.0) & (acc > 0.5))
    pick = lambda a: np.column_stack([np.interp(t, tt, a[:, j]) for j in range(a.shape[1])])  # noqa: E731
    return RoverPath(t, pick(p), pick(vel), np.interp(t, tt, np.unwrap(psi)), np.zeros(len(t)), np.zeros(len(t)),
                     np.interp(t, tt, turning.astype(float)) > 0.5, "car")


def airframe_mask(path: RoverPath, mask_deg: float):
    """The antenna's view from the top of an airframe: satellites at least `mask_deg` above the body's horizontal
    plane (rotated by roll and pitch) are visible; a function of the rover's (el, az) arrays (rad)."""
    cr, sr, cp, sp = np.cos(path.roll), np.sin(path.roll), np.cos(path.pitch), np.sin(path.pitch)
    ch, sh = np.cos(path.heading), np.sin(path.heading)

    def visible(el: np.ndarray, az: np.ndarray) -> np.ndarray:
        n = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)], axis=-1)   # NED
        # NED -> body: yaw, pitch, roll (Z-Y-X); only the body z component (down) is needed
        x1 = ch[:, None] * n[..., 0] + sh[:, None] * n[..., 1]
        y1 = -sh[:, None] * n[..., 0] + ch[:, None] * n[..., 1]
        z2 = sp[:, None] * x1 + cp[:, None] * n[..., 2]
        zb = -sr[:, None] * y1 + cr[:, None] * z2
        return -zb >= np.sin(np.radians(mask_deg))
    return visible


def street_mask(path: RoverPath, urban: float):
    """Buildings on both sides of the street: a satellite at azimuth az is visible above
    ``atan(urban |sin(az - heading)|)`` (`urban` = building height / distance to the antenna)."""
    def visible(el: np.ndarray, az: np.ndarray) -> np.ndarray:
        return np.tan(el) >= urban * np.abs(np.sin(az - path.heading[:, None]))
    return visible


def turn_slips(path: RoverPath, el: np.ndarray, visible: np.ndarray, sats: list, n_freq: int, rate: float,
               rng) -> list:
    """Cycle slips (t_gps, sat, slot, cycles, flagged) drawn while the rover turns: per visible satellite and
    turning epoch with probability `rate` (twice that below 25 deg elevation), on one slot or (one in three) on
    every slot; half flagged by LLI."""
    out = []
    low = np.where(el < np.radians(25.0), 2.0, 1.0)
    p = rate * low * visible * path.turning[:, None]
    p[:3] = 0.0
    for k, i in zip(*np.nonzero(rng.uniform(size=p.shape) < p)):
        cycles = int(rng.integers(1, 12)) * int(rng.choice([-1, 1]))
        flagged = bool(rng.uniform() < 0.5)
        slots = range(n_freq) if rng.uniform() < 1 / 3 else [int(rng.integers(0, n_freq))]
        out += [(float(path.t[k]), sats[i], f, cycles, flagged) for f in slots]
    return out


def rover_base_with_turn_slips(path: RoverPath, base_ecef: np.ndarray, mask, slip_rate: float, rng,
                               half_cycle_share: float = 0.0, **kw) -> CarrierSimulation:
    """`dgcal.sim.gnss.simulate_rover_base` of the rover moving along `path` against a base at `base_ecef` (ECEF m),
    its antenna's view limited by `mask` (None: open sky), with `turn_slips` at `slip_rate` drawn on what it sees:
    a first run finds the visible satellites, the second adds the slips (the same seed gives the same draws). `kw`:
    the other arguments of simulate_rover_base."""
    slips = []
    if slip_rate > 0:
        seen: dict = {}

        def probe_mask(el, az):
            vis = mask(el, az) if mask is not None else np.ones(el.shape, bool)
            seen["el"], seen["vis"] = el, vis & (el >= np.radians(kw.get("elev_mask_deg", 10.0)))
            return vis
        probe = simulate_rover_base(path.t, path.p_ecef, path.v_ecef, base_ecef, rover_mask=probe_mask, **kw)
        slips = turn_slips(path, seen["el"], seen["vis"], probe.rover.sats, kw.get("n_freq", 2), slip_rate, rng)
    return simulate_rover_base(path.t, path.p_ecef, path.v_ecef, base_ecef, rover_mask=mask, slips=slips,
                               half_cycle_share=half_cycle_share, **kw)


@dataclass
class KinematicRoverSimulation:
    """A simulated kinematic rover and its base (`carrier`) with the motion (`path`) and the scenario's settings."""

    carrier: CarrierSimulation
    path: RoverPath
    settings: dict


def simulate_kinematic_rover(kind: str = "uav", seed: int = 0, duration_s: float = 600.0, rate_hz: float = 1.0,
                             doppler: bool = True, slip_rate: float = 0.01, half_cycle_share: float = 0.3,
                             base_distance_m: float = 4000.0, systems=("G", "E"), n_freq: int = 2,
                             errors: CarrierErrorModel | None = None, nav=None, uav_kind: str = "fixed-wing",
                             bank_deg: float = 30.0, speed_mps: float | None = None,
                             airframe_mask_deg: float = 10.0, urban: float = 0.3,
                             t0_gps: float | None = None) -> KinematicRoverSimulation:
    """A UAV or car rover (`kind`) and a static base `base_distance_m` away, with masking, slips on turns and
    half cycles (module doc). Car errors default to more multipath than the UAV's (street reflections)."""
    if kind not in ROVER_KINDS:
        raise ValueError(f"rover kind {kind!r}: one of {', '.join(ROVER_KINDS)}")
    rng = np.random.default_rng(seed)
    nav = load_nav(nav)
    t0 = float(DEFAULT_T0_GPS + 5.0 if t0_gps is None else t0_gps)
    t = t0 + np.arange(int(round(duration_s * rate_hz)) + 1) / rate_hz
    lat0, lon0 = 35.3 + rng.uniform(-0.02, 0.02), 139.5 + rng.uniform(-0.02, 0.02)
    if kind == "uav":
        path = uav_path(t, uav_kind, speed_mps, bank_deg, lat0, lon0)
        mask = airframe_mask(path, airframe_mask_deg)
        err = errors or CarrierErrorModel()
    else:
        path = car_path(t, seed, lat0, lon0)
        mask = street_mask(path, urban)
        err = errors or CarrierErrorModel(code_mp_m=0.5, phase_mp_m=0.004, phase_mp_tau_s=20.0)
    az_b = rng.uniform(0, 2 * np.pi)
    base = LocalENU(lat0, lon0, 40.0).to_ecef(np.array([[base_distance_m * np.sin(az_b),
                                                          base_distance_m * np.cos(az_b), 0.0]]))[0]

    sim = rover_base_with_turn_slips(path, base, mask, slip_rate, rng, half_cycle_share=half_cycle_share, nav=nav,
                                     seed=seed + 1, errors=err, systems=tuple(systems), n_freq=n_freq,
                                     doppler=doppler)
    settings = {"kind": kind, "seed": seed, "duration_s": duration_s, "rate_hz": rate_hz, "doppler": doppler,
                "slip_rate": slip_rate, "half_cycle_share": half_cycle_share, "base_distance_m": base_distance_m,
                "systems": list(systems), "n_freq": n_freq, "uav_kind": uav_kind if kind == "uav" else None,
                "bank_deg": bank_deg if kind == "uav" else None,
                "airframe_mask_deg": airframe_mask_deg if kind == "uav" else None,
                "urban": urban if kind == "car" else None,
                "speed_mps": {"max": float(np.max(np.linalg.norm(path.v_ecef, axis=1))),
                              "mean": float(np.mean(np.linalg.norm(path.v_ecef, axis=1)))}}
    return KinematicRoverSimulation(sim, path, settings)


def write_rover_dataset(out, sim: KinematicRoverSimulation) -> dict:
    """Write rover.rnx, base.rnx, nav.rnx, truth.csv (antenna per epoch: gps_week, gps_sow, ECEF m, speed m/s) and
    truth.json (settings, base position, slips, the `dgcal pos --mode ppk` command) into `out`, all or nothing."""
    c = sim.carrier
    b = c.base_ecef
    week = np.floor(c.truth["t_gps"] / SECONDS_PER_WEEK).astype(int)
    sow = c.truth["t_gps"] - week * SECONDS_PER_WEEK
    truth = {"kind": "rover", **sim.settings, "base_ecef_m": b.tolist(),
             "errors": c.truth["errors"], "slips": [{"t_gps": t, "sat": s, "slot": f, "cycles": n, "flagged": fl}
                                                    for t, s, f, n, fl in c.truth["slips"]],
             "half_cycle_arcs": c.truth["half_cycles"], "loss_of_lock_restarts": len(c.truth["restarts"]),
             "files": {"rover": "rover.rnx", "base": "base.rnx", "nav": "nav.rnx", "truth": "truth.csv"},
             "command_ppk": ("dgcal pos --mode ppk --rinex-obs rover.rnx --rinex-nav nav.rnx --rinex-base base.rnx "
                             f"--base-position {b[0]:.4f} {b[1]:.4f} {b[2]:.4f} --out OUT")}
    speed = np.linalg.norm(c.truth["v_ecef"], axis=1)
    with staged_dir(out) as d:
        d = Path(d)
        write_rinex_carrier(d / "rover.rnx", c.rover, marker="ROVER")
        write_rinex_carrier(d / "base.rnx", c.base, marker="BASE")
        src = Path(c.nav.source) if c.nav.source else None
        if src is not None and src.is_file():
            shutil.copyfile(src, d / "nav.rnx")
        write_table(d / "truth.csv", ["gps_week", "gps_sow", "x", "y", "z", "speed_mps"],
                    [[int(w), float(s), *p.tolist(), float(v)] for w, s, p, v in zip(week, sow, c.truth["p_ecef"],
                                                                                     speed)], fmt="%.12g")
        with atomic_write(d / "truth.json") as fh:
            json.dump(truth, fh, indent=2)
    return truth
