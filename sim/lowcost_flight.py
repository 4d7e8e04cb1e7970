"""Seed 000-style low-cost flight: 113 m above ground, 26 m/s, a NASCAR loop (two straight legs, two turns)
with small attitudes on the legs, an ADIS16405-class IMU, a 50 Hz GNSS receiver (position + velocity) and
a down-looking laser range finder (10 Hz) along the camera axis.

GNSS position errors are time-correlated (first-order Gauss-Markov, the OEMV-1 class of seed 000 Table 3:
about 1.5 m horizontal RMS) plus a little white noise; velocities carry white noise only.

Other settings of the same family (`simulate_lowcost_flight`): slow platforms (`speed` 1 m/s with a gentle
`bank_deg`, `climb_rate`, short legs), a static start (`static_s` at rest, then a smooth acceleration to the
speed), a constant crab angle (`crab_deg`: heading - course) and GNSS outages (`gnss_outages`: START LENGTH
PERIOD s, the fixes inside withheld; the spans in `LowcostFlight.outages` and truth.json).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dgcal.calib.camera.models import Fraser7
from dgcal.calib.dg.dem import Dem
from dgcal.calib.dg.single_image import average_estimates, georeference, intersect_dem, pose_covariance_from_rph
from dgcal.fields.crs import ecef_to_geodetic, geodetic_to_ecef
from dgcal.fields.io.csv_tables import atomic_write, staged_dir
from dgcal.fields.io.formats import week_sow, write_events
from dgcal.fields.frames import (R_CAM_TO_BODY_NADIR, R_ENU_TO_NED, R_body_to_ned_from_rph, R_ecef_to_ned,
                                 rph_from_R_body_to_ned)
from dgcal.pos.ins.imu_data import ImuData, write_imu_csv
from dgcal.pos.ins.nav_frame import NavFrame
from dgcal.pos.gnss.solution_files import cov_to_sqvar
from dgcal.pos.lowcost.fix_files import write_gnss_fixes
from dgcal.pos.lowcost.ukf import run_ukf
from dgcal.pos.smoother.batch import SmootherOptions, smooth
from dgcal.pos.smoother.initial import GnssFixes
from dgcal.sim.imu import ImuErrorRealisation, simulate_imu
from dgcal.sim.trajectory import (FlightProfile, Segment, SmoothSteps, TrueTrajectory, assemble_trajectory,
                                  camera_events, simulate_true_trajectory)


@dataclass
class LowcostFlight:
    """A simulated flight: truth at the IMU rate, the noisy IMU, GNSS fixes and their true errors."""

    truth: TrueTrajectory
    imu: ImuData
    imu_errors: ImuErrorRealisation
    fixes: GnssFixes
    gnss_error_ned: np.ndarray  # true position error of each fix (N,3) m
    h_ground: float
    outages: list = field(default_factory=list)  # GNSS outages [(t_start, t_end) GPS s]: no fixes inside


def gnss_fixes(truth: TrueTrajectory, rate_hz: float = 50.0, sigma_h_m: float = 1.5, sigma_v_m: float = 2.5,
               tau_s: float = 60.0, white_m: float = 0.2, sigma_vel_mps: float = 0.05,
               seed: int = 0, lever_arm_b=(0.0, 0.0, 0.0)) -> tuple[GnssFixes, np.ndarray]:
    """GNSS antenna fixes at `rate_hz` with Gauss-Markov position errors; the antenna sits at `lever_arm_b`
    (body FRD, m) from the IMU origin. Returns (fixes, position errors NED)."""
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
    R_ned_to_ecef = np.swapaxes(R_ecef_to_ned(truth.lat[idx], truth.lon[idx]), 1, 2)
    lever = np.asarray(lever_arm_b, float)
    R_body_to_ecef = truth.R_body_to_ecef[idx]
    p_ant = truth.p_ecef[idx] + R_body_to_ecef @ lever
    v_ant = truth.v_ecef[idx] + np.einsum("nij,nj->ni", R_body_to_ecef, np.cross(truth.omega_ib_b[idx], lever))
    p = p_ant + np.einsum("nij,nj->ni", R_ned_to_ecef, e)
    v = v_ant + np.einsum("nij,nj->ni", R_ned_to_ecef, rng.standard_normal((n, 3)) * sigma_vel_mps)
    s_p = np.tile(np.hypot(sig, white_m), (n, 1))
    s_v = np.full((n, 3), sigma_vel_mps)
    return GnssFixes(t=truth.t[idx].copy(), p_ecef=p, sigma_ned=s_p, v_ecef=v, sigma_v_ned=s_v), e


def simulate_lowcost_flight(duration_s: float = 180.0, rate_hz: float = 100.0, gnss_hz: float = 50.0,
                            height_agl: float = 113.0, speed: float = 26.0, bank_deg: float = 20.0,
                            leg_length_m: float = 1200.0, loop_width_m: float = 400.0, lat0: float = 39.65,
                            lon0: float = -79.95, h_ground: float = 300.0, grade: str = "adis16405",
                            seed: int = 0, climb_rate: float = 4.0, margin_m: float = 150.0, crab_deg: float = 0.0,
                            static_s: float = 0.0, gnss_outages: tuple[float, float, float] | None = None
                            ) -> LowcostFlight:
    """The seed 000 flight (Phastball: 113 m AGL, 26 m/s, NASCAR loop) with IMU and 50 Hz GNSS; truth body FRD.

    `static_s` > 0: the platform first rests that long (GNSS running), then accelerates smoothly to `speed`
    (over max(2, speed/2) s, straight and level) before the flight plan starts. `gnss_outages` = (start, length,
    period) s from the first fix: the fixes in [t0 + start + k period, + length) are withheld."""
    shift = 0.0
    ramp_s = max(2.0, speed / 2.0)
    if static_s > 0:
        shift = static_s + ramp_s
    truth = simulate_true_trajectory("fixed-wing", lat0=lat0, lon0=lon0, h_ground=h_ground, heights_agl=(height_agl,),
                                     n_strips=2, strip_length_m=leg_length_m, strip_spacing_m=loop_width_m,
                                     strip_heading_deg=225.0, speed=speed, bank_deg=bank_deg, climb_rate=climb_rate,
                                     aoa_deg=2.0, crab_deg=crab_deg, margin_m=margin_m, rate_hz=rate_hz,
                                     duration_s=max(duration_s - shift, 1.0))
    if static_s > 0:
        truth = _with_static_start(truth, static_s, ramp_s, duration_s)
    imu, err = simulate_imu(truth, grade, seed=seed)
    fixes, e = gnss_fixes(truth, gnss_hz, seed=seed + 1)
    spans: list = []
    if gnss_outages is not None:
        keep, spans = outage_spans(fixes.t, gnss_outages)
        fixes = GnssFixes(fixes.t[keep], fixes.p_ecef[keep], fixes.sigma_ned[keep], fixes.v_ecef[keep],
                          fixes.sigma_v_ned[keep])
        e = e[keep]
    return LowcostFlight(truth, imu, err, fixes, e, h_ground, spans)


def outage_spans(t: np.ndarray, outages: tuple[float, float, float]) -> tuple[np.ndarray, list]:
    """Fixes outside GNSS outages (start, length, period) s from t[0] (the mask of epochs kept) and the outages'
    [t_start, t_end) spans (GPS s) inside the fixes' time span."""
    start, length, period = (float(v) for v in outages)
    if not (length > 0 and period > length and start >= 0):
        raise ValueError(f"GNSS outages need start >= 0, length > 0 and period > length, not {outages}")
    t = np.asarray(t, float)
    x = t - (t[0] + start)
    keep = ~((x >= 0) & (np.mod(x, period) < length))
    a = t[0] + start + period * np.arange(int(np.floor((t[-1] - t[0] - start) / period)) + 1)
    spans = [(float(s), float(min(s + length, t[-1]))) for s in a if s < t[-1]]
    return keep, spans


@dataclass
class _RampedProfile(FlightProfile):
    """A flight profile whose horizontal speed is `speed` times a smooth factor `ramp` (0 at rest, then 1)."""

    ramp: SmoothSteps | None = None

    def controls(self, t: np.ndarray) -> dict:
        c = super().controls(t)
        _, s, sd, sdd = self.ramp.evaluate(np.asarray(t, float) - self.t0)
        V, psi, r, rdot = self.speed, c["psi"], c["r"], c["rdot"]
        u = np.stack([np.cos(psi), np.sin(psi)], -1)      # along the course
        w = np.stack([-np.sin(psi), np.cos(psi)], -1)     # to its right
        c["v_l"][..., :2] = (s * V)[..., None] * u
        c["a_l"][..., :2] = (sd * V)[..., None] * u + (s * V * r)[..., None] * w
        c["j_l"][..., :2] = ((sdd * V - s * V * r * r)[..., None] * u
                             + (2 * sd * V * r + s * V * rdot)[..., None] * w)
        return c


def _with_static_start(truth: TrueTrajectory, static_s: float, ramp_s: float, duration_s: float) -> TrueTrajectory:
    """`truth`'s flight plan delayed by static_s + ramp_s: at rest for static_s, a straight level acceleration to its
    speed over ramp_s, then the plan; `duration_s` in all."""
    p = truth.profile
    shift = static_s + ramp_s

    def later(st: SmoothSteps) -> SmoothSteps:
        return SmoothSteps(st.a + shift, st.T, st.delta)

    prof = _RampedProfile(p.lat0, p.lon0, p.h0, p.t0, p.p0_l.copy(), p.speed, p.heading0, later(p.turn),
                          later(p.climb), p.aoa_rad, p.crab_rad, ramp=SmoothSteps([static_s], [ramp_s], [1.0]))
    rate = truth.rate_hz
    n = int(np.floor(duration_s * rate + 1e-9)) + 1
    t = p.t0 + np.arange(n) / rate
    inc = prof.horizontal_increment(t[:-1], t[1:])
    p_l = np.zeros((n, 3))
    p_l[:, :2] = prof.p0_l[:2] + np.vstack([np.zeros(2), np.cumsum(inc, axis=0)])
    p_l[:, 2] = prof.p0_l[2] - prof.climb.evaluate(t - p.t0)[0]
    out = assemble_trajectory(prof, t, p_l, with_increments=True, rate_hz=rate)
    t_end = float(t[-1])
    out.segments = [Segment("static", p.t0, p.t0 + static_s), Segment("takeoff", p.t0 + static_s, p.t0 + shift)]
    out.segments += [Segment(s.kind, s.t_start + shift, min(s.t_end + shift, t_end), s.index, s.height_agl,
                             s.heading_deg) for s in truth.segments if s.t_start + shift < t_end]
    return out


def laser_ranges(truth: TrueTrajectory, t: np.ndarray, ground_height, axis_b=(0.0, 0.0, 1.0), sigma_m: float = 0.3,
                 seed: int = 0) -> np.ndarray:
    """Laser ranges (m) along the body axis `axis_b` (FRD) to flat ground at ellipsoidal height(s), with noise."""
    s = truth.at(t)
    d_ned = np.einsum("nij,j->ni", s.R_body_to_ned, np.asarray(axis_b, float) / np.linalg.norm(axis_b))
    rng = np.random.default_rng(seed)
    return (s.h - np.asarray(ground_height, float)) / d_ned[:, 2] + rng.standard_normal(len(t)) * sigma_m


def write_gnss_csv(path: str | Path, fx: GnssFixes) -> None:
    """The fixes as dgcal's gnss.csv (`dgcal pos --gnss`): gps_week,gps_sow,x,y,z, the ECEF covariance as sigmas and
    signed square roots of the cross terms (sx,sy,sz,sxy,sxz,syz, m), velocity and its ECEF sigmas (m/s)."""
    geo = ecef_to_geodetic(fx.p_ecef)
    R_ned_to_ecef = np.swapaxes(R_ecef_to_ned(geo[:, 0], geo[:, 1]), 1, 2)
    C_ned = fx.cov_ned if fx.cov_ned is not None else np.einsum("ni,ij->nij", fx.sigma_ned ** 2, np.eye(3))
    C = R_ned_to_ecef @ C_ned @ np.swapaxes(R_ned_to_ecef, 1, 2)
    Cv = R_ned_to_ecef @ np.einsum("ni,ij->nij", fx.sigma_v_ned ** 2, np.eye(3)) @ np.swapaxes(R_ned_to_ecef, 1, 2)
    w, sow = week_sow(fx.t)
    cols = [w.astype(int), sow, fx.p_ecef, np.sqrt(np.einsum("nii->ni", C)), cov_to_sqvar(C[:, 0, 1]),
            cov_to_sqvar(C[:, 0, 2]), cov_to_sqvar(C[:, 1, 2]), fx.v_ecef, np.sqrt(np.einsum("nii->ni", Cv))]
    rows = np.column_stack(cols)
    with atomic_write(path) as fh:
        fh.write("gps_week,gps_sow,x,y,z,sx,sy,sz,sxy,sxz,syz,vx,vy,vz,svx,svy,svz\n")
        np.savetxt(fh, rows, delimiter=",", fmt=["%d", "%.4f"] + ["%.4f"] * 3 + ["%.5f"] * 6 + ["%.4f"] * 3
                   + ["%.5f"] * 3)


def write_lowcost_dataset(out: str | Path, f: LowcostFlight, seed: int = 0, event_interval_s: float = 2.0) -> None:
    """Write a simulated low-cost flight into `out`: imu.csv, gnss_fixes.csv (t_gps, ECEF m and m/s, NED sigmas;
    `dgcal.pos.lowcost.fix_files.read_gnss_fixes`), gnss.csv (the same as dgcal's gnss.csv for `dgcal pos
    --gnss`), events.csv (an image every `event_interval_s` s on the legs), truth_trajectory.csv (t_gps, lat,
    lon, h, NED velocity, roll/pitch/heading deg; `dgcal pos --truth` reads it), truth.json."""
    with staged_dir(out) as d:
        write_imu_csv(Path(d) / "imu.csv", f.imu)
        write_gnss_fixes(Path(d) / "gnss_fixes.csv", f.fixes)
        write_gnss_csv(Path(d) / "gnss.csv", f.fixes)
        ev = camera_events(f.truth, interval_s=event_interval_s)
        write_events(Path(d) / "events.csv", ev)
        tr = f.truth
        rows = np.column_stack([tr.t, tr.lat, tr.lon, tr.h, tr.v_ned, tr.rph])
        np.savetxt(Path(d) / "truth_trajectory.csv", rows, delimiter=",", fmt="%.9f",
                   header="t_gps,lat,lon,h,vn,ve,vd,roll,pitch,heading", comments="")
        (Path(d) / "truth.json").write_text(json.dumps({"imu_errors": f.imu_errors.as_dict(),
                                                       "h_ground": f.h_ground, "seed": seed,
                                                       "imu_grade": f.imu_errors.grade.name,
                                                       "gnss_outages": [list(o) for o in f.outages]}, indent=1))
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
    fx = flight.fixes
    grade = flight.imu_errors.grade
    u = run_ukf(flight.imu, fx, grade, progress=progress)
    step = max(1, int(round(1.0 / (smoother_rate_hz * np.median(np.diff(fx.t))))))
    s = slice(None, None, step)
    lc = GnssFixes(fx.t[s], fx.p_ecef[s], fx.sigma_ned[s], fx.v_ecef[s], fx.sigma_v_ned[s])
    sm = smooth(flight.imu, lc, grade, SmootherOptions(), mode="lc", frame=u.frame)
    R_body_to_ned_smoothed = sm.frame.R_nav_to_local_ned(sm.p_nav) @ sm.R_body_to_nav
    rph_sm = rph_from_R_body_to_ned(R_body_to_ned_smoothed)
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
            "ukf": {**attitude_error_stats(e_u), "pos_rms_ned_m": pos_u.tolist(),
                    "tilt_rms_deg": float(np.sqrt(np.mean(e_u[:, :2] ** 2))),
                    "attitude_rms_deg": float(np.sqrt(np.mean(e_u ** 2)))},
            "smoother": {**attitude_error_stats(e_s), "pos_rms_ned_m": pos_s.tolist(),
                         "tilt_rms_deg": float(np.sqrt(np.mean(e_s[:, :2] ** 2))),
                         "attitude_rms_deg": float(np.sqrt(np.mean(e_s ** 2)))},
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


# --- the UKF through GNSS outages and from slow or static starts (issue 27) ---------------------------------

SLOW_1MPS = dict(speed=1.0, bank_deg=1.2, height_agl=10.0, climb_rate=0.3, leg_length_m=60.0, loop_width_m=20.0,
                 margin_m=10.0)
MID_10MPS = dict(speed=10.0, bank_deg=15.0, height_agl=60.0, climb_rate=2.0, leg_length_m=500.0, loop_width_m=150.0,
                 margin_m=50.0)
# name -> (flight settings of simulate_lowcost_flight, duration s, GNSS outages (start, length, period) s, static s)
UKF_STUDY_SETTINGS = {
    "26 m/s, 30 s outages": ({}, 240.0, (60.0, 30.0, 120.0), 0.0),
    "10 m/s, 60 s outages": (MID_10MPS, 240.0, (40.0, 60.0, 120.0), 0.0),
    "1 m/s, 10 s outages": (SLOW_1MPS, 240.0, (60.0, 10.0, 40.0), 0.0),
    "1 m/s from rest, 60 s outages": (SLOW_1MPS, 300.0, (80.0, 60.0, 120.0), 20.0),
    "26 m/s from rest, 45 s outages": ({}, 240.0, (90.0, 45.0, 150.0), 20.0),
    "10 m/s from rest, 20 s outages": (MID_10MPS, 200.0, (50.0, 20.0, 50.0), 15.0),
}


def ukf_outage_study(settings: dict | None = None, seeds=range(5), rate_hz: float = 10.0) -> dict:
    """Seed 000's UKF on the low-cost family at other settings (`UKF_STUDY_SETTINGS`: slow platforms, starts at rest,
    GNSS outages): per setting, the RMS and the largest |error| / sigma of roll, pitch, heading, N, E, D (IMU against
    the truth at every state from the first fix, nothing left out for convergence) with GNSS and inside the outages,
    pooled over the seeds; the heading before the course is known (a uniform heading's sigma) is left out of the
    heading column and counted apart. Returns {name: {"with_gnss"|"outages": {"rms": [6], "max": [6], "n"},
    "heading_unknown_epochs": n, "max_heading_unknown_z": z}}."""
    out = {}
    for name, (kw, dur, outages, static) in (settings or UKF_STUDY_SETTINGS).items():
        pools = {"with_gnss": [], "outages": []}
        n_unknown, z_unknown = 0, 0.0
        for seed in seeds:
            f = simulate_lowcost_flight(duration_s=dur, seed=seed, gnss_outages=outages, static_s=static, **kw)
            u = run_ukf(f.imu, f.fixes, f.imu_errors.grade, rate_hz=rate_hz)
            e_att = np.radians(_rph_error(f.truth, u.t, u.rph_deg))
            z_att = e_att / np.sqrt(np.einsum("kii->ki", u.P[:, 6:9, 6:9]))
            e_pos = u.p_nav - u.frame.from_ecef(f.truth.at(u.t).p_ecef)
            z = np.column_stack([z_att, e_pos / u.sigma_p_nav])
            unknown = ~u.heading_known
            n_unknown += int(unknown.sum())
            z_unknown = max(z_unknown, float(np.abs(z[unknown, 2]).max()) if unknown.any() else 0.0)
            z[unknown, 2] = np.nan
            inside = np.zeros(len(u.t), bool)
            for a, b in f.outages:
                inside |= (u.t >= a) & (u.t < b)
            pools["with_gnss"].append(z[~inside])
            pools["outages"].append(z[inside])
        row = {}
        for k, zs in pools.items():
            z = np.vstack(zs)
            row[k] = {"rms": np.sqrt(np.nanmean(z ** 2, axis=0)).round(3).tolist(),
                      "max": np.nanmax(np.abs(z), axis=0).round(3).tolist(), "n": int(len(z))}
        row.update(heading_unknown_epochs=n_unknown, max_heading_unknown_z=round(z_unknown, 3))
        out[name] = row
    return out


def format_outage_study(study: dict) -> str:
    """`ukf_outage_study` as the Markdown table of docs/lowcost_payload.md (roll/pitch/heading/N/E/D)."""
    f = lambda v: "/".join(f"{x:.2f}" for x in v)  # noqa: E731
    lines = ["| setting | with GNSS | inside the outages | max \\|error\\|/sigma |", "|---|---|---|---|"]
    for name, r in study.items():
        mx = np.maximum(r["with_gnss"]["max"], r["outages"]["max"])
        lines.append(f"| {name} | {f(r['with_gnss']['rms'])} | {f(r['outages']['rms'])} | {f(mx)} |")
    return "\n".join(lines)


# --- single-image georeferencing campaign (seed 000 sec. 5.3, Table 6, Fig. 19) ---------------------------


def seed_camera(scale: float = 1.0):
    """The seed's still camera class: 4272 x 2848 px, 135.7 x 90.4 m footprint at 110 m, mild barrel distortion."""
    w, h = int(round(4272 * scale)), int(round(2848 * scale))
    f = 0.5 * w / (0.5 * 135.7 / 110.0)
    return Fraser7.from_dict((w, h), {"f": f, "cx": (w - 1) / 2 + 6 * scale, "cy": (h - 1) / 2 - 4 * scale,
                                      "K1": -0.04, "K2": 0.01})


def terrain_dem(center_w: np.ndarray, half_size_m: float = 600.0, step_m: float = 2.0, slope=(0.03, -0.02),
                hill_m: float = 6.0, hill_sigma_m: float = 60.0):
    """A synthetic DEM (dgcal.calib.dg.dem.Dem, world E/N/Up frame) around `center_w`: a gentle slope plus a hill."""
    n = int(round(2 * half_size_m / step_m)) + 1
    x = center_w[0] - half_size_m + step_m * np.arange(n)
    y = center_w[1] + half_size_m - step_m * np.arange(n)  # north-up rows
    X, Y = np.meshgrid(x, y)
    dx, dy = X - center_w[0], Y - center_w[1]
    H = center_w[2] + slope[0] * dx + slope[1] * dy + hill_m * np.exp(
        -((dx - 40.0) ** 2 + (dy + 30.0) ** 2) / (2 * hill_sigma_m ** 2))
    return Dem(H, np.array([[step_m, 0.0, x[0]], [0.0, -step_m, y[0]]]))


def _ray_dem_hit(C_world, d, dem):
    X, ok = intersect_dem(np.asarray(C_world, float), np.atleast_2d(d), dem, 0.0, 50, 1e-6)
    return X[0]


def georef_campaign(n_images: int = 15, seed: int = 0, sigma_px: float = 1.0, laser_sigma_m: float = 0.5,
                    trigger_interval_s: float = 0.5, progress: bool = False) -> dict:
    """Seed 000's geo-referencing study on a simulated flight: 15 images of a reference point taken on the
    straight legs, georeferenced with raw data (level attitude, no distortion correction), with distortion
    removed, with the UKF attitude (known point height), with the laser range, and with a DEM; plus true
    poses. Returns the per-image table (seed Table 6), mean/std rows and the 15-image averages (Fig. 19)."""
    truth = simulate_true_trajectory("fixed-wing", lat0=39.65, lon0=-79.95, h_ground=300.0, heights_agl=(113.0,),
                                     n_strips=3, strip_length_m=500.0, strip_spacing_m=0.0, strip_heading_deg=225.0,
                                     speed=26.0, bank_deg=25.0, climb_rate=4.0, aoa_deg=2.0, rate_hz=50.0)
    imu, err = simulate_imu(truth, "adis16405", seed=seed)
    fixes, _ = gnss_fixes(truth, 50.0, seed=seed + 1)
    frame = NavFrame.at_ecef(fixes.p_ecef.mean(axis=0))
    rng = np.random.default_rng(seed + 7)
    # reference point ("fire hydrant") 18 m right of the leg centre line, on the DEM
    c_w = _to_world(frame, geodetic_to_ecef_np(39.65, -79.95, 300.0))
    dem = terrain_dem(c_w)
    psi = np.radians(225.0)
    across_w = np.array([np.cos(psi + np.pi / 2), np.sin(psi + np.pi / 2)])[[1, 0]]  # (E, N) of "right"
    P_xy = c_w[:2] + 18.0 * across_w + np.array([6.0, -9.0])
    P_world = np.array([P_xy[0], P_xy[1], float(dem.height(P_xy[0], P_xy[1]))])
    camera = seed_camera()
    lever = np.array([0.10, 0.0, 0.05])
    rows = _exposures(truth, fixes, frame, camera, lever, P_world, dem, rng, n_images, sigma_px, laser_sigma_m,
                      trigger_interval_s)
    # the filter runs up to the last exposure (its states are causal); map exposures to its epochs
    t_last = rows[-1]["t"] + 1.0
    keep = fixes.t <= t_last
    u = run_ukf(imu.between(imu.t[0], t_last), GnssFixes(fixes.t[keep], fixes.p_ecef[keep], fixes.sigma_ned[keep],
                                                           fixes.v_ecef[keep], fixes.sigma_v_ned[keep]),
                err.grade, frame=frame, progress=progress)
    iu = {round(float(t), 4): i for i, t in enumerate(u.t)}
    for r in rows:
        r["j"] = iu[round(r["t"], 4)]
    # GNSS errors are time-correlated: filtering white-noise-modelled 50 Hz fixes does not beat the
    # receiver's own accuracy, so the camera position covariance is at least the fix covariance
    gnss_cov = np.diag(fixes.sigma_ned[0][[1, 0, 2]] ** 2)
    pinhole = Fraser7.from_dict(camera.image_size, {"f": camera["f"], "cx": camera["cx"], "cy": camera["cy"]})
    cases = {"raw": [], "distortion": [], "attitude": [], "laser": [], "dem": [], "truth": []}
    covs = {k: [] for k in cases}
    table = []
    for r in rows:
        rph = u.rph_deg[r["j"]]
        est = _estimates(u, r, camera, pinhole, lever, P_world, dem, gnss_cov, sigma_px, laser_sigma_m)
        row = {"image": f"IMG_{7242 + len(table):04d}", "t_gps": r["t"], "pitch_deg": float(rph[1]),
               "roll_deg": float(rph[0]), "yaw_deg": float(rph[2]), "laser_range_m": r["rho"],
               "ground_speed_mps": r["speed"],
               "offset_from_centre_N_m": float(P_world[1] - r["centre_true"][1]),
               "offset_from_centre_E_m": float(P_world[0] - r["centre_true"][0])}
        for k, e in est.items():
            d = e.xyz[0, :2] - P_world[:2]
            cases[k].append(d)
            covs[k].append(e.cov[0, :2, :2])
            row[k] = {"dN_m": float(d[1]), "dE_m": float(d[0]), "total_m": float(np.hypot(*d)),
                      "sigma_N_m": float(e.sigma[0, 1]), "sigma_E_m": float(e.sigma[0, 0])}
        table.append(row)
    summary = {k: _case_summary(np.array(cases[k]), np.array(covs[k]), P_world,
                                None if k == "truth" else gnss_cov[:2, :2]) for k in cases}
    rph_true = np.array([rph_from_R_body_to_ned(truth.at(r["t"]).R_body_to_ned[0]) for r in rows])
    return {"images": table, "summary": summary, "n_images": len(table), "sigma_px": sigma_px,
            "reference_point_w": P_world.tolist(), "mean_height_agl_m": float(np.mean([r["C_true"][2] for r in rows])
                                                                            - P_world[2]),
            "ukf_attitude_rms_deg": np.sqrt(np.mean((np.array([x["roll_deg"] for x in table]) - rph_true[:, 0]) ** 2
                                                    )).tolist(),
            "pixel_ground_size_m": float(np.mean([x["laser_range_m"] for x in table]) / camera["f"])}


_R_NED_TO_WORLD = R_ENU_TO_NED.T  # the georeferencing world: ENU axes of the UKF's tangent frame


def _to_world(frame: NavFrame, p_ecef: np.ndarray) -> np.ndarray:
    """World (ENU axes of the UKF's tangent frame `frame`, m) of ECEF points (m)."""
    return frame.from_ecef(p_ecef) @ _R_NED_TO_WORLD.T


def _exposures(truth: TrueTrajectory, fixes: GnssFixes, frame: NavFrame, camera, lever: np.ndarray,
               P_world: np.ndarray, dem: Dem, rng, n_images: int, sigma_px: float, laser_sigma_m: float,
               trigger_interval_s: float) -> list[dict]:
    """The first `n_images` exposures on the straight legs (on the logger's 50 Hz grid) that see the reference
    point `P_world` well inside the frame: time, noisy pixel (px), true pose (world), noisy laser range (m)."""
    w, h = camera.image_size
    rows = []
    t_fix = fixes.t
    for s in truth.strips:
        tt = np.arange(s.t_start, s.t_end, trigger_interval_s)
        k = np.clip(np.searchsorted(t_fix, tt), 0, len(t_fix) - 1)  # exposures on the logger's 50 Hz grid
        for j in np.unique(k):
            if len(rows) >= n_images:
                break
            tr = truth.at(t_fix[j])
            R_body_to_world = _R_NED_TO_WORLD @ frame.R_nav_to_ecef.T @ tr.R_body_to_ecef[0]
            C_world_true = _to_world(frame, tr.p_ecef[0]) + R_body_to_world @ lever
            R_cam_to_world_true = R_body_to_world @ R_CAM_TO_BODY_NADIR
            X_c = R_cam_to_world_true.T @ (P_world - C_world_true)
            if X_c[2] <= 0:
                continue
            uv_true = camera.project(X_c[None])[0]
            if not (0.05 * w < uv_true[0] < 0.95 * w and 0.05 * h < uv_true[1] < 0.95 * h):
                continue
            uv = uv_true + rng.standard_normal(2) * sigma_px
            centre_hit = _ray_dem_hit(C_world_true, R_cam_to_world_true[:, 2], dem)
            rho = float(np.linalg.norm(centre_hit - C_world_true)) + rng.standard_normal() * laser_sigma_m
            rows.append(dict(j=int(j), t=float(t_fix[j]), uv=uv, C_true=C_world_true, R_true=R_cam_to_world_true,
                             rho=rho, centre_true=centre_hit, speed=float(np.linalg.norm(tr.v_ned[0]))))
        if len(rows) >= n_images:
            break
    if len(rows) < n_images:
        raise RuntimeError(f"only {len(rows)} images see the reference point")
    return rows


def _estimates(u, r: dict, camera, pinhole, lever: np.ndarray, P_world: np.ndarray, dem: Dem, gnss_cov: np.ndarray,
               sigma_px: float, laser_sigma_m: float) -> dict:
    """The reference point from exposure `r` by each case: raw (level attitude, GNSS course, no distortion),
    distortion, attitude (UKF), laser, DEM and true pose."""
    j = r["j"]
    P_nav = u.P[j]
    R_ned_to_world = _R_NED_TO_WORLD
    r_imu_world = R_ned_to_world @ u.p_nav[j]
    rph = u.rph_deg[j]
    R_body_to_world = R_ned_to_world @ R_body_to_ned_from_rph_np(rph)
    C_world, R_cam_to_world = r_imu_world + R_body_to_world @ lever, R_body_to_world @ R_CAM_TO_BODY_NADIR
    cov_rph = np.degrees(np.degrees(P_nav[6:9, 6:9]))
    cov_p = np.maximum(R_ned_to_world @ P_nav[0:3, 0:3] @ R_ned_to_world.T, gnss_cov)
    pose_cov = pose_covariance_from_rph(rph, cov_rph, cov_p, R_CAM_TO_BODY_NADIR, R_enu_to_world=np.eye(3))
    # raw data: level attitude, heading from the GNSS course, no distortion model
    v = u.v_nav[j]
    course = np.degrees(np.arctan2(v[1], v[0]))
    R_body_to_world_level = R_ned_to_world @ R_body_to_ned_from_rph_np(np.array([0.0, 0.0, course]))
    C_world_level = r_imu_world + R_body_to_world_level @ lever
    R_cam_to_world_level = R_body_to_world_level @ R_CAM_TO_BODY_NADIR
    lvl_cov = pose_covariance_from_rph(np.array([0.0, 0.0, course]), np.array([3.0, 3.0, 3.0]) ** 2,
                                       cov_p, R_CAM_TO_BODY_NADIR, np.eye(3))
    level = (C_world_level, R_cam_to_world_level)
    pose = (C_world, R_cam_to_world)
    return {"raw": georeference(pinhole, r["uv"], *level, height=P_world[2], pose_cov=lvl_cov, sigma_px=sigma_px),
            "distortion": georeference(camera, r["uv"], *level, height=P_world[2], pose_cov=lvl_cov,
                                       sigma_px=sigma_px),
            "attitude": georeference(camera, r["uv"], *pose, height=P_world[2], pose_cov=pose_cov, sigma_px=sigma_px),
            "laser": georeference(camera, r["uv"], *pose, range_m=r["rho"], pose_cov=pose_cov, sigma_px=sigma_px,
                                  sigma_range=laser_sigma_m),
            "dem": georeference(camera, r["uv"], *pose, dem=dem, pose_cov=pose_cov, sigma_px=sigma_px,
                                sigma_height=0.1),
            "truth": georeference(camera, r["uv"], r["C_true"], r["R_true"], height=P_world[2], sigma_px=sigma_px)}


def _case_summary(d: np.ndarray, covs: np.ndarray, P_world: np.ndarray, common_cov: np.ndarray | None) -> dict:
    """Mean, spread and averaged error (m) of one case's horizontal errors d (n,2) (E, N) with covariances (n,2,2)."""
    tot = np.hypot(d[:, 0], d[:, 1])
    av = average_estimates(d + P_world[:2], covs, common_cov=common_cov)
    z = np.array([np.sqrt(x @ np.linalg.solve(c, x) / 2) for x, c in zip(d, covs)])
    return {"mean_dN_m": float(d[:, 1].mean()), "mean_dE_m": float(d[:, 0].mean()),
            "mean_total_m": float(tot.mean()), "std_total_m": float(tot.std(ddof=1)),
            "std_dN_m": float(d[:, 1].std(ddof=1)), "std_dE_m": float(d[:, 0].std(ddof=1)),
            "average_error_m": float(np.hypot(*(av.mean - P_world[:2]))),
            "weighted_average_error_m": float(np.hypot(*(av.weighted - P_world[:2]))),
            "weighted_average_sigma_m": float(np.sqrt(np.trace(av.cov_weighted))),
            "weighted_average_sigma_common_m": float(np.sqrt(np.trace(av.cov_with_common))),
            "chi2_dof": av.chi2_dof, "normalised_error_rms": float(np.sqrt(np.mean(z ** 2)))}


def geodetic_to_ecef_np(lat, lon, h) -> np.ndarray:
    return np.asarray(geodetic_to_ecef(lat, lon, h), float)


def R_body_to_ned_from_rph_np(rph) -> np.ndarray:
    return R_body_to_ned_from_rph(*np.asarray(rph, float))


def format_table6(rep: dict) -> str:
    """Seed Table 6 layout: per image attitude, range, speed, offset and errors (N, E, total) per case."""
    cases = ("raw", "distortion", "attitude", "laser", "dem", "truth")
    hdr = f"{'image':9s}{'pitch':>6s}{'roll':>6s}{'yaw':>7s}{'range':>7s}{'gs':>6s}{'offN':>6s}{'offE':>6s}"
    hdr += "".join(f"{c[:9]:>21s}" for c in cases)
    out = [hdr]
    for r in rep["images"]:
        s = (f"{r['image']:9s}{r['pitch_deg']:6.2f}{r['roll_deg']:6.2f}{r['yaw_deg']:7.1f}{r['laser_range_m']:7.1f}"
             f"{r['ground_speed_mps']:6.1f}{r['offset_from_centre_N_m']:6.1f}{r['offset_from_centre_E_m']:6.1f}")
        s += "".join(f"{r[c]['dN_m']:7.2f}{r[c]['dE_m']:7.2f}{r[c]['total_m']:7.2f}" for c in cases)
        out.append(s)
    sm = rep["summary"]
    out.append(f"{'mean':51s}" + "".join(f"{sm[c]['mean_dN_m']:7.2f}{sm[c]['mean_dE_m']:7.2f}"
                                          f"{sm[c]['mean_total_m']:7.2f}" for c in cases))
    out.append(f"{'std':51s}" + "".join(f"{sm[c]['std_dN_m']:7.2f}{sm[c]['std_dE_m']:7.2f}"
                                         f"{sm[c]['std_total_m']:7.2f}" for c in cases))
    out.append(f"{'avg of n':51s}" + "".join(f"{'':14s}{sm[c]['average_error_m']:7.2f}" for c in cases))
    return "\n".join(out)
