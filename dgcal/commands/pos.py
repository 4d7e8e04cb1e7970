"""Position the GNSS antenna (--mode spp) or smooth a GNSS/INS trajectory (--mode tc|lc).

--mode spp writes DIR/gnss.csv: one row per epoch with a fix, columns
gps_week,gps_sow,x,y,z (ECEF, m), vx,vy,vz (m/s), sx,sy,sz, svx,svy,svz (1-sigma, ECEF),
lat,lon,h (deg, deg, m ellipsoidal), s_e,s_n,s_u (m), clk_G_m,clk_E_m,clk_C_m (receiver clock
bias per clock group, metres = c*dt; QZSS shares GPS's), drift_mps (c*clock drift, m/s),
n_sat, gdop,pdop,hdop,vdop, chi2_dof, rejected (satellites removed by RAIM, ';'-separated);
DIR/gnss_summary.json and DIR/gnss_report.html. --mode ppk (rover + base RINEX, carrier phase) writes
DIR/gnss.csv with gps_week,gps_sow,x,y,z (ECEF, m), fix (fixed/float/single), n_sat, ratio, sx,sy,sz (m),
sxy,sxz,syz (RTKLIB's signed square roots of the covariances, m), lat,lon,h, s_e,s_n,s_u, age_s,
n_fixed_amb, fix_forward, fix_backward, plus gnss_summary.json and gnss_report.html (dgcal.pos.ppk_mode.run_ppk).
--mode tc|lc hand over to dgcal.pos.gnss_ins.run_gnss_ins (trajectory.csv, events.csv). --mode ukf runs seed 000's
UKF on the same inputs (dgcal.pos.lowcost.ukf_pos) and writes trajectory.csv, events.csv, trajectory_fixes.csv
(every fix epoch), accuracy.csv (the UKF beside the lc smoother, against --truth when given) and the report.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dgcal.steps import Campaign
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "pos"
HELP = "GNSS single-point positioning, carrier-phase PPK, or GNSS/INS smoothing (trajectory + events)"
SECTION = "pos"
SPP_OUTPUTS = {"gnss": "gnss.csv", "gnss_summary": "gnss_summary.json", "gnss_report": "gnss_report.html"}
INS_OUTPUTS = {"trajectory": "trajectory.csv", "events": "events.csv", "trajectory_forward": "trajectory_forward.csv",
               "summary": "pos_summary.json", "report": "report.html"}  # --mode tc|lc
UKF_OUTPUTS = {"trajectory": "trajectory.csv", "events": "events.csv", "trajectory_fixes": "trajectory_fixes.csv",
               "accuracy": "accuracy.csv", "summary": "pos_summary.json", "report": "report.html"}  # --mode ukf
OUTPUTS = {**SPP_OUTPUTS, **INS_OUTPUTS, **{k: v for k, v in UKF_OUTPUTS.items() if k not in INS_OUTPUTS}}


def _ratio(text: str) -> float:
    """--ar-ratio: a finite ratio of at least 1 (the second-best candidate's norm over the best's)."""
    v = float(text)
    if not (v >= 1.0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a number >= 1, not {text}")
    return v


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rinex-obs", metavar="OBS", help="RINEX 2.10/2.11/3.x observation file of the rover")
    p.add_argument("--rinex-nav", metavar="NAV", nargs="+",
                   help="RINEX 3 (mixed) or RINEX 2 GPS broadcast navigation file(s)")
    p.add_argument("--sp3", metavar="SP3", nargs="+", default=None,
                   help="precise orbits (SP3-c/d, plain or .gz; with their own clocks unless --clk) for spp, ppk and "
                   "tc: every satellite's orbit and clock from them; --rinex-nav still gives group delays and "
                   "ionosphere (docs/gnss.md)")
    p.add_argument("--clk", metavar="CLK", nargs="+", default=None,
                   help="precise satellite clocks (RINEX clock files, plain or .gz) beside --sp3")
    p.add_argument("--atx", metavar="ANTEX", default=None,
                   help="satellite antenna phase-centre offsets (ANTEX file, e.g. igs20.atx) for the --sp3 orbits "
                   "(without it they are the satellites' centres of mass)")
    p.add_argument("--mode", choices=("spp", "ppk", "tc", "lc", "ukf"), default="spp",
                   help="spp: GNSS code only; ppk: carrier-phase PPK against --rinex-base; tc: tightly coupled "
                   "GNSS/INS; lc: loosely coupled; ukf: seed 000's 15-state UKF on the fixes (--gnss or SPP), "
                   "the lc smoother beside it")
    p.add_argument("--truth", metavar="TRUTH.csv", default=None,
                   help="ukf: true trajectory (trajectory CSV or a simulator's truth_trajectory.csv) for the accuracy "
                   "table")
    p.add_argument("--rinex-base", metavar="BASE", help="RINEX observation file of the base station (ppk; tc: "
                   "double-differenced carrier phase and code against it)")
    p.add_argument("--base-position", type=arg_types.finite, nargs=3, metavar=("X", "Y", "Z"), default=None,
                   help="base antenna position, ECEF m (ppk, tc with --rinex-base; default: the base header's "
                   "APPROX POSITION, with a warning)")
    p.add_argument("--base-position-llh", type=arg_types.finite, nargs=3, metavar=("LAT", "LON", "H"), default=None,
                   help="base antenna position, geodetic degrees and ellipsoidal height m (ppk, tc)")
    p.add_argument("--dynamics", choices=("kinematic", "static"), default="kinematic",
                   help="ppk rover model: kinematic (any motion, default) or static")
    p.add_argument("--ppk-solution", choices=("combined", "forward", "backward"), default="combined",
                   help="ppk: forward + backward combined (default), or one pass")
    p.add_argument("--ar-ratio", type=_ratio, default=3.0, help="ppk: ratio-test threshold of ambiguity fixing")
    p.add_argument("--frequencies", type=int, default=3, choices=(1, 2, 3),
                   help="ppk: frequencies per system (L1/L2/L5, E1/E5a/E5b, ...)")
    p.add_argument("--imu", metavar="IMU", help="IMU file (tc/lc): dgcal CSV, KF-GINS text, a PX4 .ulg, a ROS 1/2 bag "
                   "(sensor_msgs/Imu), or as --imu-format says")
    p.add_argument("--imu-format", metavar="NAME|FILE.toml", default=None,
                   help="IMU file description: a preset (dgcal, kf-gins, rtklibexplorer, rtklibexplorer-sf) or a TOML "
                   "file (columns, units, time, axes; docs/formats.md)")
    p.add_argument("--imu-set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one key of the IMU description (repeatable), e.g. units.gyro=deg/s, "
                   "axes.euler_zyx_deg=[180,0,180], time.kind=unix_utc")
    p.add_argument("--imu-tag", metavar="FILE.tag", default=None,
                   help="RTKLIB time-tag file of a tick-counter IMU log (default: the IMU file + .tag)")
    p.add_argument("--imu-time-offset", type=arg_types.finite, default=0.0, metavar="S",
                   help="seconds added to every IMU sample time (e.g. -0.125 for a logger's delay)")
    p.add_argument("--estimate-imu-time-offset", action="store_true",
                   help="tc/lc: estimate the IMU-GNSS time offset (beyond --imu-time-offset) from the data, with its "
                   "sigma (9-13 smoother runs; needs motion); reported in pos_summary.json imu_time_offset, not "
                   "applied when the data do not determine it")
    p.add_argument("--events", metavar="EVENTS",
                   help="camera events (tc/lc, optional): dgcal CSV image,gps_week,gps_sow, DJI .MRK, image,utc CSV "
                   "or a PX4 .ulg (camera_capture)")
    p.add_argument("--events-format", choices=("dgcal", "mrk", "utc-csv", "px4"), default=None,
                   help="format of --events (default: recognised by content)")
    p.add_argument("--event-images", metavar="DIR",
                   help="DJI MRK events: the folder of the images its rows are paired with (by --mrk-pairing)")
    p.add_argument("--mrk-names", default="DJI_{index:04d}.JPG", metavar="PATTERN",
                   help="DJI MRK events: an image name per row, or with --event-images the pattern its index is "
                   "found in ({index}, {any} or *; 're:' + a regex with (?P<index>...)); e.g. 'DJI_{any}_{index}.JPG' "
                   "for a P1's DJI_<yyyymmddhhmmss>_<index>.JPG (default %(default)s)")
    p.add_argument("--mrk-pairing", choices=("index", "time"), default="index",
                   help="DJI MRK events with --event-images: pair rows and images by the index in the names, or in "
                   "time order (default %(default)s)")
    p.add_argument("--gnss", metavar="GNSS", help="GNSS antenna positions for lc mode: dgcal gnss.csv, RTKLIB .pos "
                   "(llh or xyz, with its covariance), NMEA GGA or a ROS 1/2 bag (sensor_msgs/NavSatFix)")
    p.add_argument("--gnss-format", choices=("dgcal-csv", "rtklib-pos", "nmea", "rosbag"), default=None,
                   help="format of --gnss (default: recognised by content)")
    p.add_argument("--gnss-quality", default=None, metavar="Q[,Q]",
                   help="lc: fix qualities of --gnss to use (fixed, float, sbas, dgps, single, ppp; default all)")
    p.add_argument("--gnss-outages", type=arg_types.finite, nargs=3, default=None,
                   metavar=("START", "LENGTH", "PERIOD"),
                   help="lc: withhold the --gnss fixes inside outages of LENGTH s every PERIOD s from START s "
                   "after the first fix, and report the trajectory's errors at them (pos_summary.json withheld_fixes)")
    p.add_argument("--nmea-date", default=None, metavar="YYYY-MM-DD",
                   help="UTC date of an NMEA log without RMC sentences")
    p.add_argument("--sbet-out", metavar="FILE.out", default=None,
                   help="tc/lc: also write the trajectory as an Applanix SBET (and FILE's smrmsg beside it)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--systems", default="GECJ", help="constellations to use, letters of G,E,C,J (and R: GLONASS, in "
                   "spp, and in lc/ukf without a base station through their SPP fixes)")
    p.add_argument("--elev-mask", type=arg_types.elevation_deg, default=10.0, help="elevation mask, degrees")
    p.add_argument("--code-sigma", type=arg_types.positive, default=0.3,
                   help="code noise at zenith, m (real data: the starting value; the receiver's own is estimated from "
                   "its residuals, --set code_sigma_from_data=false keeps this one)")
    p.add_argument("--doppler-sigma", type=arg_types.positive, default=0.1, help="range-rate noise at zenith, m/s")
    p.add_argument("--no-raim", action="store_true", help="keep all satellites (no outlier rejection)")
    p.add_argument("--iono", choices=("klobuchar", "auto", "iono-free"), default="klobuchar",
                   help="spp/tc code ionosphere: the broadcast Klobuchar model on the first code (default), the "
                   "dual-frequency ionosphere-free combination where a second code exists (auto), or only that")
    p.add_argument("--t-start", type=arg_types.finite, default=None, help="first epoch, continuous GPS seconds")
    p.add_argument("--t-end", type=arg_types.finite, default=None, help="last epoch, continuous GPS seconds")
    p.add_argument("--lever-arm", type=arg_types.finite, nargs=3, metavar=("X", "Y", "Z"), default=None,
                   help="GNSS antenna lever arm in the IMU body frame, m (tc/lc/ukf)")
    p.add_argument("--imu-grade", default=None,
                   help="IMU error model (tc/lc/ukf; default adis16488): a preset (navigation, adis16488, adis16405, "
                   "consumer) or a datasheet "
                   "TOML file (ARW, VRW, bias instabilities, scale factors, range; docs/formats.md)")
    p.add_argument("--set", dest="extra", action="append", default=[], metavar="KEY=VALUE",
                   help="further option (repeatable): a field of the mode's options, KEY or GROUP.KEY (spp: "
                   "SppOptions; ppk: PpkOptions; tc/lc: smoother, output, imu_checks, spp, and dd, ppk with "
                   "--rinex-base; ukf: ukf, ukf_run, smoother, output; docs/gnss.md); another mode's key is an error")
    p.add_argument("--reference", type=arg_types.finite, nargs=3, metavar=("X", "Y", "Z"), default=None,
                   help="known antenna position (ECEF, m) for the spp/ppk summary and report")
    p.add_argument("--forward-filter", action="store_true",
                   help="tc/lc: trajectory_forward.csv and the innovations from an iterated Kalman filter about its "
                   "own estimates (slower) instead of the forward pass of the smoother's linearised problem")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--no-report", action="store_true",
                   help="skip the HTML report of any mode (the CSV and JSON files are still written)")


# option fields named in library errors -> this verb's flags where the names differ (dgcal.cli maps the rest)
OPTION_FLAGS = {"rinex_nav": "--rinex-nav", "base.rinex": "--rinex-base", "base.position_ecef": "--base-position",
                "base.position_llh": "--base-position-llh", "ppk.dynamics": "--dynamics",
                "ppk.solution": "--ppk-solution", "ppk.n_freq": "--frequencies", "ppk.ratio_threshold": "--ar-ratio",
                "ppk.systems": "--systems", "spp.systems": "--systems", "imu.path": "--imu",
                "imu.format": "--imu-format", "imu.overrides": "--imu-set", "imu.tag": "--imu-tag",
                "imu.time_offset_s": "--imu-time-offset",
                "fixes.path": "--gnss", "fixes.format": "--gnss-format", "fixes.quality": "--gnss-quality",
                "fixes.nmea_date": "--nmea-date", "fixes.outages": "--gnss-outages", "quality": "--gnss-quality",
                "imu_grade": "--imu-grade", "lever_arm_m": "--lever-arm", "mode": "--mode",
                "estimate_imu_time_offset": "--estimate-imu-time-offset", "reference_ecef": "--reference"}


def _systems(text: str, mode: str = "spp", carrier: bool = False) -> tuple[str, ...]:
    from dgcal.fields.errors import InputError
    systems = tuple(dict.fromkeys(s for s in str(text).upper() if s in "GECJR"))
    # GLONASS serves spp, and lc/ukf through their SPP fixes; not tc or a base station's double differences
    if "R" in systems and (mode in ("ppk", "tc") or carrier):
        print(f"warning: --mode {mode}{' with a base station' if carrier and mode != 'ppk' else ''} does not use "
              "GLONASS (R): spp, and lc/ukf without a base station, do", file=sys.stderr)
        systems = tuple(s for s in systems if s != "R")
    if not systems:
        raise InputError(f"no known constellation in '{text}' (letters of G, E, C, J, R; R for spp, lc, ukf)",
                         field="--systems")
    return systems


def _other_modes(mode: str) -> dict:
    """Default options of every other mode: where a `--set` key that this mode lacks belongs (imported only then)."""
    from dgcal.pos.mode_options import MODE_OPTIONS
    return {m: (cls(mode=m) if m in ("tc", "lc") else cls()) for m, cls in MODE_OPTIONS.items() if m != mode}


def _nav_files(args: argparse.Namespace) -> tuple:
    """--rinex-nav's files, then --sp3's, --clk's and --atx's (each checked to be what its flag says): the navigation
    files every mode reads together (dgcal.pos.gnss.rinex.read_rinex_nav tells them apart by content)."""
    from dgcal.pos.gnss.precise import require_kind
    sp3, clk, atx = (getattr(args, k, None) for k in ("sp3", "clk", "atx"))
    return (tuple(args.rinex_nav or ()) + tuple(require_kind(f, "sp3", "--sp3") for f in sp3 or ())
            + tuple(require_kind(f, "clk", "--clk") for f in clk or ())
            + ((require_kind(atx, "atx", "--atx"),) if atx else ()))


def spp_mode_options(args: argparse.Namespace):
    """The dgcal.pos.gnss.spp_mode.SppModeOptions of a parsed `dgcal pos` command line (GNSS modules only)."""
    from dgcal.pos.gnss.spp import SppOptions
    from dgcal.pos.gnss.spp_mode import RinexInput, SppModeOptions
    spp = SppOptions(elev_mask_deg=args.elev_mask, code_sigma_zenith_m=args.code_sigma,
                     doppler_sigma_zenith_mps=args.doppler_sigma,
                     systems=_systems(args.systems, getattr(args, "mode", "spp"),
                                      bool(getattr(args, "rinex_base", None))),
                     raim=not args.no_raim, iono=args.iono)
    return SppModeOptions(RinexInput(args.rinex_obs, _nav_files(args), args.t_start, args.t_end), spp,
                          None if args.reference is None else tuple(args.reference), not args.no_progress)


def pos_options(args: argparse.Namespace):
    """The options object of the chosen mode (dgcal.pos.mode_options) of a parsed `dgcal pos` command line, its
    `--set KEY=VALUE` items applied (a key of another mode is an error naming that mode)."""
    if args.mode == "spp":
        opts = spp_mode_options(args)
    else:
        from dgcal.pos.gnss.ppk import PpkOptions
        from dgcal.pos.mode_options import (BaseStation, FixInput, ImuInput, InsModeOptions, PpkModeOptions,
                                            RinexInput, UkfModeOptions)
        tup = lambda v: None if v is None else tuple(v)  # noqa: E731
        spp = spp_mode_options(args).spp
        rover = RinexInput(args.rinex_obs, _nav_files(args), args.t_start, args.t_end)
        base = BaseStation(args.rinex_base, tup(args.base_position), tup(args.base_position_llh))
        ppk_common = dict(systems="".join(spp.systems), n_freq=args.frequencies, elev_mask_deg=args.elev_mask,
                          ar_elev_mask_deg=args.elev_mask, ratio_threshold=args.ar_ratio)
        if args.mode == "ppk":
            opts = PpkModeOptions(rover, base, PpkOptions(**ppk_common, dynamics=args.dynamics,
                                                          solution=args.ppk_solution), spp, tup(args.reference),
                                  not args.no_progress)
        else:
            cls = UkfModeOptions if args.mode == "ukf" else InsModeOptions
            opts = cls(mode=args.mode, rover=rover, base=base, spp=spp,
                       imu=ImuInput(args.imu, args.imu_format, tuple(args.imu_set or ()), args.imu_tag,
                                    float(args.imu_time_offset or 0.0)),
                       fixes=FixInput(args.gnss, args.gnss_format, args.gnss_quality, args.nmea_date,
                                      tup(args.gnss_outages)),
                       events=args.events, events_format=args.events_format, event_images=args.event_images,
                       mrk_names=args.mrk_names, mrk_pairing=args.mrk_pairing, lever_arm_m=tup(args.lever_arm),
                       imu_grade=args.imu_grade, estimate_imu_time_offset=bool(args.estimate_imu_time_offset),
                       progress=not args.no_progress)
            opts.ppk = PpkOptions(**{**vars(opts.ppk), **ppk_common})
            opts.dd.elev_mask_deg = args.elev_mask
            opts.output.forward_filter = bool(args.forward_filter)
            if args.mode == "ukf":
                opts.truth = args.truth
    if args.extra:
        from dgcal.settings import apply_settings
        apply_settings(opts, args.extra, others=lambda: _other_modes(args.mode))
    return opts


def spp_files_in(out_dir: Path, args: argparse.Namespace) -> tuple[dict, dict]:
    """`dgcal pos --mode spp`'s positioning: gnss.csv and its summary written in `out_dir`; returns the summary and
    the series its report plots (dgcal.reports.gnss.spp_report_series: plain arrays, which pickle without the GNSS
    modules). Imports the GNSS modules only, not dgcal.pos.mode_options (whose GNSS/INS imports take longer than the
    SPP) nor matplotlib."""
    from dgcal.pos.gnss.spp_mode import run_spp
    from dgcal.reports.gnss import spp_report_series, write_spp_files
    sp = run_spp(pos_options(args))
    write_spp_files(out_dir, sp, SPP_OUTPUTS)
    return sp.summary, (None if args.no_report else spp_report_series(sp.solution, sp.reference_ecef))


def run(args: argparse.Namespace) -> int:
    from dgcal.fields.io.atomic import staged_dir   # why not csv_tables: SPP forks before anything imports numpy
    from dgcal.fields.processes import forked_call
    if args.mode == "spp":
        if args.extra:
            pos_options(args)              # --set keys refused before anything is written
        with staged_dir(args.out) as tmp:
            if args.no_report:
                s = spp_files_in(tmp, args)[0]
            else:
                with forked_call(spp_files_in, tmp, args) as positioned:   # the GNSS work beside matplotlib's import
                    from dgcal.reports.gnss_page import draw_spp_report
                    s, series = positioned()
                draw_spp_report(tmp / SPP_OUTPUTS["gnss_report"], series, s)
        print(f"{Path(args.out) / SPP_OUTPUTS['gnss']}: {s['n_fixed']}/{s['n_epochs']} epochs, "
              f"median sigma 3D {s['median_sigma_3d_m']:.2f} m", file=sys.stderr)
        return 0
    opts = pos_options(args)
    if opts.mode == "ppk":
        from dgcal.pos.ppk_mode import run_ppk
        from dgcal.reports.ppk import write_ppk_outputs
        run_ = run_ppk(opts)
        with staged_dir(args.out) as tmp:
            write_ppk_outputs(tmp, run_, SPP_OUTPUTS, report=not args.no_report)
        s = run_.summary
        for w in run_.warnings:
            print(f"warning: {w}", file=sys.stderr)
        c = s["counts"]
        msg = (f"{Path(args.out) / SPP_OUTPUTS['gnss']}: PPK {c['fixed']} fixed, {c['float']} float, {c['single']} "
               f"single of {s['n_epochs']} epochs ({100 * s['fix_rate']:.1f} % fixed)")
        if "error_fixed" in s:
            msg += f"; fixed-epoch 3D RMS {1e3 * s['error_fixed']['rms_3d_m']:.1f} mm vs --reference"
        print(msg, file=sys.stderr)
        return 0
    from dgcal.pos.gnss_ins import run_gnss_ins
    from dgcal.reports.pos import write_pos_outputs
    res = run_gnss_ins(opts)
    for w in res.summary.get("warnings", []):       # data integrity (IMU, GNSS epochs, RINEX records)
        print(f"warning: {w}", file=sys.stderr)
    if opts.mode == "ukf":
        from dgcal.reports.ukf import write_ukf_outputs
        with staged_dir(args.out) as tmp:
            write_ukf_outputs(tmp, res, UKF_OUTPUTS, report=not args.no_report)
        s = res.summary
        print(f"{Path(args.out) / UKF_OUTPUTS['trajectory']}: UKF {s['keyframes']} epochs, {s['events']} events, "
              f"median sigma position {_triple(s['median_sigma_m'], 3)} m, "
              f"attitude {_triple(s['median_sigma_deg'], 3)} deg"
              + ("" if args.no_report else f"; report {Path(args.out) / UKF_OUTPUTS['report']}"), file=sys.stderr)
        return 0
    with staged_dir(args.out) as tmp:
        write_pos_outputs(tmp, res, INS_OUTPUTS, report=not args.no_report)
        if getattr(args, "sbet_out", None):
            from dgcal.pos.ins.sbet import write_sbet_files
            sbet = Path(args.sbet_out)
            staged = tmp / sbet.name if not sbet.is_absolute() and len(sbet.parts) == 1 else None
            write_sbet_files(staged if staged is not None else sbet, res.trajectory)
    s = res.summary
    print(f"{Path(args.out) / INS_OUTPUTS['trajectory']}: {opts.mode.upper()} {s['keyframes']} keyframes, "
          f"{s['events']} events, median sigma position {_triple(s['median_sigma_m'], 3)} m, "
          f"attitude {_triple(s['median_sigma_deg'], 4)} deg", file=sys.stderr)
    if "imu_time_offset" in s:
        o = s["imu_time_offset"]
        if o.get("determinable", True):
            print(f"IMU time offset estimated: {o['offset_ms']:+.2f} +- {o['sigma_ms']:.2f} ms (applied on top of "
                  f"--imu-time-offset {1e3 * opts.imu.time_offset_s:+.1f} ms)", file=sys.stderr)
        else:
            print(f"IMU time offset not determinable by these data (best fit {o.get('estimate_ms', float('nan')):+.1f}"
                  f" ms, its time windows disagree: sigma {o.get('sigma_ms', float('nan')):.1f} ms): not applied, "
                  f"--imu-time-offset {1e3 * opts.imu.time_offset_s:+.1f} ms stands", file=sys.stderr)
    w = s.get("withheld_fixes")
    if w and w.get("n"):
        print(f"withheld fixes: {w['n']}, antenna 3D RMS {w['rms_3d_m']} m (N,E,D {w['rms_ned_m']} m), max "
              f"{w['max_3d_m']} m", file=sys.stderr)
    return 0


def _is_ubx(path) -> bool:
    """Whether a campaign's rover file is a u-blox UBX log (read only then: the check reads the file's head)."""
    from dgcal.pos.gnss.gnss_files import is_ubx_file
    return path is not None and is_ubx_file(path)      # False for a file that cannot be read


def campaign_steps(c: Campaign) -> None:
    """[pos] -> `dgcal pos --mode lc|tc`: `imu`, `events`, `gnss` (lc) or `rinex_obs` + `rinex_nav` (a UBX log as
    `rinex_obs` needs no `rinex_nav`; tc: with
    `rinex_base`, `base_position` [X, Y, Z] ECEF m and `frequencies`, carrier phase against the base), `imu_grade`,
    `lever_arm_gnss`, `set` = [KEY=VALUE], `args`; with `trajectory` (+ `events`) an external POS is used and no
    step runs. Provides the trajectory and events to later steps."""
    pos = c.section(SECTION)
    if pos is None:
        return
    traj = c.path(SECTION, "trajectory", required=False)
    if traj is not None:
        c.provide("trajectory", traj)
        events = c.path(SECTION, "events", required=False)
        if events is not None:
            c.provide("events", events)
        return
    mode = str(pos.get("mode", "lc"))
    if mode not in ("lc", "tc"):
        raise c.error(f"[pos] mode must be lc or tc, not {mode!r}", "pos.mode")
    imu, events = c.path(SECTION, "imu"), c.path(SECTION, "events")
    out = c.out / "pos"
    a = [NAME, "--mode", mode, "--imu", str(imu), "--events", str(events), "--out", str(out), "--no-progress"]
    ins = [imu, events]
    if mode == "lc" and "gnss" in pos:
        a += ["--gnss", str(c.path(SECTION, "gnss"))]
        ins.append(c.path(SECTION, "gnss"))
    elif "rinex_obs" in pos or mode == "tc":
        obs = c.path(SECTION, "rinex_obs")
        # a u-blox UBX log is its own navigation file (`RinexInput`): rinex_nav may be left out for one
        nav = c.path(SECTION, "rinex_nav", required=not _is_ubx(obs))
        a += ["--rinex-obs", str(obs)] + ([] if nav is None else ["--rinex-nav", str(nav)])
        ins += [obs] + ([] if nav is None else [nav])
        if mode == "tc" and "rinex_base" in pos:   # carrier phase against a base station
            base = c.path(SECTION, "rinex_base")
            a += ["--rinex-base", str(base)]
            ins.append(base)
            if "base_position" in pos:
                a += ["--base-position", *map(str, c.vec3(SECTION, "base_position"))]
            if "frequencies" in pos:
                a += ["--frequencies", str(int(pos["frequencies"]))]
    else:
        raise c.error("[pos] mode lc needs 'gnss' (or rinex_obs and rinex_nav)", "pos.gnss")
    if "imu_grade" in pos:
        grade = str(pos["imu_grade"])
        if grade.lower().endswith(".toml"):             # a datasheet file, relative to the campaign file
            gp = c.path(SECTION, "imu_grade")
            a += ["--imu-grade", str(gp)]
            ins.append(gp)
        else:
            a += ["--imu-grade", grade]
    if "lever_arm_gnss" in pos:
        a += ["--lever-arm", *map(str, c.vec3(SECTION, "lever_arm_gnss"))]
    for kv in pos.get("set", []):
        a += ["--set", str(kv)]
    a += c.extra_args(SECTION)
    step = c.add(NAME, a, ins, out, INS_OUTPUTS, required=("trajectory", "events"), weight=4.0)
    c.provide("trajectory", step.files["trajectory"])
    c.provide("events", events)


def _triple(values, digits: int) -> str:
    """'a/b/c' of a number or a sequence of numbers (one line for people, not a Python list)."""
    vals = values if isinstance(values, (list, tuple)) else [values]
    return "/".join(f"{float(v):.{digits}f}" for v in vals)
