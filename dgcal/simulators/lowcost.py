"""The seed 000 low-cost payload flight: IMU, 50 Hz GNSS fixes, true trajectory (dgcal.sim.lowcost_flight)."""
from __future__ import annotations

import argparse
from pathlib import Path

from dgcal.sim import lowcost_flight
from dgcal.sim.lowcost_flight import simulate_lowcost_flight, write_lowcost_dataset
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "lowcost"
HELP = "seed 000 low-cost payload flight: ADIS16405 IMU, 50 Hz GNSS, laser range (113 m, 26 m/s)"
DESCRIPTION = lowcost_flight.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=arg_types.positive, default=360.0, help="flight length (s)")
    p.add_argument("--speed", type=arg_types.positive, default=26.0,
                   help="ground speed (m/s; e.g. 1 for a slow platform, default 26 as the seed's)")
    p.add_argument("--static", type=arg_types.non_negative, default=0.0, metavar="S",
                   help="rest this long first (GNSS running), then accelerate to --speed")
    p.add_argument("--gnss-outages", type=arg_types.non_negative, nargs=3, default=None,
                   metavar=("START", "LENGTH", "PERIOD"),
                   help="withhold the fixes of LENGTH s every PERIOD s from START s after the first fix")
    p.add_argument("--height", type=arg_types.positive, default=113.0, help="height above ground (m)")


def run(args: argparse.Namespace) -> int:
    out = tuple(args.gnss_outages) if args.gnss_outages else None
    if out is not None and not (out[1] > 0 and out[2] > out[1]):
        raise SystemExit(f"dgcal simulate lowcost: error: --gnss-outages needs LENGTH > 0 and PERIOD > LENGTH, not "
                         f"{out[1]:g} {out[2]:g}")
    fl = simulate_lowcost_flight(duration_s=args.duration, seed=args.seed, speed=args.speed, static_s=args.static,
                                 gnss_outages=out, height_agl=args.height)
    write_lowcost_dataset(args.out, fl, args.seed)
    print(f"wrote {args.out}/imu.csv, gnss_fixes.csv, gnss.csv, events.csv, truth_trajectory.csv, truth.json")
    return 0
