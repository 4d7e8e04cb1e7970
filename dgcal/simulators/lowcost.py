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
    p.add_argument("--duration", type=arg_types.finite, default=360.0, help="flight length (s)")


def run(args: argparse.Namespace) -> int:
    write_lowcost_dataset(args.out, simulate_lowcost_flight(duration_s=args.duration, seed=args.seed), args.seed)
    print(f"wrote {args.out}/imu.csv, gnss_fixes.csv, gnss.csv, events.csv, truth_trajectory.csv, truth.json")
    return 0
