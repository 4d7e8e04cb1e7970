"""`dgcal simulate pos`: a UAV flight with a realistic IMU, raw GNSS code + Doppler from broadcast orbits,
rover and base carrier phase, an antenna lever arm, a partial outage (3 satellites for 60 s) and camera
events, with the truth.

Composes dgcal.sim.trajectory (exact flight kinematics), dgcal.sim.imu (grade presets of
dgcal.pos.ins.error_model) and dgcal.sim.gnss (pseudoranges from the real navigation file of
../shared/data/rinex-sept by default, so the flight is dated 2021-03-19 around 12:00 GPS time).
Files: imu.csv (increments, dgcal.pos.ins.imu_data), obs.rnx (RINEX 3, code + Doppler), rover.rnx and base.rnx
(RINEX 3, dual-frequency code, carrier phase, Doppler, C/N0 of the rover antenna and of a static base station:
`dgcal.sim.gnss.simulate_rover_base`, with multipath, atmosphere residuals, cycle slips, a 10 s total outage and
the 60 s three-satellite window), nav.rnx, events.csv, truth_trajectory.csv (true IMU trajectory at 10 Hz),
truth_events.csv, truth.json (with the base position and the exact `dgcal pos` command lines).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.fields.constants import OMEGA_IE_E, SECONDS_PER_WEEK
from dgcal.fields.crs import LocalENU
from dgcal.fields.io.csv_tables import atomic_write, staged_dir
from dgcal.fields.io.formats import Trajectory, write_events, write_trajectory
from dgcal.pos.gnss.carrier import write_rinex_carrier
from dgcal.pos.gnss.rinex import write_rinex_obs
from dgcal.pos.ins.error_model import imu_grade as grade_of
from dgcal.pos.ins.imu_data import write_imu_csv
from dgcal.sim.gnss import (DEFAULT_T0_GPS, CarrierErrorModel, CodeErrorModel, load_nav, simulate_gnss,
                            write_nav_file)
from dgcal.sim.imu import simulate_imu
from dgcal.sim.rover_motion import RoverPath, airframe_mask, rover_base_with_turn_slips
from dgcal.sim.trajectory import camera_events, simulate_true_trajectory


@dataclass
class PosSimulation:
    """An in-memory simulated POS data set (see `simulate_pos`)."""

    traj: object  # dgcal.sim.trajectory.TrueTrajectory
    imu: object  # dgcal.pos.ins.imu_data.ImuData (noisy)
    imu_errors: object  # dgcal.sim.imu.ImuErrorRealisation
    obs: object  # dgcal.pos.gnss.observations.GnssObservations (raw epochs; obs.truth holds the receiver truth)
    nav: object  # dgcal.pos.gnss.rinex.BroadcastNav
    events: object  # dgcal.fields.io.formats.Events
    lever_arm_b: np.ndarray
    outage: tuple
    grade: object
    sigma_pr: float
    sigma_doppler: float
    info: dict = field(default_factory=dict)
    carrier: object = None  # dgcal.sim.gnss.CarrierSimulation: rover + base carrier phase (None if not simulated)
    outages: list = field(default_factory=list)  # the carrier pair's rover outages (t0, t1, max_sats)
    code_errors: object = None  # dgcal.sim.gnss.CodeErrorModel of the rover's code (None: exact models)


def simulate_pos(seed: int = 0, duration_s: float = 1200.0, kind: str = "multirotor", imu_grade="adis16488",
                 rate_hz: float = 200.0, lever_arm_b=(0.05, -0.10, -0.30), outage_start_s: float | None = None,
                 outage_s: float = 60.0, outage_sats: int = 3, nav=None, systems=("G", "E"),
                 sigma_pr: float = 0.3, sigma_doppler: float = 0.1, event_interval_s: float = 2.0,
                 lat0: float = 35.3, lon0: float = 139.5, h_ground: float = 40.0, height_agl: float = 120.0,
                 n_strips: int = 6, strip_length_m: float = 600.0, strip_spacing_m: float = 80.0,
                 misalignment: bool = True, carrier: bool = True, base_offset_enu_m=(1200.0, -700.0, 0.0),
                 total_outage_s: float = 10.0, n_slips: int = 6,
                 carrier_errors: CarrierErrorModel | None = None,
                 code_errors: CodeErrorModel | None = None, airframe_mask_deg: float | None = None,
                 turn_slip_rate: float = 0.0, half_cycle_share: float = 0.0,
                 carrier_doppler: bool = True) -> PosSimulation:
    """Simulate a flight (seconds, metres, degrees; GPS time from the navigation file's day).

    The outage (`outage_sats` highest satellites kept) starts at `outage_start_s` after take-off (default:
    60 % of the flight, on a strip or turn). GNSS epochs are at whole GPS seconds at 1 Hz. With `carrier`, the
    rover antenna and a static base at `base_offset_enu_m` from the site (ground height) also get dual-frequency
    code and carrier phase (`dgcal.sim.gnss.simulate_rover_base`): the same three-satellite window, a total
    outage of `total_outage_s` at 30 % of the flight (0: none) and `n_slips` random cycle slips. `code_errors`: the
    satellites' slow pseudorange errors of real broadcast models (`dgcal.sim.gnss.CodeErrorModel`; default none:
    the rover's code then fits the front end's models exactly, so process it with model_errors=False).
    The carrier phase as a real airframe sees it (`dgcal.sim.rover_motion`): `airframe_mask_deg` hides satellites
    below that angle above the body's horizontal plane (a bank takes the low wing's side away), `turn_slip_rate`
    slips per satellite and epoch while banked, `half_cycle_share` of new arcs start with a half cycle,
    `carrier_doppler` False: a rover receiver without Doppler.
    """
    nav = load_nav(nav)
    week = int(DEFAULT_T0_GPS // SECONDS_PER_WEEK)
    sow = DEFAULT_T0_GPS - week * SECONDS_PER_WEEK + 5.0
    traj = simulate_true_trajectory(kind, lat0=lat0, lon0=lon0, h_ground=h_ground, heights_agl=(height_agl,),
                                    n_strips=n_strips, strip_length_m=strip_length_m, strip_spacing_m=strip_spacing_m,
                                    rate_hz=rate_hz, gps_week=week, gps_sow=sow, duration_s=duration_s)
    grade = grade_of(imu_grade)
    imu, err = simulate_imu(traj, grade, seed=seed + 1, misalignment=misalignment)
    # the first sample's increment covers the interval before the flight start: drop it
    imu = imu.between(traj.t[1], traj.t[-1])
    lever = np.asarray(lever_arm_b, float)
    t_gnss = np.arange(np.ceil(traj.t[0]) + 1.0, np.floor(traj.t[-1]) - 1.0 + 1e-9, 1.0)
    st = traj.at(t_gnss)
    p_ant = st.p_ecef + np.einsum("kij,j->ki", st.R_body_to_ecef, lever)
    # antenna velocity: IMU velocity plus the lever arm's rotation (body rate relative to the earth)
    w_eb_b = st.omega_ib_b - np.einsum("kji,j->ki", st.R_body_to_ecef, np.array(OMEGA_IE_E, float).ravel())
    v_ant = st.v_ecef + np.einsum("kij,kj->ki", st.R_body_to_ecef, np.cross(w_eb_b, lever))
    t0 = t_gnss[0] + (0.6 * (t_gnss[-1] - t_gnss[0]) if outage_start_s is None else outage_start_s)
    outage = (float(t0), float(t0 + outage_s), int(outage_sats))
    obs = simulate_gnss(t_gnss, p_ant, v_ant, nav=nav, seed=seed + 2, sigma_pr=sigma_pr,
                        sigma_doppler=sigma_doppler, outages=[outage], systems=tuple(systems), prepare=False,
                        code_errors=code_errors)
    nav = obs.truth["nav"]      # with the synthetic GLONASS records the simulation drew, when it asked for R
    events = camera_events(traj, interval_s=event_interval_s)
    inside = (events.t > t_gnss[0] + 1.0) & (events.t < t_gnss[-1] - 1.0)  # the smoothed span
    events.image, events.t = events.image[inside], events.t[inside]
    csim, outages = None, []
    if carrier:
        outages = [outage]
        if total_outage_s > 0:
            ta = float(t_gnss[0] + 0.3 * (t_gnss[-1] - t_gnss[0]))
            outages.append((ta, ta + float(total_outage_s), 0))
        base = LocalENU(lat0, lon0, h_ground).to_ecef(np.asarray(base_offset_enu_m, float)[None])[0]
        path = RoverPath(t_gnss, p_ant, v_ant, np.radians(st.rph[:, 2]), np.radians(st.rph[:, 0]),
                         np.radians(st.rph[:, 1]), np.abs(st.rph[:, 0]) > 10.0, kind)
        mask = airframe_mask(path, airframe_mask_deg) if airframe_mask_deg is not None else None
        csim = rover_base_with_turn_slips(path, base, mask, turn_slip_rate, np.random.default_rng(seed + 4),
                                          half_cycle_share=half_cycle_share, nav=nav, seed=seed + 3,
                                          # GLONASS's FDMA carrier is not double-differenced: none in rover/base
                                          errors=carrier_errors, systems=tuple(x for x in systems if x != "R"),
                                          n_freq=2, outages=outages,
                                          n_random_slips=n_slips, doppler=carrier_doppler)
    return PosSimulation(traj, imu, err, obs, nav, events, lever, outage, grade, sigma_pr, sigma_doppler,
                         {"seed": seed, "flight": kind, "duration_s": duration_s, "rate_hz": rate_hz,
                          "carrier_airframe_mask_deg": airframe_mask_deg, "carrier_turn_slip_rate": turn_slip_rate,
                          "carrier_half_cycle_share": half_cycle_share, "carrier_doppler": carrier_doppler},
                         csim, outages,
                         code_errors)


def true_trajectory(traj, t) -> object:
    """The true IMU trajectory at times t as a dgcal.fields.io.formats.Trajectory (no sigmas)."""
    st = traj.at(np.asarray(t, float))
    return Trajectory(t=st.t, lat=st.lat, lon=st.lon, h=st.h, v_ned=st.v_ned, rph=st.rph)


def navigation_errors(sol, traj) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Errors of a smoother solution against the true flight: position (K,3) m in nav axes, attitude (K,3) rad
    as a body-frame rotation vector, and the solution's sigmas of both."""
    st = traj.at(sol.t)
    dp = sol.p_nav - sol.frame.from_ecef(st.p_ecef)
    R_true = np.einsum("ji,kjl->kil", sol.frame.R_nav_to_ecef, st.R_body_to_ecef)
    dth = Rotation.from_matrix(np.einsum("kji,kjl->kil", R_true, sol.R_body_to_nav)).as_rotvec()
    sp = np.sqrt(np.einsum("kii->ki", sol.cov_p_nav))
    sa = np.sqrt(np.einsum("kii->ki", sol.cov_pose[:, :3, :3]))
    return dp, dth, sp, sa


def write_pos_dataset(out, sim: PosSimulation) -> dict:
    """Write the files of a simulated data set into `out` (staged: all or nothing); returns truth.json."""
    t10 = np.arange(sim.traj.t[0], sim.traj.t[-1], 0.1)
    truth = {
        "kind": "pos", **sim.info, "lever_arm_gnss_m": sim.lever_arm_b.tolist(),
        "imu_grade": sim.grade.name, "imu_errors": sim.imu_errors.as_dict(),
        "outage": {"t0_gps": sim.outage[0], "t1_gps": sim.outage[1], "max_sats": sim.outage[2]},
        "gnss": {"sigma_pr_zenith_m": sim.sigma_pr, "sigma_doppler_zenith_mps": sim.sigma_doppler,
                 "systems": sorted(sim.obs.signals), "signals": sim.obs.signals,
                 "model_errors": sim.code_errors is not None, "n_epochs": len(sim.obs.epochs),
                 "code_errors": None if sim.code_errors is None else sim.code_errors.as_dict()},
        "n_events": len(sim.events.t),
        "files": {"imu": "imu.csv", "rinex_obs": "obs.rnx", "rinex_nav": "nav.rnx", "events": "events.csv",
                  "truth_trajectory": "truth_trajectory.csv", "truth_events": "truth_events.csv"},
        **_carrier_truth(sim),
        "command": ("dgcal pos --mode tc --rinex-obs obs.rnx --rinex-nav nav.rnx --imu imu.csv --events events.csv "
                    f"--imu-grade {sim.grade.name} --lever-arm {' '.join('%g' % v for v in sim.lever_arm_b)} "
                    f"--code-sigma {sim.sigma_pr:g} --doppler-sigma {sim.sigma_doppler:g} "
                    + ("" if sim.code_errors is not None else "--set model_errors=false ")
                    + ("" if list(sim.obs.signals) == ["G", "E"] else f"--systems {''.join(sim.obs.signals)} ")
                    + "--out OUT"),
    }
    with staged_dir(out) as d:
        d = Path(d)
        write_imu_csv(d / "imu.csv", sim.imu)
        write_rinex_obs(d / "obs.rnx", sim.obs)
        if sim.carrier is not None:
            write_rinex_carrier(d / "rover.rnx", sim.carrier.rover, marker="ROVER")
            write_rinex_carrier(d / "base.rnx", sim.carrier.base, marker="BASE")
        src = Path(sim.nav.source) if sim.nav.source else None
        if src is not None and src.is_file():
            write_nav_file(d / "nav.rnx", src, sim.nav)      # with the GLONASS records drawn, when R was asked for
        write_events(d / "events.csv", sim.events)
        write_trajectory(d / "truth_trajectory.csv", true_trajectory(sim.traj, t10))
        te = true_trajectory(sim.traj, sim.events.t)
        te.image = sim.events.image
        write_trajectory(d / "truth_events.csv", te)
        with atomic_write(d / "truth.json") as fh:
            json.dump(truth, fh, indent=2)
    return truth


def _carrier_truth(sim: PosSimulation) -> dict:
    """The rover + base part of truth.json: files, base position, the carrier simulation's errors, slips and
    outages, and the exact `dgcal pos` command line of TC with carrier phase."""
    c = sim.carrier
    if c is None:
        return {}
    b = c.base_ecef
    return {
        "carrier": {"files": {"rover": "rover.rnx", "base": "base.rnx"}, "base_ecef_m": b.tolist(),
                    "systems": sorted({s[0] for s in c.rover.sats}), "frequencies": int(c.rover.n_slots),
                    "signals": {f"{s}{f}": "/".join(v) for (s, f), v in c.rover.signals.items()},
                    "errors": c.truth["errors"], "tropo_zenith_residual_m": c.truth["tropo_zenith_residual_m"],
                    "outages": [{"t0_gps": a, "t1_gps": e, "max_sats": n} for a, e, n in sim.outages],
                    "slips": [{"t_gps": t, "sat": s, "slot": f, "cycles": n, "flagged": fl}
                              for t, s, f, n, fl in c.truth["slips"]],
                    "loss_of_lock_restarts": len(c.truth["restarts"])},
        "command_carrier": ("dgcal pos --mode tc --rinex-obs rover.rnx --rinex-nav nav.rnx --rinex-base base.rnx "
                            f"--base-position {b[0]:.4f} {b[1]:.4f} {b[2]:.4f} --imu imu.csv --events events.csv "
                            f"--imu-grade {sim.grade.name} --lever-arm {' '.join('%g' % v for v in sim.lever_arm_b)} "
                            f"--code-sigma 0.3 --doppler-sigma {sim.sigma_doppler:g} --frequencies 2 "
                            "--set model_errors=false --out OUT"),
        "command_ppk": ("dgcal pos --mode ppk --rinex-obs rover.rnx --rinex-nav nav.rnx --rinex-base base.rnx "
                        f"--base-position {b[0]:.4f} {b[1]:.4f} {b[2]:.4f} --frequencies 2 --out OUT"),
    }
