"""Position the GNSS antenna (--mode spp) or smooth a GNSS/INS trajectory (--mode tc|lc).

--mode spp writes DIR/gnss.csv: one row per epoch with a fix, columns
gps_week,gps_sow,x,y,z (ECEF, m), vx,vy,vz (m/s), sx,sy,sz, svx,svy,svz (1-sigma, ECEF),
lat,lon,h (deg, deg, m ellipsoidal), s_e,s_n,s_u (m), clk_G_m,clk_E_m,clk_C_m (receiver clock
bias per clock group, metres = c*dt; QZSS shares GPS's), drift_mps (c*clock drift, m/s),
n_sat, gdop,pdop,hdop,vdop, chi2_dof, rejected (satellites removed by RAIM, ';'-separated);
DIR/gnss_summary.json and DIR/gnss_report.html. --mode tc|lc hand over to dgcal.pos.pipeline.run_pos (trajectory.csv, events.csv).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from dgcal.fields.errors import InputError

NAME = "pos"
HELP = "GNSS single-point positioning or GNSS/INS smoothing (trajectory + events)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rinex-obs", metavar="OBS", help="RINEX 3 observation file of the rover")
    p.add_argument("--rinex-nav", metavar="NAV", nargs="+",
                   help="RINEX 3 (mixed) broadcast navigation file(s)")
    p.add_argument("--mode", choices=("spp", "tc", "lc"), default="spp",
                   help="spp: GNSS only; tc: tightly coupled GNSS/INS; lc: loosely coupled")
    p.add_argument("--imu", metavar="IMU", help="IMU file (tc/lc)")
    p.add_argument("--events", metavar="EVENTS.csv", help="camera events image,gps_week,gps_sow (tc/lc)")
    p.add_argument("--gnss", metavar="GNSS.csv", help="GNSS positions for lc mode (gnss.csv of --mode spp)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--systems", default="GECJ", help="constellations to use, letters of G,E,C,J")
    p.add_argument("--elev-mask", type=float, default=10.0, help="elevation mask, degrees")
    p.add_argument("--code-sigma", type=float, default=0.3, help="code noise at zenith, m")
    p.add_argument("--doppler-sigma", type=float, default=0.1, help="range-rate noise at zenith, m/s")
    p.add_argument("--no-raim", action="store_true", help="keep all satellites (no outlier rejection)")
    p.add_argument("--t-start", type=float, default=None, help="first epoch, continuous GPS seconds")
    p.add_argument("--t-end", type=float, default=None, help="last epoch, continuous GPS seconds")
    p.add_argument("--lever-arm", type=float, nargs=3, metavar=("X", "Y", "Z"), default=None,
                   help="GNSS antenna lever arm in the IMU body frame, m (tc/lc)")
    p.add_argument("--imu-grade", default=None,
                   help="IMU error model preset (tc/lc), see dgcal.pos.ins.error_model: navigation, adis16488, "
                   "adis16405, consumer")
    p.add_argument("--set", dest="extra", action="append", default=[], metavar="KEY=VALUE",
                   help="further smoother option for tc/lc (repeatable), passed to dgcal.pos.pipeline")
    p.add_argument("--reference", type=float, nargs=3, metavar=("X", "Y", "Z"), default=None,
                   help="known antenna position (ECEF, m) for the spp report's error plots")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def spp_options_from_args(args: argparse.Namespace):
    from dgcal.pos.gnss.spp import SppOptions
    systems = tuple(s for s in args.systems.upper() if s in "GECJ")
    if not systems:
        raise InputError(f"no known constellation in '{args.systems}'", field="--systems")
    return SppOptions(elev_mask_deg=args.elev_mask, code_sigma_zenith_m=args.code_sigma,
                      doppler_sigma_zenith_mps=args.doppler_sigma, systems=systems,
                      raim=not args.no_raim)


def run(args: argparse.Namespace) -> int:
    if args.mode != "spp":
        try:
            from dgcal.pos.pipeline import run_pos
        except ImportError:
            raise InputError(f"mode {args.mode} not available yet", field="--mode") from None
        from dgcal.reports.pos import write_pos_report
        return int(run_pos(args, report_writer=write_pos_report) or 0)
    for name in ("rinex_obs", "rinex_nav"):
        if not getattr(args, name):
            raise InputError("required for --mode spp", field="--" + name.replace("_", "-"))
    return run_spp(args)


def run_spp(args: argparse.Namespace) -> int:
    """--mode spp: read RINEX, SPP every epoch, write gnss.csv and gnss_summary.json."""
    from dgcal.pos.gnss.rinex import read_rinex_nav, read_rinex_obs
    from dgcal.pos.gnss.spp import spp
    from dgcal.pos.gnss.spp import spp_summary, write_gnss_csv
    from dgcal.fields.io.csv_tables import atomic_write, staged_dir

    opts = spp_options_from_args(args)
    nav = read_rinex_nav(args.rinex_nav[0], args.rinex_nav[1:])
    obs = read_rinex_obs(args.rinex_obs, systems=opts.systems, t_start=args.t_start, t_end=args.t_end)
    sol = spp(obs, nav, opts, progress=not args.no_progress)
    if not sol.ok.any():
        raise InputError("no epoch could be positioned (too few satellites with ephemeris?)",
                         args.rinex_obs)
    summary = spp_summary(sol, obs, nav, opts)
    with staged_dir(args.out) as d:
        write_gnss_csv(Path(d) / "gnss.csv", sol)
        if args.reference is not None:
            import numpy as np
            ok = sol.ok
            err = sol.p_ecef[ok] - np.asarray(args.reference)
            summary["rms_3d_vs_reference_m"] = float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))
        with atomic_write(Path(d) / "gnss_summary.json") as fh:
            json.dump(summary, fh, indent=2)
        from dgcal.reports.gnss import write_spp_report
        write_spp_report(Path(d) / "gnss_report.html", sol, summary, args.reference)
    print(f"{Path(args.out) / 'gnss.csv'}: {summary['n_fixed']}/{summary['n_epochs']} epochs, "
          f"median sigma 3D {summary['median_sigma_3d_m']:.2f} m", file=sys.stderr)
    return 0
