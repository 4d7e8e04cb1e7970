"""A mounting-calibration flight and a mapping flight with known lever arm, boresight and delay
(dgcal.sim.mounting)."""
from __future__ import annotations

import argparse
from pathlib import Path

from dgcal.sim import mounting
from dgcal.sim.mounting import simulate_mounting, write_mounting_sim
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "mounting"
HELP = "a mounting-calibration flight and a mapping flight with known lever arm, boresight and delay"
DESCRIPTION = mounting.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--delay", type=arg_types.finite, default=-0.14, help="exposure delay t_exposure - t_event (s)")
    p.add_argument("--lever-arm", type=arg_types.finite, nargs=3, default=(-0.30, 0.12, 0.20), metavar=("X", "Y", "Z"),
                   help="lever arm IMU -> camera in body FRD (m)")
    p.add_argument("--crs", default="EPSG:32651", help="map CRS of the EOPs and ground points")


def run(args: argparse.Namespace) -> int:
    write_mounting_sim(simulate_mounting(args.seed, lever_arm_m=args.lever_arm, delay_s=args.delay, crs=args.crs),
                       args.out)
    print(args.out / "truth.json")
    return 0
