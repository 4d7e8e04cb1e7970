"""Seed 000-style low-cost flight: 113 m above ground, 26 m/s, a NASCAR loop (two straight legs, two turns)
with small attitudes on the legs, an ADIS16405-class IMU, a 50 Hz GNSS receiver (position + velocity) and
a down-looking laser range finder (10 Hz) along the camera axis.

GNSS position errors are time-correlated (first-order Gauss-Markov, the OEMV-1 class of seed 000 Table 3:
about 1.5 m horizontal RMS) plus a little white noise; velocities carry white noise only.
"""
from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fields.csvio import staged_dir
from fields.frames import R_ecef_to_ned
from pos.imu_io import ImuData, write_imu_csv
from pos.smoother_init import GnssFixes
from sim.imu import ImuErrors, simulate_imu
from sim.trajectory import TrueTrajectory, simulate_flight

NAME = "lowcost"
HELP = "seed 000 low-cost payload flight: ADIS16405 IMU, 50 Hz GNSS, laser range (113 m, 26 m/s)"


@dataclass
class LowcostFlight:
    """A simulated flight: truth at the IMU rate, the noisy IMU, GNSS fixes and their true errors."""

    truth: TrueTrajectory
    imu: ImuData
    imu_errors: ImuErrors
    fixes: GnssFixes
    gnss_error_ned: np.ndarray  # true position error of each fix (N,3) m
    h_ground: float


def gnss_fixes(truth: TrueTrajectory, rate_hz: float = 50.0, sigma_h_m: float = 1.5, sigma_v_m: float = 2.5,
               tau_s: float = 60.0, white_m: float = 0.2, sigma_vel_mps: float = 0.05,
               seed: int = 0) -> tuple[GnssFixes, np.ndarray]:
    """GNSS antenna fixes (at the IMU origin) at `rate_hz` with Gauss-Markov position errors; (fixes, errors NED)."""
    rng = np.random.default_rng(seed)
    step = max(1, int(round(truth.rate_hz / rate_hz)))
    idx = np.arange(0, len(truth.t), step)
    n = len(idx)
    dt = step / truth.rate_hz
    phi = np.exp(-dt / tau_s)
    sig = np.array([sigma_h_m, sigma_h_m, sigma_v_m]) / np.sqrt(2.0)  # per horizontal axis
    e = np.empty((n, 3))
    e[0] = rng.standard_normal(3) * sig
    w = rng.standard_normal((n, 3)) * sig * np.sqrt(1 - phi ** 2)
    for k in range(1, n):
        e[k] = phi * e[k - 1] + w[k]
    e += rng.standard_normal((n, 3)) * white_m
    R_ne = np.swapaxes(R_ecef_to_ned(truth.lat[idx], truth.lon[idx]), 1, 2)
    p = truth.p_ecef[idx] + np.einsum("nij,nj->ni", R_ne, e)
    v = truth.v_ecef[idx] + np.einsum("nij,nj->ni", R_ne, rng.standard_normal((n, 3)) * sigma_vel_mps)
    s_p = np.tile(np.hypot(sig, white_m), (n, 1))
    s_v = np.full((n, 3), sigma_vel_mps)
    return GnssFixes(t=truth.t[idx].copy(), p_ecef=p, sigma_ned=s_p, v_ecef=v, sigma_v_ned=s_v), e


def simulate_lowcost_flight(duration_s: float = 180.0, rate_hz: float = 100.0, gnss_hz: float = 50.0,
                            height_agl: float = 113.0, speed: float = 26.0, bank_deg: float = 20.0,
                            leg_length_m: float = 1200.0, loop_width_m: float = 400.0, lat0: float = 39.65,
                            lon0: float = -79.95, h_ground: float = 300.0, grade: str = "adis16405",
                            seed: int = 0) -> LowcostFlight:
    """The seed 000 flight (Phastball: 113 m AGL, 26 m/s, NASCAR loop) with IMU and 50 Hz GNSS; truth body FRD."""
    truth = simulate_flight("fixed-wing", lat0=lat0, lon0=lon0, h_ground=h_ground, heights_agl=(height_agl,),
                            n_strips=2, strip_length_m=leg_length_m, strip_spacing_m=loop_width_m,
                            strip_heading_deg=225.0, speed=speed, bank_deg=bank_deg, climb_rate=4.0,
                            aoa_deg=2.0, rate_hz=rate_hz, duration_s=duration_s)
    imu, err = simulate_imu(truth, grade, seed=seed)
    fixes, e = gnss_fixes(truth, gnss_hz, seed=seed + 1)
    return LowcostFlight(truth, imu, err, fixes, e, h_ground)


def laser_ranges(truth: TrueTrajectory, t: np.ndarray, ground_height, axis_b=(0.0, 0.0, 1.0), sigma_m: float = 0.3,
                 seed: int = 0) -> np.ndarray:
    """Laser ranges (m) along the body axis `axis_b` (FRD) to flat ground at ellipsoidal height(s), with noise."""
    s = truth.at(t)
    d_ned = np.einsum("nij,j->ni", s.R_body_to_ned, np.asarray(axis_b, float) / np.linalg.norm(axis_b))
    rng = np.random.default_rng(seed)
    return (s.h - np.asarray(ground_height, float)) / d_ned[:, 2] + rng.standard_normal(len(t)) * sigma_m


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=360.0, help="flight length (s)")


def run(args: argparse.Namespace) -> int:
    f = simulate_lowcost_flight(duration_s=args.duration, seed=args.seed)
    with staged_dir(args.out) as d:
        write_imu_csv(Path(d) / "imu.csv", f.imu)
        fx = f.fixes
        rows = np.column_stack([fx.t, fx.p_ecef, fx.v_ecef, fx.sigma_ned, fx.sigma_v_ned])
        np.savetxt(Path(d) / "gnss_fixes.csv", rows, delimiter=",", fmt="%.4f",
                   header="t_gps,x,y,z,vx,vy,vz,s_n,s_e,s_d,s_vn,s_ve,s_vd", comments="")
        tr = f.truth
        rows = np.column_stack([tr.t, tr.lat, tr.lon, tr.h, tr.v_ned, tr.rph])
        np.savetxt(Path(d) / "truth_trajectory.csv", rows, delimiter=",", fmt="%.9f",
                   header="t_gps,lat,lon,h,vn,ve,vd,roll,pitch,heading", comments="")
        (Path(d) / "truth.json").write_text(json.dumps({"imu_errors": f.imu_errors.as_dict(),
                                                       "h_ground": f.h_ground, "seed": args.seed}, indent=1))
    print(f"wrote {args.out}/imu.csv, gnss_fixes.csv, truth_trajectory.csv, truth.json")
    return 0



def attitude_error_stats(err_deg: np.ndarray) -> dict:
    """Mean, std and RMS (deg) of roll/pitch/heading errors (N,3) — the rows of seed 000 / 001 accuracy tables."""
    e = np.asarray(err_deg, float)
    return {name: {"mean_deg": float(e[:, i].mean()), "std_deg": float(e[:, i].std()),
                   "rms_deg": float(np.sqrt(np.mean(e[:, i] ** 2)))}
            for i, name in enumerate(("roll", "pitch", "heading"))}


def _rph_error(truth: TrueTrajectory, t: np.ndarray, rph_deg: np.ndarray) -> np.ndarray:
    d = np.asarray(rph_deg, float) - truth.at(t).rph
    d[:, 2] = (d[:, 2] + 180.0) % 360.0 - 180.0
    return d


def compare_ukf_smoother(flight: LowcostFlight, smoother_rate_hz: float = 10.0, skip_s: float = 30.0,
                         progress: bool = False) -> dict:
    """Seed 000's UKF and the gtsam smoother (LC position+velocity factors, fixes decimated to
    `smoother_rate_hz`) on the same flight; attitude and position accuracy against truth at their common
    epochs after `skip_s` of filter convergence. Returns a JSON-ready report dict."""
    from fields.frames import rph_from_R_body_to_ned
    from pos.smoother import SmootherOptions, smooth
    from pos.ukf import run_ukf
    fx = flight.fixes
    grade = flight.imu_errors.grade
    u = run_ukf(flight.imu, fx, grade, progress=progress)
    step = max(1, int(round(1.0 / (smoother_rate_hz * np.median(np.diff(fx.t))))))
    s = slice(None, None, step)
    lc = GnssFixes(fx.t[s], fx.p_ecef[s], fx.sigma_ned[s], fx.v_ecef[s], fx.sigma_v_ned[s])
    sm = smooth(flight.imu, lc, grade, SmootherOptions(), mode="lc", frame=u.frame)
    R_sm = sm.frame.R_nav_to_local_ned(sm.p_nav) @ sm.R_body_to_nav
    rph_sm = rph_from_R_body_to_ned(R_sm)
    iu = {round(float(t), 3): i for i, t in enumerate(u.t)}
    pairs = [(iu[round(float(t), 3)], k) for k, t in enumerate(sm.t)
             if round(float(t), 3) in iu and t >= u.t[0] + skip_s]
    a, b = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
    t = u.t[a]
    e_u = _rph_error(flight.truth, t, u.rph_deg[a])
    e_s = _rph_error(flight.truth, t, rph_sm[b])
    # the UKF's own uncertainty against its errors (honest sigmas give |e|/sigma ~ N(0,1))
    z = e_u / u.sigma_rph_deg[a]
    p_true = u.frame.from_ecef(flight.truth.at(t).p_ecef)
    pos_u = np.sqrt(np.mean((u.p_nav[a] - p_true) ** 2, axis=0))
    pos_s = np.sqrt(np.mean((sm.p_nav[b] - p_true) ** 2, axis=0))
    return {"n_epochs": int(len(t)), "skip_s": skip_s, "gnss_rate_hz": float(1.0 / np.median(np.diff(fx.t))),
            "smoother_rate_hz": smoother_rate_hz, "imu_grade": grade.name,
            "ukf": {**attitude_error_stats(e_u), "pos_rms_ned_m": pos_u.tolist()},
            "smoother": {**attitude_error_stats(e_s), "pos_rms_ned_m": pos_s.tolist()},
            "ukf_normalised_error_rms": np.sqrt(np.mean(z ** 2, axis=0)).tolist(),
            "seed000_ukf_std_deg": {"roll": 2.6, "pitch": 2.1}}


def format_accuracy_table(report: dict) -> str:
    """The UKF-vs-smoother report as a small text table (deg, m)."""
    lines = [f"{'':10s}{'roll rms':>10s}{'pitch rms':>10s}{'head rms':>10s}{'roll std':>10s}{'pitch std':>10s}"
             f"{'pos N/E/D rms (m)':>22s}"]
    for k in ("ukf", "smoother"):
        r = report[k]
        pos = "/".join(f"{x:.2f}" for x in r["pos_rms_ned_m"])
        lines.append(f"{k:10s}{r['roll']['rms_deg']:10.3f}{r['pitch']['rms_deg']:10.3f}{r['heading']['rms_deg']:10.3f}"
                     f"{r['roll']['std_deg']:10.3f}{r['pitch']['std_deg']:10.3f}{pos:>22s}")
    lines.append(f"{'seed 000':10s}{'':30s}{2.6:10.3f}{2.1:10.3f}")
    return "\n".join(lines)
