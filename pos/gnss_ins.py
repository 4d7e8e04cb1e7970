"""`dgcal pos --mode tc|lc|ukf`: IMU + GNSS (RINEX, with a base station's carrier phase, or antenna positions) +
camera events -> smoothed trajectory and the events' poses.

`process(...)` works on in-memory data (tests, simulator); `run_gnss_ins(InsModeOptions)` reads the files and runs
it (or the UKF for `UkfModeOptions`); dgcal.reports.pos.write_pos_outputs and dgcal.reports.ukf.write_ukf_outputs
write their files.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
from threadpoolctl import threadpool_limits

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.crs import R_ecef_to_ned_at
from dgcal.fields.errors import InputError, ResultError
from dgcal.fields.processes import fork_map
from dgcal.pos.base_station import read_base
from dgcal.fields.io.image_folders import list_image_names
from dgcal.pos.events import read_any_events
from dgcal.pos.gnss.carrier import carrier_observations
from dgcal.pos.gnss.dd import DDOptions, carrier_front_end, imu_aided_front_end
from dgcal.pos.gnss.observations import GnssObservations
from dgcal.pos.gnss.ppk import PpkOptions, PpkResult
from dgcal.pos.gnss.rinex import read_rinex_nav, read_rinex_obs
from dgcal.pos.gnss.rinex_obs import read_obs_file
from dgcal.pos.gnss.solution_files import GnssSolution
from dgcal.pos.gnss.spp import SppOptions, glonass_channels, prepare_epochs, spp
from dgcal.pos.gnss_ins_summary import (add_integrity, antenna_track, carrier_summary, observability_warnings,
                                        summarize, time_offset_summary, withheld_fix_errors)
from dgcal.pos.ins.error_model import imu_grade
from dgcal.pos.ins.integrity import ImuIntegrityOptions, check_imu
from dgcal.pos.ins.plausibility import check_turn_sense
from dgcal.pos.ins.interpolate import trajectory_at_events
from dgcal.pos.lowcost.ukf_pos import UkfPosResult, process_ukf, read_true_trajectory
from dgcal.pos.mode_options import InsModeOptions, UkfModeOptions
from dgcal.pos.readers import read_fix_input, read_imu_input
from dgcal.pos.smoother.batch import SmootherOptions, smooth
from dgcal.pos.smoother.forward_filter import forward_solution, linear_forward_solution
from dgcal.pos.smoother.initial import GnssFixes, wide_derivative
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
    withheld: GnssSolution | None = None   # fixes withheld inside the outages (the trajectory's check)


def fixes_from_spp(sol) -> GnssFixes:
    """GnssFixes (antenna ECEF, NED sigmas) from a dgcal.pos.gnss.spp.SppSolution's epochs with a fix."""
    ok = sol.ok
    p = sol.p_ecef[ok]
    R_ecef_to_ned = R_ecef_to_ned_at(p).reshape(-1, 3, 3)
    cp = R_ecef_to_ned @ sol.cov_p[ok] @ np.swapaxes(R_ecef_to_ned, 1, 2)
    cv = R_ecef_to_ned @ sol.cov_v[ok] @ np.swapaxes(R_ecef_to_ned, 1, 2)
    s_p = np.sqrt(np.einsum("nii->ni", cp))
    s_v = np.sqrt(np.einsum("nii->ni", cv))
    v = sol.v_ecef[ok]
    good_v = np.all(np.isfinite(v), axis=1) & np.all(np.isfinite(s_v), axis=1)
    v = np.where(good_v[:, None], v, np.nan)
    return GnssFixes(sol.t_gps[ok], p, s_p, v, np.where(good_v[:, None], s_v, np.nan),
                     velocity_on_time=True)      # SPP's Doppler velocity is the epoch's own


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
        # the options SPP solved with (its code noise estimated from the data's residuals), not the caller's
        used = getattr(spp_sol, "options", None) or opts
        for i, m in zip(redo, prepare_epochs([raw.epochs[i] for i in redo], nav, p, used)):
            out[i] = m if m.n > 0 else None
    epochs = [e for e in out if e is not None]
    return GnssObservations(epochs=epochs, receiver=raw.receiver, p_approx_ecef=np.median(p_ok, axis=0),
                            signals=raw.signals, source=raw.source)


def process(mode: str, imu, grade, lever_arm_b, *, raw_obs=None, nav=None, spp_opts=None,
            lc_fixes: GnssFixes | None = None, events=None, rate_hz: float = 10.0, forward: bool | str = False,
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
    solution (`linear_forward_solution`, about a tenth of the smoothing), "filter" for the iterated filter about its
    own estimates (`forward_solution`), False (the default: what the trajectory and events need) for none.

    estimate_imu_time_offset: the IMU-GNSS time offset estimated from the smoother's chi-square profile
    (`dgcal.pos.smoother.time_offset`, 9-13 smoothings without covariances; its sigma the larger of the curvature's
    and the block jackknife's over time windows), applied to the IMU's time tags and reported in
    `summary['imu_time_offset']`; a ResultError when the profile has no minimum; not applied, and warned, when it
    is not determinable (windows that disagree, or a sigma beyond the estimate).
    """
    if mode not in ("tc", "lc"):
        raise InputError(f"must be tc or lc, not {mode!r}", field="mode")
    opts = replace(smoother_opts or SmootherOptions(), lever_arm_b=np.asarray(lever_arm_b, float))
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
        raise InputError("no GNSS data: give RINEX observations and navigation (or antenna positions for lc)",
                         field="rinex_obs")
    if mode == "tc" and gnss is None:
        raise InputError("tc mode needs RINEX observations and navigation", field="rinex_obs")
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
                                                    fe.input if fe is not None else None, windows=None))
        if not (np.isfinite(offset.sigma_s) and abs(offset.offset_s) < 10.0):
            why = offset.note or "the chi-square profile has no minimum within 10 s"
            raise ResultError(f"the IMU time offset cannot be estimated from these data ({why}); give the offset "
                              "instead", field="estimate_imu_time_offset")
        if offset.determinable:      # an offset the data cannot pin down is reported, not applied
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

    if forward:
        # independent: the dense trajectory (plain arrays) from a child while this process runs the forward pass
        (fw, timing["forward_s"]), (dense, ev, timing["outputs_s"]) = fork_map([forward_pass, outputs])
    else:                                 # nothing to run beside it: no fork, no copy of the trajectory back
        fw, timing["forward_s"] = None, 0.0
        dense, ev, timing["outputs_s"] = outputs()
    sol.info.setdefault("timing", {}).update({k: round(v, 2) for k, v in timing.items()})
    res = PosResult(mode, sol, fw, dense, solution_trajectory(sol), solution_trajectory(fw) if fw else None, ev,
                    spp_sol, fixes, carrier=fe)
    res.summary = summarize(res)
    if offset is not None:
        res.summary["imu_time_offset"] = time_offset_summary(offset)
    add_integrity(res.summary, imu_report, sol.info.get("gnss_rejected", []))
    res.summary.setdefault("warnings", []).extend(observability_warnings(sol, grade))
    if offset is not None and not offset.determinable:
        res.summary["warnings"].append(f"IMU time offset not determinable: {offset.note}; the estimate "
                                       f"({1e3 * offset.offset_s:+.1f} +- {1e3 * offset.sigma_s:.1f} ms) was not "
                                       "applied: the offset given (--imu-time-offset) stands")
    if fe is not None:
        res.summary["carrier"] = carrier_summary(res)
    return res


def track_velocity_ned(fixes: GnssFixes) -> np.ndarray:
    """Velocities (N,3) m/s along the fixes' track in the local NED frame of the first fix (secants of the positions
    over about a second: solution files' own velocities may lag)."""
    R_ecef_to_ned = R_ecef_to_ned_at(fixes.p_ecef[0])
    p_ned = (fixes.p_ecef - fixes.p_ecef[0]) @ R_ecef_to_ned.T
    return wide_derivative(fixes.t, p_ned, half_window_s=0.5)     # 50 Hz fixes' noise: a secant over 1 s


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
    R_ecef_to_ned = R_ecef_to_ned_at(p).reshape(-1, 3, 3)
    C = R_ecef_to_ned @ res.P[ok] @ np.swapaxes(R_ecef_to_ned, 1, 2)
    s = np.sqrt(np.maximum(np.einsum("nii->ni", C), 1e-8))
    return GnssFixes(res.t_gps[ok], p, s, None, None, C)


def tc_carrier_inputs(opts: InsModeOptions, nav):
    """TC with a base station: the rover's and base's RINEX read and checked (`read_base`), as carrier observations
    for the PPK/double-difference front end and as the rover's code epochs for SPP. Returns (carrier tuple for
    `process`, rover GnssObservations, base summary dict)."""
    popts, sopts = opts.ppk, opts.spp
    if not 1 <= int(popts.n_freq) <= 3:
        raise InputError(f"must be 1, 2 or 3, not {popts.n_freq}", field="ppk.n_freq")
    systems = popts.systems
    rover_rx = read_obs_file(opts.rover.rinex_obs, t_start=opts.rover.t_start, t_end=opts.rover.t_end,
                             systems=systems)
    bs = read_base(opts.base, rover_rx, nav, sopts, systems, popts.max_age_s)
    raw = read_rinex_obs(opts.rover.rinex_obs, systems=sopts.systems, rinex=rover_rx)
    rover = carrier_observations(rover_rx, systems, popts.n_freq)
    base = carrier_observations(bs.rinex, systems, popts.n_freq)
    info = {"rinex_base": str(opts.base.rinex), "base_ecef_m": bs.ecef.tolist(), "base_position_source": bs.source,
            "base_spp_ecef_m": bs.spp_ecef.tolist() if bs.spp_ecef is not None else None,
            "base_minus_spp_m": bs.minus_spp_m, "warnings": bs.warnings + list(nav.warnings),
            "rinex_warnings": list(rover_rx.warnings) + list(bs.rinex.warnings)}
    return (rover, base, bs.ecef), raw, info


def _span(opts: InsModeOptions) -> tuple[float, float]:
    r = opts.rover
    return (r.t_start if r.t_start is not None else -np.inf, r.t_end if r.t_end is not None else np.inf)


def read_fixes(opts: InsModeOptions) -> tuple[GnssFixes, GnssSolution | None]:
    """The antenna positions of `opts.fixes` in the time span, without the withheld ones (outages), and those."""
    sol = read_fix_input(opts.fixes)
    t0, t1 = _span(opts)
    if np.isfinite(t0) or np.isfinite(t1):
        keep = (sol.t >= t0) & (sol.t <= t1)
        if keep.sum() < 2:
            raise InputError("fewer than two GNSS epochs between t_start and t_end", opts.fixes.path)
        sol = sol.subset(keep)
    withheld = None
    if opts.fixes.outages is not None:
        out_mask = outage_mask(sol.t, opts.fixes.outages)
        if (~out_mask).sum() < 2:
            raise InputError("the outages leave fewer than two GNSS epochs", field="fixes.outages")
        withheld = sol.subset(out_mask)
        sol = sol.subset(~out_mask)
    return fixes_from_solution(sol), withheld


def run_gnss_ins(opts: InsModeOptions) -> PosResult | UkfPosResult:
    """`dgcal pos --mode tc|lc` (and `ukf` for `UkfModeOptions`): read the IMU, GNSS (RINEX, a base station's
    carrier phase, or antenna positions) and events of `opts` and smooth them (see `process`); the result holds
    the trajectory, the events' poses and the summary."""
    mode = opts.mode
    if mode not in ("tc", "lc", "ukf"):
        raise InputError(f"must be tc, lc or ukf, not {mode!r}", field="mode")
    if not opts.imu.path:
        raise InputError(f"required for --mode {mode}", field="imu.path")
    try:
        grade = imu_grade(opts.imu_grade or "adis16488")
    except ValueError as exc:
        raise InputError(str(exc), field="imu_grade") from None
    lever = np.asarray(opts.lever_arm_m or (0.0, 0.0, 0.0), float)
    # GLONASS serves lc and ukf through their SPP fixes; not tc (in a window of three satellites its Doppler in the
    # smoother made the end of a simulated flight 5-6 sigma off), and not a base station's double differences (FDMA
    # carrier phase). The CLI's --systems drops it then with a warning; a --set or a caller must not pass it.
    for name, systems in (("spp.systems", opts.spp.systems), ("ppk.systems", opts.ppk.systems)):
        if (mode == "tc" or opts.base.rinex) and "R" in str(systems):
            raise InputError(f"GLONASS (R) is used by spp, and by lc and ukf without a base station; take {systems!r} "
                             "without it", field=name)
    image_names = list_image_names(opts.event_images, "event_images", raw=True) if opts.event_images else None
    events = read_any_events(opts.events, opts.events_format, opts.mrk_names, image_names,
                             opts.mrk_pairing) if opts.events else None
    raw = nav = lc = withheld = carrier = base_info = None
    rinex_warnings: list = []
    week = int(np.floor(events.t[0] / SECONDS_PER_WEEK)) if events is not None and len(events) else None
    rover = opts.rover
    if rover.rinex_obs and rover.rinex_nav:
        nav = read_rinex_nav(rover.rinex_nav[0], list(rover.rinex_nav[1:]))
        if mode == "tc" and opts.base.rinex:
            carrier, raw, base_info = tc_carrier_inputs(opts, nav)
            rinex_warnings = base_info.pop("rinex_warnings")
        else:
            rx = read_obs_file(rover.rinex_obs, t_start=rover.t_start, t_end=rover.t_end)
            raw = read_rinex_obs(rover.rinex_obs, systems=opts.spp.systems, rinex=rx, glonass_k=glonass_channels(nav))
            rinex_warnings = list(rx.warnings) + list(nav.warnings)   # with a base, tc_carrier_inputs adds them
        if len(raw.epochs):
            week = int(np.floor(raw.epochs[0].t_gps / SECONDS_PER_WEEK))
    elif mode == "tc":
        raise InputError("tc mode needs the rover's RINEX observations and navigation", field="rinex_obs")
    if opts.fixes.path:
        lc, withheld = read_fixes(opts)
        week = int(np.floor(lc.t[0] / SECONDS_PER_WEEK))
    imu = read_imu_input(opts.imu, gps_week=week)
    t0, t1 = _span(opts)
    if np.isfinite(t0) or np.isfinite(t1):
        imu = imu.between(t0, t1)
        if len(imu) < 2:
            raise InputError("fewer than two IMU samples between t_start and t_end", opts.imu.path)
    if lc is not None and len(lc.t) > 2:
        check_turn_sense(imu, lc.t, track_velocity_ned(lc), opts.fixes.path)
    out = opts.output
    forward = "filter" if out.forward_filter else bool(out.forward)
    try:
        if isinstance(opts, UkfModeOptions):
            imu, imu_report = check_imu(imu, opts.imu_checks)
            res = run_ukf(opts, imu, grade, lever, raw, nav, lc, events)
            add_integrity(res.summary, imu_report)
        else:
            res = process(mode, imu, grade, lever, raw_obs=raw, nav=nav, spp_opts=opts.spp, lc_fixes=lc,
                          events=events, rate_hz=out.rate_hz, forward=forward, smoother_opts=opts.smoother,
                          progress=opts.progress, carrier=carrier, ppk_opts=opts.ppk if carrier else None,
                          dd_opts=opts.dd if carrier else None, imu_checks=opts.imu_checks,
                          estimate_imu_time_offset=opts.estimate_imu_time_offset)
        add_integrity(res.summary, rinex_warnings=rinex_warnings)
    except InputError:
        raise
    except ValueError as exc:
        raise InputError(str(exc), opts.imu.path) from None
    res.summary["imu_grade"] = grade.datasheet()
    if nav is not None:
        res.summary["orbits"] = nav.orbits   # broadcast, or the precise products' files
    if base_info is not None:
        res.summary.setdefault("carrier", {}).update(base_info)
    if withheld is not None:
        res.summary["withheld_fixes"] = withheld_fix_errors(res.trajectory, withheld, lever)
        res.withheld = withheld
    return res


def run_ukf(opts: UkfModeOptions, imu, grade, lever, raw, nav, lc: GnssFixes | None, events) -> UkfPosResult:
    """`--mode ukf`: the fixes (`opts.fixes`, or SPP of the RINEX) through seed 000's UKF, the LC smoother beside it
    and the truth when given (dgcal.pos.lowcost.ukf_pos.process_ukf)."""
    fixes = lc
    if fixes is None:
        if raw is None:
            raise InputError("ukf mode needs antenna positions (or the rover's RINEX observations and navigation)",
                             field="fixes.path")
        fixes = fixes_from_spp(spp(raw, nav, opts.spp, progress=opts.progress))
    run = opts.ukf_run
    truth = read_true_trajectory(opts.truth) if opts.truth else None
    return process_ukf(imu, grade, lever, fixes, events, opts.output.rate_hz, opts.ukf, compare=run.compare,
                       compare_rate_hz=run.compare_rate_hz, smoother_opts=opts.smoother, truth=truth,
                       skip_s=run.skip_s, progress=opts.progress)


def outage_mask(t: np.ndarray, outages: tuple[float, float, float]) -> np.ndarray:
    """Epochs inside simulated GNSS outages `(start, length, period)` (s): [t0+start+k*period, +length)."""
    start, length, period = (float(v) for v in outages)
    if not (length > 0 and period > length and start >= 0):
        raise InputError(f"need start >= 0, length > 0 and period > length, not {start:g} {length:g} {period:g}",
                         field="fixes.outages")
    x = np.asarray(t, float) - (float(t[0]) + start)
    return (x >= 0) & (np.mod(x, period) < length)
