"""A control-field flight with truth EOPs (dgcal.sim.flight)."""
from __future__ import annotations

import argparse

from dgcal.sim import flight
from dgcal.sim.flight import DEFAULT_CRS, simulate_block_flight
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "flight"
HELP = "a control-field flight: terrain, GCP targets, two heights, images, truth EOPs"
DESCRIPTION = flight.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--crs", default=DEFAULT_CRS, help="map CRS of gcp.csv and truth_eop.csv (default %(default)s)")
    p.add_argument("--no-render", action="store_true", help="write measurements only, no images")
    p.add_argument("--noise-px", type=arg_types.finite, default=0.3, help="image measurement noise (px)")
    p.add_argument("--targets", choices=("disc", "aruco"), default="disc",
                   help="GCP targets: quartered discs, or ArUco DICT_4X4_50 markers named by their ids")


def run(args: argparse.Namespace) -> int:
    truth = simulate_block_flight(args.out, args.seed, crs=args.crs, render=not args.no_render,
                                  noise_px=args.noise_px, targets=args.targets)
    print(f"simulated {len(truth['images'])} images, {len(truth['ground_points'])} ground points -> {args.out}")
    return 0
