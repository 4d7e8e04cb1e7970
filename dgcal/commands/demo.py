"""The built-in demo: simulate a complete calibration campaign like seed 003 into DIR/data (fixed-wing UAV,
ADIS16488-class IMU, 20 mm full-frame camera, 300 m and 600 m strips in opposite headings, exposure delay
-0.14 s) and run it into DIR/results; prints the calibration report's path at the end."""
from __future__ import annotations

import argparse
from pathlib import Path

from dgcal.commands.run import add_jobs_argument

NAME = "demo"
HELP = "simulate a calibration campaign and run the whole chain on it (prints the report path)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (data/ and results/)")
    p.add_argument("--seed", type=int, default=3, help="random seed of the simulation")
    p.add_argument("--force", action="store_true", help="simulate and run everything again")
    add_jobs_argument(p)


def run(args: argparse.Namespace) -> int:
    from dgcal.campaign import DemoOptions, run_demo
    res = run_demo(DemoOptions(args.out, args.seed, args.force, max(1, args.jobs)))
    print(f"demo finished in {res['elapsed_s']:.1f} s ({max(1, args.jobs)} step(s) at once); step times: "
          + ", ".join(f"{k} {v:.1f} s" for k, v in res["timings_s"].items()))
    print("calibration report:")
    print(res["report"])
    return 0
