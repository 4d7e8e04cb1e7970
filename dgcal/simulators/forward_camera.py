"""A forward-looking camera's image stream over textured terrain, with truth (dgcal.sim.forward_camera)."""
from __future__ import annotations

import argparse
from pathlib import Path

from dgcal.sim import forward_camera
from dgcal.sim.forward_camera import write_forward_camera_dataset
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "forward-camera"
HELP = "forward-camera image stream over textured terrain from a simulated flight (seed 001)"
DESCRIPTION = forward_camera.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=arg_types.finite, default=300.0, help="flight length (s)")
    p.add_argument("--fps", type=arg_types.positive, default=5.0, help="frame rate (Hz)")
    p.add_argument("--size", type=int, default=240, help="image width = height (px)")


def run(args: argparse.Namespace) -> int:
    n = write_forward_camera_dataset(args.out, seed=args.seed, duration_s=args.duration, fps=args.fps,
                                     image_px=args.size)
    print(f"wrote {n} frames to {args.out}/frames and frames.csv, gnss_velocity.csv, truth.json")
    return 0
