"""Time synchronisation of a low-cost logger (seed 000): restore lost packets, align to GPS time by PPS,
find exposure times from the photoresistor channel, match triggers and images; writes events.csv."""
from __future__ import annotations

import argparse
from pathlib import Path

NAME = "sync"
HELP = "restore and align logger streams, find exposure times, write events.csv"
OUTPUTS = {"events": "events.csv", "summary": "sync.json", "report": "report.html"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--gnss-log", required=True, type=Path, help="CSV gps_week,gps_sow[,h] of the GNSS packets")
    p.add_argument("--logger", required=True, type=Path, help="CSV counter,pps,photo[,trigger][,laser]")
    p.add_argument("--images", required=True, type=Path, help="image folder, or CSV image[,camera_time_s]")
    p.add_argument("--rate", type=float, default=50.0, help="logger sample rate (Hz)")
    p.add_argument("--gnss-rate", type=float, default=None, help="GNSS packet rate (Hz; default: --rate)")
    p.add_argument("--counter-bits", type=int, default=16, help="logger counter width for wrap-around (0: none)")
    p.add_argument("--tau", type=float, default=0.05, help="light sensor time constant (s)")
    p.add_argument("--blackout", type=float, default=0.06, help="camera viewfinder blackout (mirror-up) time (s)")
    p.add_argument("--out", required=True, type=Path)


def run(args: argparse.Namespace) -> int:
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.pos.lowcost.sync import SyncOptions, synchronise_logger_files
    from dgcal.reports.sync import write_sync_outputs

    res = synchronise_logger_files(SyncOptions(args.gnss_log, args.logger, args.images, rate_hz=args.rate,
                                               gnss_rate_hz=args.gnss_rate, counter_bits=args.counter_bits or None,
                                               tau=args.tau, blackout_s=args.blackout))
    with staged_dir(args.out) as tmp:
        write_sync_outputs(tmp, res, OUTPUTS)
    s = res.summary()
    print(f"{s['n_events']} events; clock drift {s['clock_drift'] * 1e6:.1f} ppm, bound {s['clock_max_error_s'] * 1e3:.2f} ms; "
          f"skipped triggers {len(s['skipped_triggers'])}; report {args.out / OUTPUTS['report']}")
    return 0
