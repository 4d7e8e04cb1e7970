"""Time synchronisation of a low-cost logger (seed 000): restore lost packets, fit the logger clock to its PPS,
take the whole second from the laser/baro against the GNSS height (or GNSS time in the logger, or stream ends
within --end-gap), find exposure times from the photoresistor channel, match triggers and images; writes
events.csv — or exits 2 naming the check that failed (dgcal.pos.lowcost.sync lists them)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "sync"
HELP = "restore and align logger streams, find exposure times, write events.csv (every stage checked)"
OUTPUTS = {"events": "events.csv", "exposures": "exposures.csv", "summary": "sync.json", "report": "report.html"}
# SyncOptions fields named in library errors -> flags where the names differ
OPTION_FLAGS = {"blackout_s": "--blackout", "rate_hz": "--rate", "max_time_error_s": "--max-time-error",
                "end_gap_s": "--end-gap", "logger_columns": "--logger-column"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--gnss-log", required=True, type=Path, help="GNSS packet log: CSV gps_week,gps_sow[,h]")
    p.add_argument("--logger", required=True, type=Path, help="logger stream: CSV counter,pps,photo[,trigger]"
                   "[,laser][,baro] (other layouts: --logger-format)")
    p.add_argument("--images", required=True, type=Path, help="image folder, or CSV image[,camera_time_s]")
    p.add_argument("--logger-format", type=Path, default=None, metavar="FORMAT.toml",
                   help="column/unit description of the logger and GNSS logs (dgcal.pos.lowcost.logger_format)")
    p.add_argument("--logger-column", action="append", default=[], metavar="ROLE=COLUMN",
                   help="logger column of a role (counter, pps, photo, trigger, laser, baro, gps_time); repeatable")
    p.add_argument("--laser-unit", default=None, help="laser range unit: m, cm, mm, ft")
    p.add_argument("--rate", type=arg_types.positive, default=None,
                   help="logger sample rate (Hz; default: the format's, 50)")
    p.add_argument("--gnss-rate", type=arg_types.positive, default=None,
                   help="GNSS packet rate (Hz; default: --rate)")
    p.add_argument("--counter-bits", type=arg_types.positive_int, default=None,
                   help="logger counter width for wrap-around (0: none; "
                   "default: the format's, 16)")
    p.add_argument("--tau", type=arg_types.positive, default=0.05, help="light sensor time constant (s)")
    p.add_argument("--blackout", type=arg_types.non_negative, default=0.06,
                   help="camera viewfinder blackout (mirror-up) time (s)")
    p.add_argument("--end-gap", type=arg_types.non_negative, default=None, metavar="S",
                   help="the recorders stopped within S s of each other (default: unknown; the laser/baro "
                   "alignment then fixes the whole second, and S only cross-checks it); below 0.45 s to pick the whole "
                   "second from the ends alone")
    p.add_argument("--search-range", type=arg_types.non_negative, default=None, metavar="S",
                   help="coarse search within S s of the stream-end offset (default: the whole overlap)")
    p.add_argument("--max-drift-ppm", type=arg_types.positive, default=200.0, help="plausible crystal drift (ppm)")
    p.add_argument("--max-time-error", type=arg_types.positive, default=0.005, metavar="S",
                   help="the events must be good to S s (clock bound + 3 sigma); default 0.005")
    p.add_argument("--out", required=True, type=Path)


def run(args: argparse.Namespace) -> int:
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.pos.lowcost.sync import SyncOptions, synchronise_logger_files
    from dgcal.reports.sync import write_sync_outputs

    res = synchronise_logger_files(SyncOptions(
        args.gnss_log, args.logger, args.images, rate_hz=args.rate, gnss_rate_hz=args.gnss_rate,
        counter_bits=args.counter_bits, tau=args.tau, blackout_s=args.blackout,
        logger_format=args.logger_format, logger_columns=tuple(args.logger_column), laser_unit=args.laser_unit,
        end_gap_s=args.end_gap, search_s=args.search_range, max_drift_ppm=args.max_drift_ppm,
        max_time_error_s=args.max_time_error))
    with staged_dir(args.out) as tmp:
        write_sync_outputs(tmp, res, OUTPUTS)
    s = res.summary()
    for w in s["warnings"]:
        print(f"warning: {w}", file=sys.stderr)
    print(f"{s['n_events']} events of {s['n_images']} images ({len(s['unmatched_images'])} unmatched); clock drift "
          f"{s['clock_drift_ppm']:.1f} ppm, bound {s['clock_max_error_s'] * 1e3:.2f} ms; whole second by "
          f"{s['coarse_alignment'].get('method')}; skipped triggers {len(s['skipped_triggers'])}; "
          f"report {args.out / OUTPUTS['report']}")
    return 0
