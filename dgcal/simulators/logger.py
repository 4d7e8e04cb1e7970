"""A low-cost logger's GNSS and sensor streams with packet loss, PPS and triggers (dgcal.sim.logger)."""
from __future__ import annotations

import argparse
from pathlib import Path

from dgcal.sim import logger
from dgcal.sim.logger import simulate_logger, write_logger_sim
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "logger"
HELP = "GNSS and logger streams with packet loss, PPS, photoresistor spikes and triggers (seed 000)"
DESCRIPTION = logger.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=arg_types.finite, default=720.0, help="flight length (s)")


def run(args: argparse.Namespace) -> int:
    write_logger_sim(args.out, simulate_logger(seed=args.seed, duration_s=args.duration))
    print(f"wrote {args.out}/logger.csv, gnss_log.csv, images.csv, truth.json")
    return 0
