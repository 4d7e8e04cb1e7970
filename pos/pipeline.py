"""`dgcal pos`: RINEX -> SPP or PPK antenna positions; IMU + RINEX (or GNSS positions) + events -> smoothed trajectory.

`process(...)` works on in-memory data (tests, simulator); `run_pos(PosOptions)` reads the files and runs
it, `run_spp(PosOptions)` is `--mode spp`, `run_ppk(PosOptions)` is `--mode ppk` (rover + base carrier
phase); dgcal.reports.pos.write_pos_outputs, dgcal.reports.gnss.write_spp_outputs and
dgcal.reports.ppk.write_ppk_outputs write their files.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
from scipy.special import chdtri
from threadpoolctl import threadpool_limits

from dgcal.fields.constants import G0, SECONDS_PER_WEEK
from dgcal.fields.crs import ecef_to_geodetic, geodetic_to_ecef
from dgcal.fields.errors import InputError, ResultError
from dgcal.fields.frames import R_ecef_to_enu, R_ecef_to_ned
from dgcal.fields.processes import fork_map
from dgcal.pos.gnss.carrier import carrier_observations
from dgcal.pos.gnss.dd import DDOptions, carrier_front_end, imu_aided_front_end
from dgcal.pos.gnss.observations import GnssObservations
from dgcal.pos.gnss.ppk import PpkOptions, PpkResult, ppk, ppk_summary
from dgcal.pos.gnss.rinex import calendar_from_gps_seconds, read_rinex_nav, read_rinex_obs
from dgcal.pos.gnss.rinex_obs import read_obs_file
from dgcal.pos.gnss.spp import SppOptions, prepare_epochs, solve_epoch, spp, spp_summary
from dgcal.pos.events import read_any_events
from dgcal.pos.gnss.solution_files import GnssSolution, read_gnss_solution, select_quality
from dgcal.pos.ins.error_model import imu_grade
from dgcal.pos.ins.imu_data import read_imu_csv, read_kf_gins
from dgcal.pos.ins.imu_formats import imu_format, read_imu
from dgcal.pos.ins.integrity import ImuIntegrity, ImuIntegrityOptions, check_imu
from dgcal.pos.ins.interpolate import interpolate_trajectory, trajectory_at_events
from dgcal.pos.ins.ulog import is_ulog, read_ulog_imu
from dgcal.pos.lowcost.ukf import UkfOptions
from dgcal.pos.lowcost.ukf_pos import UKF_SETTINGS, UkfPosResult, process_ukf, read_true_trajectory
from dgcal.pos.ros_bags import is_ros_bag, read_rosbag_imu, read_rosbag_navsatfix
from dgcal.pos.smoother.batch import SmootherOptions, smooth
from dgcal.pos.smoother.forward_filter import forward_solution, linear_forward_solution
from dgcal.pos.smoother.initial import GnssFixes
from dgcal.pos.smoother.integrity import gnss_warnings
from dgcal.pos.smoother.output import densify, solution_trajectory
from dgcal.pos.smoother.time_offset import estimate_time_offset, shifted_imu, smoother_chi2


@dataclass
class PosResult:
    """Everything the pipeline produced: smoothed and forward solutions, trajectories, GNSS inputs."""

    mode: str
    smoothed: object  # NavSolution
    forward: object | None
    trajectory: object  # dgcal.fields.io.formats.Trajectory at the output rate
    keyframes: object  # Trajectory at the keyframes
    forward_keyframes: object | None
    events: object | None
    spp: object | None = None
    fixes: GnssFixes | None = None
    summary: dict = field(default_factory=dict)
    carrier: object | None = None  # dgcal.pos.gnss.dd.CarrierFrontEnd (TC with a base station)


def fixes_from_spp(sol) -> GnssFixes:
    """GnssFixes (antenna ECEF, NED sigmas) from a dgcal.pos.gnss.spp.SppSolution's epochs with a fix."""
    ok = sol.ok
    p = sol.p_ecef[ok]
    geo = ecef_to_geodetic(p)
    Rn = R_ecef_to_ned(geo[:, 0], geo[:, 1])
    cp = Rn @ sol.cov_p[ok] @ np.swapaxes(Rn, 1, 2)
    cv = Rn @ sol.cov_v[ok] @ np.swapaxes(Rn, 1, 2)
    s_p = np.sqrt(np.einsum("nii->ni", cp))
    s_v = np.sqrt(np.einsum("nii->ni", cv))
    v = sol.v_ecef[ok]
    good_v = np.all(np.isfinite(v), axis=1) & np.all(np.isfinite(s_v), axis=1)
    v = np.where(good_v[:, None], v, np.nan)
    return GnssFixes(sol.t_gps[ok], p, s_p, v, np.where(good_v[:, None], s_v, np.nan))


def fixes_from_solution(sol: GnssSolution) -> GnssFixes:
    """GnssFixes (antenna ECEF, NED sigmas and full NED covariance, velocities) from a GNSS solution file."""
    s_v = None
    if sol.cov_v_ned is not None:
        s_v = np.sqrt(np.clip(np.einsum("nii->ni", sol.cov_v_ned), 0, None))
    v = sol.v_ecef
    if v is not None and s_v is not None:
        good = np.all(np.isfinite(v), axis=1) & np.all(np.isfinite(s_v), axis=1) & np.all(s_v > 0, axis=1)
        v = np.where(good[:, None], v, np.nan)
        s_v = np.where(good[:, None], s_v, np.nan)
    cov = sol.cov_ned.copy()
    # RTKLIB prints 4 decimals: a zero sigma would be an infinitely sure fix; floor at 1 mm
    s = np.sqrt(np.clip(np.einsum("nii->ni", cov), 0, None))
    floor = np.maximum(s, 1e-3)
    scale = floor / np.where(s > 0, s, 1.0)
    cov = cov * scale[:, :, None] * scale[:, None, :]
    cov[:, [0, 1, 2], [0, 1, 2]] = floor ** 2
    # a covariance that rounding made indefinite keeps only its diagonal
    bad = np.linalg.eigvalsh(cov)[:, 0] <= 0
    cov[bad] = np.einsum("ni,ij->nij", floor[bad] ** 2, np.eye(3))
    return GnssFixes(sol.t, sol.p_ecef, floor, v, s_v, cov)


def tc_epochs(raw, nav, spp_sol, opts):
    """GNSS epochs for the TC smoother: SPP's modelled epochs where it had a fix; elsewhere (fewer than four
    satellites, RAIM failure) the raw epoch modelled at the SPP track interpolated in time."""
    ok = spp_sol.ok
    if ok.sum() < 2:
        raise InputError("fewer than two epochs with a GNSS fix: cannot initialise", raw.source or None)
    t_ok = spp_sol.t_gps[ok]
    p_ok = spp_sol.p_ecef[ok]
    out = [spp_sol.epochs[i] if ok[i] else None for i in range(len(raw.epochs))]
    redo = [i for i, e in enumerate(out) if e is None]
    if redo:
        t = np.array([raw.epochs[i].t_gps for i in redo])
        p = np.stack([np.interp(t, t_ok, p_ok[:, j]) for j in range(3)], axis=1)
        for i, m in zip(redo, prepare_epochs([raw.epochs[i] for i in redo], nav, p, opts)):
            out[i] = m if m.n > 0 else None
    epochs = [e for e in out if e is not None]
    return GnssObservations(epochs=epochs, receiver=raw.receiver, p_approx_ecef=np.median(p_ok, axis=0),
                            signals=raw.signals, source=raw.source)


def process(mode: str, imu, grade, lever_arm_b, *, raw_obs=None, nav=None, spp_opts=None,
            lc_fixes: GnssFixes | None = None, events=None, rate_hz: float = 10.0, forward: bool | str = True,
            smoother_opts=None, progress: bool = False, carrier: tuple | None = None,
            ppk_opts: PpkOptions | None = None, dd_opts: DDOptions | None = None,
            imu_checks: ImuIntegrityOptions | None = None, estimate_imu_time_offset: bool = False) -> PosResult:
    """Run SPP (when RINEX is given), the smoother (TC or LC), the forward solution and the outputs in memory.

    The IMU data are checked first (dgcal.pos.ins.integrity.check_imu: order, duplicates, gaps, spikes; a gap
    too long to bridge is a ResultError) and the GNSS epochs screened in the smoother; what was found is in
    `summary['integrity']` and one line per finding in `summary['warnings']`.

    carrier: (rover, base `dgcal.pos.gnss.carrier.CarrierObs`, base ECEF m) for TC with carrier phase: PPK, the
    arcs' integers and the double differences (`dgcal.pos.gnss.dd.carrier_front_end`) replace the pseudoranges.

    forward: True for the forward solution and normalised innovations of the smoother's problem linearised at its
    solution (`linear_forward_solution`, cheap), "filter" for the iterated filter about its own estimates
    (`forward_solution`), False for none.

    estimate_imu_time_offset: the IMU-GNSS time offset estimated from the smoother's chi-square profile
    (`dgcal.pos.smoother.time_offset`, 7-11 smoothings without covariances), applied to the IMU's time tags and
    reported with its sigma in `summary['imu_time_offset']`; a ResultError when the data cannot determine it.
    """
    if mode not in ("tc", "lc"):
        raise InputError(f"mode must be tc or lc, not {mode!r}", field="--mode")
    opts = smoother_opts or SmootherOptions()
    opts.lever_arm_b = np.asarray(lever_arm_b, float)
    imu, imu_report = check_imu(imu, imu_checks)
    spp_sol = fixes = gnss = None
    timing = {}
    t0 = time.perf_counter()
    if raw_obs is not None:
        spp_opts = spp_opts or SppOptions()
        spp_sol = spp(raw_obs, nav, spp_opts, progress=progress)
        fixes = fixes_from_spp(spp_sol)
        if mode == "tc":
            gnss = tc_epochs(raw_obs, nav, spp_sol, spp_opts)
    timing["gnss_front_end_s"] = time.perf_counter() - t0
    if mode == "lc" and lc_fixes is None:
        lc_fixes = fixes
    if fixes is None:
        fixes = lc_fixes
    if fixes is None:
        raise InputError("no GNSS data: give RINEX observations and navigation (or --gnss for lc)",
                         field="--rinex-obs")
    if mode == "tc" and gnss is None:
        raise InputError("tc mode needs RINEX observations and navigation", field="--rinex-obs")
    fe = None
    if mode == "tc" and carrier is not None:
        t0 = time.perf_counter()
        rover_co, base_co, base_ecef = carrier
        po = ppk_opts or PpkOptions(humidity=0.7, solution="forward", iono_ppm=0.0, tropo_zenith_m=0.0)
        with threadpool_limits(1):        # small matrices: BLAS threads only cost
            fe = carrier_front_end(rover_co, base_co, nav, base_ecef, (fixes.t, fixes.p_ecef), po, dd_opts,
                                   p_init=fixes.p_ecef[0])
        fixes = fixes_with_ppk(fixes, fe.ppk)
        timing["carrier_front_end_s"] = time.perf_counter() - t0
    offset = None
    if estimate_imu_time_offset:
        t0 = time.perf_counter()
        offset = estimate_time_offset(smoother_chi2(imu, fixes, grade, opts, mode, gnss, lc_fixes,
                                                    fe.input if fe is not None else None))
        if not (np.isfinite(offset.sigma_s) and abs(offset.offset_s) < 10.0):
            why = offset.note or "the chi-square profile has no minimum within 10 s"
            raise ResultError(f"the IMU time offset cannot be estimated from these data ({why}); give it with "
                              "--imu-time-offset", field="--estimate-imu-time-offset")
        imu = shifted_imu(imu, offset.offset_s)
        timing["time_offset_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sol = smooth(imu, fixes, grade, opts, mode=mode, gnss=gnss, lc_fixes=lc_fixes,
                 carrier=fe.input if fe is not None else None)
    timing["smoother_s"] = time.perf_counter() - t0
    if fe is not None and opts.covariances:
        # IMU-aided integers: where PPK stayed float, the smoother's antenna positions vote for the arcs' integers;
        # arcs that gain one make the smoother run again with them
        t0 = time.perf_counter()
        aided = imu_aided_front_end(fe, *antenna_track(sol, lever_arm_b), dd_opts)
        if aided is not None:
            fe = aided
            sol = smooth(imu, fixes, grade, opts, mode=mode, gnss=gnss, lc_fixes=lc_fixes, carrier=fe.input)
        timing["imu_aided_integers_s"] = time.perf_counter() - t0

    def forward_pass():
        t0 = time.perf_counter()
        fw = forward_solution(sol.problem, sol.values) if forward == "filter" else \
            linear_forward_solution(sol.problem, sol.values, sol.rows) if forward else None
        return fw, time.perf_counter() - t0

    def outputs():
        t0 = time.perf_counter()
        dense = densify(sol, sol.problem, imu, rate_hz)
        ev = trajectory_at_events(dense, events) if events is not None and len(events) else None
        return dense, ev, time.perf_counter() - t0

    # independent: the dense trajectory (plain arrays) from a child while this process runs the forward pass
    (fw, timing["forward_s"]), (dense, ev, timing["outputs_s"]) = fork_map([forward_pass, outputs])
    sol.info.setdefault("timing", {}).update({k: round(v, 2) for k, v in timing.items()})
    res = PosResult(mode, sol, fw, dense, solution_trajectory(sol), solution_trajectory(fw) if fw else None, ev,
                    spp_sol, fixes, carrier=fe)
    res.summary = summarize(res)
    if offset is not None:
        res.summary["imu_time_offset"] = offset.as_dict()
    add_integrity(res.summary, imu_report, sol.info.get("gnss_rejected", []))
    if fe is not None:
        res.summary["carrier"] = carrier_summary(res)
    return res


def add_integrity(summary: dict, imu_report: ImuIntegrity | None = None, gnss_rejected: list | None = None,
                  rinex_warnings: list | None = None) -> None:
    """Put the data-integrity findings into a summary: `integrity` (IMU issues and bridges, rejected GNSS
    epochs and observations, RINEX record problems) and one line per finding in `warnings` (appended)."""
    it = summary.setdefault("integrity", {})
    w = summary.setdefault("warnings", [])
    if imu_report is not None:
        it["imu"] = imu_report.summary()
        w += imu_report.warnings()
    if gnss_rejected is not None:
        it["gnss_rejected"] = [{k: v for k, v in r.items() if k != "keyframe"} for r in gnss_rejected]
        w += gnss_warnings(gnss_rejected)
    if rinex_warnings:
        it.setdefault("rinex", []).extend(rinex_warnings)
        w += list(rinex_warnings)


def fixes_with_ppk(fixes: GnssFixes, res: PpkResult) -> GnssFixes:
    """SPP fixes with the positions replaced by PPK's (float or fixed) where it has them (initial track, m)."""
    ok = (res.status >= 2) & np.all(np.isfinite(res.p), axis=1)
    if not ok.any():
        return fixes
    j = np.clip(np.searchsorted(res.t_gps, fixes.t - 1e-3), 0, len(res.t_gps) - 1)
    same = (np.abs(res.t_gps[j] - fixes.t) < 1e-3) & ok[j]
    p = fixes.p_ecef.copy()
    p[same] = res.p[j[same]]
    return GnssFixes(fixes.t, p, fixes.sigma_ned, fixes.v_ecef, fixes.sigma_v_ned, fixes.cov_ned)


def fixes_from_ppk(res: PpkResult, fixed_only: bool = False) -> GnssFixes:
    """LC input from a PPK result: antenna ECEF positions with their full local-NED covariance (m^2) of the epochs
    with a solution (fixed and float, or only fixed); no velocities."""
    ok = (res.status >= (3 if fixed_only else 2)) & np.all(np.isfinite(res.p), axis=1)
    p = res.p[ok]
    geo = ecef_to_geodetic(p).reshape(-1, 3)
    Rn = R_ecef_to_ned(geo[:, 0], geo[:, 1]).reshape(-1, 3, 3)
    C = Rn @ res.P[ok] @ np.swapaxes(Rn, 1, 2)
    s = np.sqrt(np.maximum(np.einsum("nii->ni", C), 1e-8))
    return GnssFixes(res.t_gps[ok], p, s, None, None, C)


def antenna_ecef(sol, lever_arm_b) -> np.ndarray:
    """Antenna positions (K,3) ECEF m of a smoother solution's keyframes (IMU pose + lever arm)."""
    p_nav = sol.p_nav + np.einsum("kij,j->ki", sol.R_body_to_nav, np.asarray(lever_arm_b, float))
    return sol.frame.to_ecef(p_nav)


def antenna_track(sol, lever_arm_b) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The GNSS antenna of a smoothed solution at its keyframes: (t GPS s, ECEF m (K,3) of `antenna_ecef`, 3D position
    sigma m (K,): the IMU position's covariance; the lever arm's attitude part is millimetres)."""
    sig = np.sqrt(np.einsum("kii->k", sol.cov_p_nav)) if sol.cov_pose is not None else np.full(len(sol.t), np.inf)
    return sol.t, antenna_ecef(sol, lever_arm_b), sig


def carrier_summary(res: PosResult) -> dict:
    """TC with carrier phase: PPK fix rate, the arcs' integers, double differences used, slips, TC minus PPK."""
    fe, sol = res.carrier, res.smoothed
    pk = fe.ppk
    lever = sol.problem.lever_arm_b
    p_tc = antenna_ecef(sol, lever)
    j = np.clip(np.searchsorted(pk.t_gps, sol.t - 1e-3), 0, len(pk.t_gps) - 1)
    same = np.abs(pk.t_gps[j] - sol.t) < 1e-3
    st = np.where(same, pk.status[j], 0)
    n_phase = np.array([int(np.sum(d.cur.kind == 0)) if k in sol.problem.dd else 0
                        for k, d in ((k, sol.problem.dd.get(k)) for k in range(len(sol.t)))])
    out = {"ppk_counts": {name: int(np.sum(pk.status == i)) for i, name in enumerate(("none", "single", "float",
                                                                                      "fixed"))},
           "ppk_fix_rate": float(np.mean(pk.status == 3)) if len(pk.status) else 0.0,
           "slips_flagged_rover": pk.slips_rover, "slips_flagged_base": pk.slips_base,
           "integers": fe.integers.info if fe.integers is not None else None, **fe.info,
           "keyframes_with_phase": int(np.sum(n_phase > 0)),
           "keyframes_with_phase_and_lt4_sats": int(np.sum((n_phase > 0) & (sol.n_sat < 4))),
           "dd_rows_dropped": sol.info.get("dd_rows_dropped", 0)}
    tr = np.trace(np.nan_to_num(pk.P[j], nan=np.inf), axis1=1, axis2=2)
    for name, m in (("fixed", st == 3), ("float", (st == 2) & (tr < 1.0))):   # floats good to a metre
        if m.any():
            d = p_tc[m] - pk.p[j[m]]
            out[f"tc_minus_ppk_{name}_rms_m"] = float(np.sqrt(np.mean(np.sum(d ** 2, axis=1))))
    out["ppk_float_epochs_worse_than_1m"] = int(np.sum((st == 2) & (tr >= 1.0)))
    return out


def summarize(res: PosResult) -> dict:
    """Numbers for pos_summary.json: spans, counts, sigmas, residual and innovation statistics."""
    sol = res.smoothed
    s = res.keyframes.sigma
    out = {
        "mode": res.mode, "keyframes": int(len(sol.t)), "t_start_gps": float(sol.t[0]), "t_end_gps": float(sol.t[-1]),
        "nav_frame_origin_deg_m": [sol.frame.lat0, sol.frame.lon0, sol.frame.h0],
        "epochs_with_gnss": int(sol.gnss_update.sum()),
        "epochs_without_gnss_update": int((~sol.gnss_update).sum()),
        "systems": list(sol.info.get("systems", [])),
        "median_sigma_m": np.median(s[:, :3], axis=0).round(4).tolist() if s is not None else None,
        "median_sigma_deg": np.median(s[:, 3:], axis=0).round(5).tolist() if s is not None else None,
        "max_sigma_m": np.max(s[:, :3], axis=0).round(3).tolist() if s is not None else None,
        "gyro_bias_deg_h_mean": np.degrees(sol.bias[:, 3:].mean(0) * 3600).round(3).tolist(),
        "accel_bias_mg_mean": (sol.bias[:, :3].mean(0) / (G0 * 1e-3)).round(4).tolist(),
        "residuals": {k: _stats(v) for k, v in sol.residuals.items()},
        "smoother": {k: sol.info[k] for k in ("lm_iterations", "second_pass_reoptimised", "timing",
                                              "static_start_end_s", "static_white_noise", "imu_noise_used",
                                              "atmosphere_budget_m", "dd_rows_dropped")
                     if k in sol.info},
        "events": int(len(res.events.t)) if res.events is not None else 0,
    }
    if res.forward is not None:
        out["innovations"] = {k: _stats(v) for k, v in res.forward.residuals.items()}
        out["normalised_innovations"] = {k: _nis_stats(v) for k, v in res.forward.info.get("nis", {}).items()}
        d = res.forward.p_nav - sol.p_nav
        out["forward_minus_smoothed_rms_m"] = np.sqrt((d ** 2).mean(0)).round(4).tolist()
    return out


def _nis_stats(rows) -> dict:
    """Normalised innovations of one factor kind: n, the mean NIS per dimension (1 if the filter's predicted
    covariance and the measurement noise are right), and the share of factors beyond the chi-square 99 % point."""
    k, v, m = rows
    return {"n": int(len(v)), "nis_per_dim": float(np.sum(v) / np.sum(m)),
            "rms_normalised": float(np.sqrt(np.sum(v) / np.sum(m))),
            "share_beyond_99pc": float(np.mean(v > chdtri(m, 0.01)))}


def _stats(rows) -> dict:
    k, e, sig = rows
    z = e / sig
    return {"n": int(len(e)), "rms": float(np.sqrt(np.mean(e ** 2))),
            "rms_normalised": float(np.sqrt(np.nanmean(z ** 2))),
            "max_abs": float(np.max(np.abs(e))), "share_beyond_3sigma": float(np.mean(np.abs(z) > 3))}


def load_imu(path, gps_week: int | None = None, fmt=None, overrides=(), tag=None, time_offset_s: float = 0.0):
    """IMU file as `fmt` describes it (a preset name, a TOML description or None, dgcal.pos.ins.imu_formats) with
    `overrides` (KEY=VALUE), the time-tag file `tag` and `time_offset_s` added to every sample time. Without a
    description the content decides: a header with gps_week = dgcal's CSV, else KF-GINS text (sow dθ dv)."""
    path = Path(path)
    if fmt is None and not overrides and tag is None and path.exists() and is_ros_bag(path):
        imu = read_rosbag_imu(path)
        imu.t = imu.t + float(time_offset_s)
        return imu
    if fmt is None and not overrides and tag is None and path.is_file() and is_ulog(path):
        imu = read_ulog_imu(path)
        imu.t = imu.t + float(time_offset_s)
        return imu
    if not path.is_file():
        raise InputError("file not found", path)
    if fmt is None and not overrides and tag is None:
        kind = sniff_imu_file(path)
        imu = read_imu_csv(path) if kind == "dgcal" else read_kf_gins(path, gps_week=gps_week)
        if time_offset_s:
            imu.t = imu.t + float(time_offset_s)
        return imu
    f = imu_format(fmt if fmt is not None else "kf-gins", overrides, time_offset_s=time_offset_s)
    return read_imu(path, f, tag=tag, gps_week=gps_week)


def _read_lc_input(path, fmt: str | None, nmea_date: str | None) -> GnssSolution:
    """LC antenna positions from a solution file (pos.gnss.solution_files) or a ROS bag's NavSatFix messages."""
    if fmt == "rosbag" or (fmt is None and Path(path).exists() and is_ros_bag(path)):
        return read_rosbag_navsatfix(path)
    return read_gnss_solution(path, fmt, nmea_date)


def sniff_imu_file(path) -> str:
    """'dgcal' for a CSV whose header names gps_week and gps_sow, else 'kf-gins'."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            for line in fh:
                s = line.strip()
                if not s or s.startswith(("#", "%")):
                    continue
                low = s.lower()
                return "dgcal" if "gps_week" in low and "gps_sow" in low else "kf-gins"
    except OSError as exc:
        raise InputError(f"cannot read: {exc}", path) from None
    return "kf-gins"


_SMOOTHER_SETTINGS = {"rate": float, "forward": bool, "model_errors": bool, "use_doppler": bool, "earth_rotation": bool,
             "huber_k": float, "clock_bias_rw_m": float, "clock_drift_rw_mps": float, "prior_pos_sigma_m": float,
             "prior_vel_sigma_mps": float, "lc_velocity": bool, "max_iterations": int, "dd_outlier_sigma": float,
             "zupt": bool, "static_noise": bool, "gnss_outlier_sigma": float, "imu_max_gap_s": float,
             "code_bias": bool, "code_bias_tau_s": float, "forward_filter": bool}
_SETTINGS = dict(_SMOOTHER_SETTINGS)     # every key parse_settings knows (the modes' own sets: `mode_settings`)
_IMU_SETTINGS = {"imu_max_gap_s": "max_gap_s"}   # --set keys of the IMU checks (dgcal.pos.ins.integrity)


def parse_settings(items) -> dict:
    """`--set KEY=VALUE` items -> typed dict (keys of `_SETTINGS`); InputError naming --set otherwise."""
    out: dict = {}
    for item in items:
        key, sep, val = str(item).partition("=")
        key = key.strip().replace("-", "_")
        if not sep or key not in _SETTINGS:
            raise InputError(f"unknown setting {item!r} (KEY=VALUE with KEY one of {', '.join(_SETTINGS)})",
                             field="--set")
        typ = _SETTINGS[key]
        v = val.strip().lower()
        try:
            if typ is bool:
                if v not in ("1", "0", "true", "false", "yes", "no", "on", "off"):
                    raise ValueError(v)
                out[key] = v in ("1", "true", "yes", "on")
            elif key in ("huber_k", "gnss_outlier_sigma") and v in ("none", "off"):
                out[key] = None
            else:
                out[key] = typ(v)
                if typ is float and not np.isfinite(out[key]):
                    raise ValueError(v)
        except ValueError:
            raise InputError(f"bad value for {key}: {val!r}", field="--set") from None
    return out


@dataclass
class PosOptions:
    """Inputs and settings of `dgcal pos` in every mode: spp (RINEX -> antenna positions), tc or lc (GNSS/INS
    smoothing of IMU + RINEX, or IMU + gnss.csv for lc, with camera events)."""

    mode: str = "spp"                       # spp | ppk | tc | lc | ukf
    rinex_obs: Path | None = None           # RINEX observations of the rover
    rinex_nav: tuple[Path, ...] = ()        # broadcast navigation file(s)
    imu: Path | None = None                 # tc/lc: IMU file (dgcal CSV, KF-GINS text, or as `imu_format` says)
    events: Path | None = None              # tc/lc: camera events (dgcal CSV, DJI MRK, image,utc CSV, ...); optional
    gnss: Path | None = None                # lc: antenna positions (dgcal gnss.csv, RTKLIB .pos, NMEA GGA)
    imu_format: str | None = None           # tc/lc: IMU description, a preset name or TOML (pos.ins.imu_formats)
    imu_set: tuple[str, ...] = ()           # tc/lc: description overrides KEY=VALUE (e.g. units.gyro=deg/s)
    imu_tag: Path | None = None             # tc/lc: RTKLIB time-tag file of a tick-counter IMU log
    imu_time_offset_s: float = 0.0          # tc/lc: added to every IMU sample time (s; a logging delay)
    estimate_imu_time_offset: bool = False  # tc/lc: estimate the rest of the offset from the data (with its sigma)
    events_format: str | None = None        # events file format (default: recognised by content)
    gnss_format: str | None = None          # lc: rtklib-pos | nmea | dgcal-csv (default: recognised by content)
    gnss_quality: str | None = None         # lc: fix qualities to use, e.g. "fixed,float" (default all)
    nmea_date: str | None = None            # lc: UTC date YYYY-MM-DD of an NMEA log without RMC
    gnss_outages: tuple[float, float, float] | None = None  # lc: withhold fixes (start, length, period s) to check
    systems: str = "GECJ"                   # constellation letters of G, E, C, J
    elev_mask_deg: float = 10.0
    code_sigma_m: float = 0.3               # code noise at zenith
    doppler_sigma_mps: float = 0.1          # range-rate noise at zenith
    raim: bool = True                       # satellite outlier rejection
    t_start: float | None = None            # continuous GPS seconds
    t_end: float | None = None
    lever_arm_m: tuple[float, float, float] | None = None  # tc/lc: GNSS antenna in the IMU body frame (FRD)
    imu_grade: str | None = None            # tc/lc: error-model preset (default adis16488)
    settings: tuple[str, ...] = ()          # tc/lc: smoother settings KEY=VALUE (`parse_settings`)
    reference_ecef: tuple[float, float, float] | None = None  # spp/ppk: known antenna position (m) for the report
    progress: bool = True
    rinex_base: Path | None = None          # ppk: RINEX observations of the base station
    base_position_ecef: tuple[float, float, float] | None = None   # ppk: base antenna ECEF (m)
    base_position_llh: tuple[float, float, float] | None = None    # ppk: base antenna lat, lon (deg), h (m)
    dynamics: str = "kinematic"             # ppk: kinematic | static
    ppk_solution: str = "combined"          # ppk: combined | forward | backward
    ar_ratio: float = 3.0                   # ppk: ratio-test threshold
    n_freq: int = 3                         # ppk: frequencies per system (1-3)
    truth: Path | None = None               # ukf: true trajectory for the accuracy table (trajectory CSV or sim truth)
    forward_filter: bool = False            # tc/lc: the forward solution from the iterated filter, not the linear pass
    iono: str = "klobuchar"                 # spp/tc: klobuchar | auto | iono-free (dgcal.pos.gnss.spp.SppOptions.iono)


def _spp_options(opts: PosOptions, model_errors: bool = True, strict: bool = True):
    """The SPP settings of `opts`; `strict`: no known constellation in `systems` is an input error (else GPS)."""
    systems = tuple(s for s in str(opts.systems).upper() if s in "GECJ")
    if not systems and strict:
        raise InputError(f"no known constellation in '{opts.systems}'", field="--systems")
    return SppOptions(elev_mask_deg=opts.elev_mask_deg, code_sigma_zenith_m=opts.code_sigma_m,
                      doppler_sigma_zenith_mps=opts.doppler_sigma_mps, systems=systems or ("G",),
                      raim=opts.raim, model_errors=model_errors, iono=opts.iono)


@dataclass
class SppRun:
    """`dgcal pos --mode spp`: the SPP solution of every epoch, its summary and the reference position (m)."""

    solution: object                     # dgcal.pos.gnss.spp.SppSolution
    summary: dict
    reference_ecef: np.ndarray | None = None


def run_spp(opts: PosOptions) -> SppRun:
    """Read the RINEX files of `opts`, position every epoch (SPP, ECEF m) and summarise (with the 3D RMS
    against `reference_ecef` when given)."""
    for name, val in (("rinex-obs", opts.rinex_obs), ("rinex-nav", opts.rinex_nav)):
        if not val:
            raise InputError("required for --mode spp", field="--" + name)
    check_settings_mode(opts)
    sopts = _spp_options(opts)
    nav = read_rinex_nav(opts.rinex_nav[0], list(opts.rinex_nav[1:]))
    rx = read_obs_file(opts.rinex_obs, t_start=opts.t_start, t_end=opts.t_end)
    obs = read_rinex_obs(opts.rinex_obs, systems=sopts.systems, rinex=rx)
    sol = spp(obs, nav, sopts, progress=opts.progress)
    if not sol.ok.any():
        raise InputError("no epoch could be positioned (too few satellites with ephemeris?)", opts.rinex_obs)
    summary = spp_summary(sol, obs, nav, sopts)
    if rx.warnings:
        add_integrity(summary, rinex_warnings=rx.warnings)
    ref = None
    if opts.reference_ecef is not None:
        ref = np.asarray(opts.reference_ecef, float)
        err = sol.p_ecef[sol.ok] - ref
        summary["rms_3d_vs_reference_m"] = float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))
    return SppRun(sol, summary, ref)


_DD_SETTINGS = {"phase_sigma_m": float, "dd_code_sigma_m": float, "phase_corr_s": float, "code_corr_s": float,
                "phase_corr_share": float, "code_corr_share": float, "iono_ppm": float, "tropo_zenith_m": float,
                "dd_code": bool, "dd_phase": bool}
_SETTINGS.update(_DD_SETTINGS)   # --set KEY=VALUE of the double differences (tc with --rinex-base)
_SETTINGS.update(UKF_SETTINGS)   # --set KEY=VALUE of --mode ukf (dgcal.pos.lowcost.ukf_pos)


def tc_carrier_inputs(opts: PosOptions, nav, spp_opts, extra: dict):
    """TC with a base (`--rinex-base`): the rover's and base's RINEX read and checked (`read_base`), as carrier
    observations for the PPK/double-difference front end and as the rover's code epochs for SPP; the PPK and
    double-difference options (`extra` keys of `_DD_SETTINGS` are taken out of it). Returns (carrier tuple for
    `process`, rover GnssObservations, PpkOptions, DDOptions, base summary dict)."""
    if not 1 <= int(opts.n_freq) <= 3:
        raise InputError(f"must be 1, 2 or 3, not {opts.n_freq}", field="--frequencies")
    dd_kw = {k: extra.pop(k) for k in list(extra) if k in _DD_SETTINGS}
    dd_opts = DDOptions(**{("code_sigma_m" if k == "dd_code_sigma_m" else "use_code" if k == "dd_code" else
                            "use_phase" if k == "dd_phase" else k): v for k, v in dd_kw.items()},
                        elev_mask_deg=opts.elev_mask_deg)
    systems = "".join(spp_opts.systems)
    # iono/tropo 0: no atmosphere budget on PPK's fixed-position covariances, which the TC front end never reads
    # (it takes PPK's positions and integers; the smoother budgets the atmosphere itself, from dd_opts)
    popts = PpkOptions(systems=systems, n_freq=int(opts.n_freq), elev_mask_deg=opts.elev_mask_deg,
                       ar_elev_mask_deg=opts.elev_mask_deg, dynamics="kinematic", solution="forward",
                       ratio_threshold=opts.ar_ratio, humidity=0.7, iono_ppm=0.0, tropo_zenith_m=0.0)
    rover_rx = read_obs_file(opts.rinex_obs, t_start=opts.t_start, t_end=opts.t_end, systems=systems)
    bs = read_base(opts, rover_rx, nav, spp_opts, systems, popts.max_age_s)
    raw = read_rinex_obs(opts.rinex_obs, systems=spp_opts.systems, rinex=rover_rx)
    rover = carrier_observations(rover_rx, systems, popts.n_freq)
    base = carrier_observations(bs.rinex, systems, popts.n_freq)
    info = {"rinex_base": str(opts.rinex_base), "base_ecef_m": bs.ecef.tolist(), "base_position_source": bs.source,
            "base_spp_ecef_m": bs.spp_ecef.tolist() if bs.spp_ecef is not None else None,
            "base_minus_spp_m": bs.minus_spp_m, "warnings": bs.warnings + list(nav.warnings),
            "rinex_warnings": list(rover_rx.warnings) + list(bs.rinex.warnings)}
    return (rover, base, bs.ecef), raw, popts, dd_opts, info


def mode_settings(mode: str, with_base: bool = False) -> set[str]:
    """The `--set` keys a mode uses: the smoother's (tc, lc; ukf too), the double differences' (tc with a base), the
    UKF's, PPK's (the fields of PpkOptions); spp takes none."""
    return {"tc": set(_SMOOTHER_SETTINGS) | (set(_DD_SETTINGS) if with_base else set()),
            "lc": set(_SMOOTHER_SETTINGS), "ukf": set(_SMOOTHER_SETTINGS) | set(UKF_SETTINGS),
            "ppk": set(_PPK_SETTINGS), "spp": set()}.get(mode, set())


def check_settings_mode(opts: PosOptions) -> None:
    """Refuse a `--set` key that the chosen mode would not use (InputError naming the key and the modes it belongs
    to): a setting of another mode must not pass unnoticed."""
    own = mode_settings(opts.mode, bool(opts.rinex_base))
    for item in opts.settings:
        key = str(item).partition("=")[0].strip().replace("-", "_")
        if key in own:
            continue
        owners = [m for m in ("tc", "lc", "ukf", "ppk") if key in mode_settings(m, with_base=True)]
        if not owners:
            continue                          # an unknown key: the mode's own parser names every key it knows
        need = " with --rinex-base" if opts.mode == "tc" and key in _DD_SETTINGS else ""
        raise InputError(f"{key} is a setting of --mode {'/'.join(owners)}{need}: --mode {opts.mode} "
                         + ("takes no --set" if not own else "does not use it"), field="--set")


def run_pos(opts: PosOptions) -> PosResult:
    """`dgcal pos --mode tc|lc`: read the IMU, GNSS (RINEX or gnss.csv) and events of `opts` and smooth them
    (see `process`); the result holds the trajectory, the events' poses and the summary."""
    mode = opts.mode
    if mode not in ("tc", "lc", "ukf"):
        raise InputError(f"mode must be tc, lc or ukf, not {mode!r}", field="--mode")
    check_settings_mode(opts)
    extra = parse_settings(opts.settings)
    if not opts.imu:
        raise InputError(f"required for --mode {mode}", field="--imu")
    try:
        grade = imu_grade(opts.imu_grade or "adis16488")
    except ValueError as exc:
        raise InputError(str(exc), field="--imu-grade") from None
    lever = np.asarray(opts.lever_arm_m or (0.0, 0.0, 0.0), float)
    events = read_any_events(opts.events, opts.events_format) if opts.events else None
    raw = nav = lc = None
    spp_opts = None
    carrier = popts = dd_opts = base_info = None
    rinex_warnings: list = []
    week = int(np.floor(events.t[0] / SECONDS_PER_WEEK)) if events is not None and len(events) else None
    if opts.rinex_obs and opts.rinex_nav:
        spp_opts = _spp_options(opts, model_errors=bool(extra.pop("model_errors", True)), strict=False)
        navs = [opts.rinex_nav] if isinstance(opts.rinex_nav, (str, Path)) else list(opts.rinex_nav)
        nav = read_rinex_nav(navs[0], navs[1:])
        if mode == "tc" and opts.rinex_base:
            carrier, raw, popts, dd_opts, base_info = tc_carrier_inputs(opts, nav, spp_opts, extra)
            rinex_warnings = base_info.pop("rinex_warnings")
        else:
            rx = read_obs_file(opts.rinex_obs, t_start=opts.t_start, t_end=opts.t_end)
            raw = read_rinex_obs(opts.rinex_obs, systems=spp_opts.systems, rinex=rx)
            rinex_warnings = list(rx.warnings)
        if len(raw.epochs):
            week = int(np.floor(raw.epochs[0].t_gps / SECONDS_PER_WEEK))
    elif mode == "tc":
        raise InputError("tc mode needs --rinex-obs and --rinex-nav", field="--rinex-obs")
    withheld = None
    if opts.gnss:
        sol = select_quality(_read_lc_input(opts.gnss, opts.gnss_format, opts.nmea_date), opts.gnss_quality)
        if opts.t_start is not None or opts.t_end is not None:
            keep = (sol.t >= (opts.t_start if opts.t_start is not None else -np.inf)) & \
                   (sol.t <= (opts.t_end if opts.t_end is not None else np.inf))
            if keep.sum() < 2:
                raise InputError("fewer than two GNSS epochs between --t-start and --t-end", opts.gnss)
            sol = sol.subset(keep)
        if opts.gnss_outages is not None:
            out_mask = outage_mask(sol.t, opts.gnss_outages)
            if (~out_mask).sum() < 2:
                raise InputError("the outages leave fewer than two GNSS epochs", field="--gnss-outages")
            withheld = sol.subset(out_mask)
            sol = sol.subset(~out_mask)
        lc = fixes_from_solution(sol)
        week = int(np.floor(lc.t[0] / SECONDS_PER_WEEK))
    imu = load_imu(opts.imu, gps_week=week, fmt=opts.imu_format, overrides=opts.imu_set, tag=opts.imu_tag,
                   time_offset_s=opts.imu_time_offset_s)
    if opts.t_start is not None or opts.t_end is not None:
        imu = imu.between(opts.t_start if opts.t_start is not None else -np.inf,
                          opts.t_end if opts.t_end is not None else np.inf)
        if len(imu) < 2:
            raise InputError("fewer than two IMU samples between --t-start and --t-end", opts.imu)
    rate = float(extra.pop("rate", 10.0))
    forward = bool(extra.pop("forward", True))
    if extra.pop("forward_filter", False) or opts.forward_filter:
        forward = "filter"
    for k in _DD_SETTINGS:               # without a base station the double-difference settings do nothing
        extra.pop(k, None)
    ukf_kw = {k: extra.pop(k) for k in list(extra) if k in UKF_SETTINGS}
    checks = ImuIntegrityOptions(**{_IMU_SETTINGS[k]: extra.pop(k) for k in list(extra) if k in _IMU_SETTINGS})
    sm = SmootherOptions(**extra)
    try:
        if mode == "ukf":
            imu, imu_report = check_imu(imu, checks)
            res = ukf_mode(opts, imu, grade, lever, raw, nav, spp_opts, lc, events, rate, sm, ukf_kw)
            add_integrity(res.summary, imu_report)
        else:
            res = process(mode, imu, grade, lever, raw_obs=raw, nav=nav, spp_opts=spp_opts, lc_fixes=lc,
                          events=events, rate_hz=rate, forward=forward, smoother_opts=sm, progress=opts.progress,
                          carrier=carrier, ppk_opts=popts, dd_opts=dd_opts, imu_checks=checks,
                          estimate_imu_time_offset=opts.estimate_imu_time_offset)
        add_integrity(res.summary, rinex_warnings=rinex_warnings)
    except InputError:
        raise
    except ValueError as exc:
        raise InputError(str(exc), opts.imu) from None
    res.summary["imu_grade"] = grade.datasheet()
    if base_info is not None:
        res.summary.setdefault("carrier", {}).update(base_info)
    if opts.gnss and withheld is not None:
        res.summary["withheld_fixes"] = withheld_fix_errors(res.trajectory, withheld, lever)
    return res


def ukf_mode(opts: PosOptions, imu, grade, lever, raw, nav, spp_opts, lc: GnssFixes | None, events, rate: float,
             sm: SmootherOptions, ukf_kw: dict) -> UkfPosResult:
    """`--mode ukf`: the fixes (`--gnss`, or SPP of the RINEX) through seed 000's UKF, the LC smoother beside it and
    the truth (`--truth`) when given (dgcal.pos.lowcost.ukf_pos.process_ukf)."""
    fixes = lc
    if fixes is None:
        if raw is None:
            raise InputError("--mode ukf needs --gnss (or --rinex-obs and --rinex-nav)", field="--gnss")
        fixes = fixes_from_spp(spp(raw, nav, spp_opts or SppOptions(), progress=opts.progress))
    kw = dict(ukf_kw)
    compare, compare_rate, skip = kw.pop("compare", True), kw.pop("compare_rate", 10.0), kw.pop("skip_s", 30.0)
    truth = read_true_trajectory(opts.truth) if opts.truth else None
    return process_ukf(imu, grade, lever, fixes, events, rate, UkfOptions(**kw), compare=compare,
                       compare_rate_hz=compare_rate, smoother_opts=sm, truth=truth, skip_s=skip,
                       progress=opts.progress)


def outage_mask(t: np.ndarray, outages: tuple[float, float, float]) -> np.ndarray:
    """Epochs inside simulated GNSS outages `(start, length, period)` (s): [t0+start+k*period, +length)."""
    start, length, period = (float(v) for v in outages)
    if not (length > 0 and period > length and start >= 0):
        raise InputError(f"need start >= 0, length > 0 and period > length, not {start:g} {length:g} {period:g}",
                         field="--gnss-outages")
    x = np.asarray(t, float) - (float(t[0]) + start)
    return (x >= 0) & (np.mod(x, period) < length)


def withheld_fix_errors(traj, withheld: GnssSolution, lever_arm_b) -> dict:
    """Antenna position of the trajectory (IMU + R_body_to_ecef lever arm) minus the withheld fixes inside the
    outages: counts and RMS (m) along N, E, D and 3D, by fix quality."""
    ok = (withheld.t >= traj.t[0]) & (withheld.t <= traj.t[-1])
    w = withheld.subset(ok)
    if len(w) == 0:
        return {"n": 0}
    st = interpolate_trajectory(traj, w.t)
    p_ant = st.p_ecef + np.einsum("nij,j->ni", st.R_body_to_ecef, np.asarray(lever_arm_b, float))
    geo = ecef_to_geodetic(w.p_ecef)
    d_ned = np.einsum("nij,nj->ni", R_ecef_to_ned(geo[:, 0], geo[:, 1]), p_ant - w.p_ecef)
    out = {"n": int(len(w)), "rms_ned_m": np.sqrt(np.mean(d_ned ** 2, axis=0)).round(4).tolist(),
           "rms_3d_m": round(float(np.sqrt(np.mean(np.sum(d_ned ** 2, axis=1)))), 4),
           "max_3d_m": round(float(np.max(np.linalg.norm(d_ned, axis=1))), 4)}
    fixed = w.quality == 1
    if fixed.any() and not fixed.all():
        out["rms_3d_fixed_m"] = round(float(np.sqrt(np.mean(np.sum(d_ned[fixed] ** 2, axis=1)))), 4)
    return out


# ------------------------------------------------------------------------------------------------ ppk
_PPK_SETTINGS = {f.name: f.type for f in fields(PpkOptions)}


def ppk_settings(items) -> dict:
    """`--set KEY=VALUE` items of `--mode ppk` -> typed PpkOptions fields; InputError naming --set otherwise."""
    out: dict = {}
    for item in items:
        key, sep, val = str(item).partition("=")
        key = key.strip().replace("-", "_")
        if not sep or key not in _PPK_SETTINGS:
            raise InputError(f"unknown setting {item!r} (KEY=VALUE with KEY one of {', '.join(_PPK_SETTINGS)})",
                             field="--set")
        typ = _PPK_SETTINGS[key]
        v = val.strip()
        try:
            if typ in (bool, "bool"):
                if v.lower() not in ("1", "0", "true", "false", "yes", "no", "on", "off"):
                    raise ValueError(v)
                out[key] = v.lower() in ("1", "true", "yes", "on")
            elif typ in (int, "int"):
                out[key] = int(v)
            elif typ in (float, "float"):
                out[key] = float(v)
                if not np.isfinite(out[key]):
                    raise ValueError(v)
            else:
                out[key] = v
        except ValueError:
            raise InputError(f"bad value for {key}: {val!r} (a finite number)" if typ in (float, "float") else
                             f"bad value for {key}: {val!r}", field="--set") from None
    return out


@dataclass
class PpkRun:
    """`dgcal pos --mode ppk`: the PPK result (single epochs filled by SPP), its summary and warnings."""

    result: PpkResult
    summary: dict
    base_ecef: np.ndarray
    reference_ecef: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)


def _ymd(t_gps: float) -> str:
    y, mo, d, h, mi, s = calendar_from_gps_seconds(t_gps)
    return f"{y:04d}-{mo:02d}-{d:02d} {h:02d}:{mi:02d}:{s:04.1f}"


def _spp_median(raw, nav, sopts, n_max: int = 10) -> tuple[np.ndarray | None, int]:
    """Median SPP position (ECEF m) of up to `n_max` epochs spread over a receiver's file."""
    k = np.unique(np.linspace(0, len(raw.epochs) - 1, min(n_max, len(raw.epochs))).astype(int))
    guess = raw.p_approx_ecef if np.all(np.isfinite(raw.p_approx_ecef)) else None
    ps = []
    for i in k:
        s = solve_epoch(raw.epochs[i], nav, guess, sopts)
        if s.ok:
            ps.append(s.p_ecef)
            guess = s.p_ecef
    return (np.median(ps, axis=0) if ps else None), len(ps)


@dataclass
class BaseInput:
    """A base station checked against the rover: its observations in the rover's span (`RinexObsFile`), its
    position (ECEF m) and where it came from, its own SPP (median of ten epochs) and the distance to it (m)."""

    rinex: object
    ecef: np.ndarray
    source: str
    spp_ecef: np.ndarray | None
    minus_spp_m: float
    warnings: list[str] = field(default_factory=list)


def read_base(opts: PosOptions, rover_rx, nav, sopts, systems: str, max_age_s: float = 30.0) -> BaseInput:
    """Read and check `opts.rinex_base` for the rover file `rover_rx` (ppk and tc): common epochs (a base of
    another day is said so), a base epoch within `max_age_s` of a rover epoch, the base position (--base-position,
    --base-position-llh, or the header's with a warning) on the Earth's surface and within 100 m of the base's
    own SPP. One-line InputError naming the file, line and field otherwise."""
    warnings: list[str] = []
    if len(rover_rx) == 0:
        raise InputError("no observation epochs in the requested time span", opts.rinex_obs)
    t0, t1 = rover_rx.t_gps[0], rover_rx.t_gps[-1]
    base_all = read_obs_file(opts.rinex_base, systems=systems)
    if len(base_all) == 0:
        raise InputError("no observation epochs", opts.rinex_base)
    tb = base_all.t_gps
    if tb[-1] < t0 - max_age_s or tb[0] > t1 + max_age_s:
        day = abs(np.floor(tb[0] / 86400.0) - np.floor(t0 / 86400.0)) >= 1
        raise InputError(f"no common epochs: base {_ymd(tb[0])} - {_ymd(tb[-1])}, rover {_ymd(t0)} - {_ymd(t1)} GPS"
                         + (" (another day)" if day else ""), opts.rinex_base, int(base_all.epoch_line[0]), "EPOCH")
    near = np.abs(tb[np.clip(np.searchsorted(tb, rover_rx.t_gps), 0, len(tb) - 1)] - rover_rx.t_gps)
    near = np.minimum(near, np.abs(tb[np.clip(np.searchsorted(tb, rover_rx.t_gps) - 1, 0, len(tb) - 1)]
                                   - rover_rx.t_gps))
    if not np.any(near <= max_age_s):
        raise InputError(f"no base epoch within {max_age_s:g} s of any rover epoch", opts.rinex_base,
                         int(base_all.epoch_line[0]), "EPOCH")
    keep = (tb >= t0 - max_age_s) & (tb <= t1 + max_age_s)
    base_rx = base_all if keep.all() else \
        read_obs_file(opts.rinex_base, t_start=float(tb[keep][0]), t_end=float(tb[keep][-1]), systems=systems)
    if opts.base_position_ecef is not None:
        base = np.asarray(opts.base_position_ecef, float)
        src, fld = "--base-position", "--base-position"
    elif opts.base_position_llh is not None:
        lat, lon, h = (float(v) for v in opts.base_position_llh)
        if not (-90 <= lat <= 90 and -180 <= lon <= 360):
            raise InputError(f"latitude/longitude out of range: {lat}, {lon}", field="--base-position-llh")
        base = np.asarray(geodetic_to_ecef(lat, lon, h), float).reshape(3)
        src, fld = "--base-position-llh", "--base-position-llh"
    else:
        base = base_rx.p_approx_ecef
        if not np.all(np.isfinite(base)):
            raise InputError("no base position: give --base-position X Y Z (or --base-position-llh); the base "
                             "header has no APPROX POSITION XYZ", opts.rinex_base, field="APPROX POSITION XYZ")
        src, fld = "header APPROX POSITION XYZ", "APPROX POSITION XYZ"
        warnings.append(f"{opts.rinex_base}: no --base-position given: the base header's APPROX POSITION XYZ "
                        "is used; its error (often metres) goes into the rover position one to one")
    if not (np.all(np.isfinite(base)) and 6.0e6 < np.linalg.norm(base) < 6.5e6):
        raise InputError(f"base position {base.tolist()} is not on the Earth's surface (ECEF metres?)", field=fld)
    base_raw = read_rinex_obs(opts.rinex_base, systems=sopts.systems, rinex=base_rx)
    base_spp, _ = _spp_median(base_raw, nav, sopts)
    d_spp = float(np.linalg.norm(base - base_spp)) if base_spp is not None else np.nan
    if base_spp is not None and d_spp > 100.0:
        raise InputError(f"base position ({src}) is {d_spp:.0f} m from the base's own SPP position "
                         f"{np.round(base_spp, 1).tolist()}: wrong coordinates or wrong file?", field=fld)
    if base_spp is not None and not src.startswith("header"):
        z = base_spp_disagreement(base, base_spp)
        if z > 5.0:
            raise InputError(f"base position ({src}) is {d_spp:.1f} m from the base's own SPP position "
                             f"{np.round(base_spp, 1).tolist()} ({z:.1f} sigma of a static SPP's "
                             f"{BASE_SPP_SIGMA_M[0]:g} m horizontal / {BASE_SPP_SIGMA_M[1]:g} m vertical): every rover "
                             "position would be off by as much with a millimetre sigma; wrong coordinates, another "
                             "datum or epoch, or a height above the marker?", field=fld)
        if z > 3.0:
            warnings.append(f"base position ({src}) is {d_spp:.1f} m from the base's own SPP ({z:.1f} sigma): check "
                            "its coordinates; an error there goes into every rover position")
    return BaseInput(base_rx, base, src, base_spp, d_spp, warnings)


# a static receiver's SPP averaged over its file: broadcast orbit, clock and ionosphere errors do not average out
BASE_SPP_SIGMA_M = (1.5, 3.0)              # horizontal, vertical (m, 1 sigma)


def base_spp_disagreement(base_ecef: np.ndarray, spp_ecef: np.ndarray) -> float:
    """How many sigmas of a static SPP (`BASE_SPP_SIGMA_M`, local level) a given base position is from the base's
    own SPP: the norm of the local east/north/up difference scaled per axis."""
    lat, lon, _ = ecef_to_geodetic(spp_ecef)
    d = R_ecef_to_enu(lat, lon) @ (np.asarray(base_ecef, float) - np.asarray(spp_ecef, float))
    sh, sv = BASE_SPP_SIGMA_M
    return float(np.sqrt((d[0] / sh) ** 2 + (d[1] / sh) ** 2 + (d[2] / sv) ** 2))


def run_ppk(opts: PosOptions) -> PpkRun:
    """`dgcal pos --mode ppk`: carrier-phase PPK of the rover RINEX against the base RINEX at the given base
    position (ECEF m, or geodetic, or the base header's APPROX POSITION with a warning); epochs without
    double differences are SPP ('single'). Checks: common epochs, same day, base position within 100 m of the
    base's own SPP. Returns the solution and the summary (with the 3D RMS against `reference_ecef` if given)."""
    for name, val in (("rinex-obs", opts.rinex_obs), ("rinex-nav", opts.rinex_nav), ("rinex-base", opts.rinex_base)):
        if not val:
            raise InputError("required for --mode ppk", field="--" + name)
    if opts.dynamics not in ("kinematic", "static"):
        raise InputError(f"dynamics must be kinematic or static, not {opts.dynamics!r}", field="--dynamics")
    if opts.ppk_solution not in ("combined", "forward", "backward"):
        raise InputError(f"must be combined, forward or backward, not {opts.ppk_solution!r}", field="--ppk-solution")
    if not 1 <= int(opts.n_freq) <= 3:
        raise InputError(f"must be 1, 2 or 3, not {opts.n_freq}", field="--frequencies")
    sopts = _spp_options(opts)
    check_settings_mode(opts)
    extra = ppk_settings(opts.settings)
    popts = PpkOptions(**{**dict(systems="".join(sopts.systems), n_freq=int(opts.n_freq),
                                  elev_mask_deg=opts.elev_mask_deg, ar_elev_mask_deg=opts.elev_mask_deg,
                                  dynamics=opts.dynamics, solution=opts.ppk_solution,
                                  ratio_threshold=opts.ar_ratio), **extra})
    warnings: list[str] = []
    nav = read_rinex_nav(opts.rinex_nav[0], list(opts.rinex_nav[1:]))
    warnings += nav.warnings
    rover_rx = read_obs_file(opts.rinex_obs, t_start=opts.t_start, t_end=opts.t_end, systems=popts.systems)
    bs = read_base(opts, rover_rx, nav, sopts, popts.systems, popts.max_age_s)
    base_rx, base, src, base_spp, d_spp = bs.rinex, bs.ecef, bs.source, bs.spp_ecef, bs.minus_spp_m
    warnings += list(rover_rx.warnings) + list(base_rx.warnings) + bs.warnings
    # rover: SPP of the first epochs (start of the filter) and of epochs without double differences
    rover_raw = read_rinex_obs(opts.rinex_obs, systems=sopts.systems, rinex=rover_rx)
    p_init = None
    guess = rover_raw.p_approx_ecef if np.all(np.isfinite(rover_raw.p_approx_ecef)) else None
    for ep in rover_raw.epochs[:10]:
        s = solve_epoch(ep, nav, guess, sopts)
        if s.ok:
            p_init = s.p_ecef
            break
    if p_init is None:
        p_init = guess if guess is not None else base
    rover = carrier_observations(rover_rx, popts.systems, popts.n_freq)
    base_obs = carrier_observations(base_rx, popts.systems, popts.n_freq)
    t_run = time.perf_counter()
    with threadpool_limits(1):        # small matrices: BLAS threads only cost
        res = ppk(rover, base_obs, nav, base, popts, p_init=p_init)
    t_run = time.perf_counter() - t_run
    # 'single' epochs: SPP where PPK has no solution
    t_raw = {round(ep.t_gps, 3): ep for ep in rover_raw.epochs}
    guess = p_init
    for k in np.nonzero(res.status == 0)[0]:
        ep = t_raw.get(round(float(res.t_gps[k]), 3))
        if ep is None:
            continue
        s = solve_epoch(ep, nav, guess, sopts)
        if s.ok:
            res.status[k], res.p[k], res.P[k], res.n_sat[k] = 1, s.p_ecef, s.cov_p, s.n_sat
            guess = s.p_ecef
    ref = np.asarray(opts.reference_ecef, float) if opts.reference_ecef is not None else None
    summary = ppk_summary(res, ref)
    summary.update({"rinex_obs": str(opts.rinex_obs), "rinex_base": str(opts.rinex_base),
                    "rinex_nav": nav.source, "base_ecef_m": base.tolist(), "base_position_source": src,
                    "base_spp_ecef_m": base_spp.tolist() if base_spp is not None else None,
                    "base_minus_spp_m": d_spp, "ionosphere_model": nav.ion_source,
                    "run_time_s": round(t_run, 2),
                    "time_per_epoch_ms": round(1e3 * t_run / max(len(res.t_gps), 1), 2),
                    "warnings": warnings})
    return PpkRun(res, summary, base, ref, warnings)
