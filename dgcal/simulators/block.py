"""A photogrammetric block with known truth, measurements only (dgcal.sim.block): strips in opposite headings over
hills in a zone with > 1 deg meridian convergence; `--rtk` the RTK-drone family with GNSS camera centres."""
from __future__ import annotations

import argparse

from dgcal.sim import block
from dgcal.sim.block import RTK_CENTRE_SIGMA_M, BlockPattern, simulate_block, simulate_rtk_block, write_block
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "block"
HELP = "an aerial block (measurements, GCPs, check points, truth EOPs); --rtk: RTK drone with camera centres"
DESCRIPTION = block.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--images", type=arg_types.positive_int, default=None,
                   help="about this many images (default 60; --rtk 96)")
    p.add_argument("--gcps", type=_count, default=None, help="control points (default 12; --rtk 0)")
    p.add_argument("--checks", type=_count, default=10, help="check points")
    p.add_argument("--rtk", action="store_true",
                   help="the RTK-drone family: 35 mm on 8192 x 5460 px, 150 m, 80/70 %% overlap, +-50 m hills, "
                        "centres.csv with RTK camera centres")
    p.add_argument("--centre-sigma", nargs=3, type=arg_types.positive, metavar=("SE", "SN", "SU"), default=None,
                   help="camera-centre noise and sigma (m) of --rtk (default "
                        + "/".join(map(str, RTK_CENTRE_SIGMA_M)) + ")")
    p.add_argument("--noise-px", type=arg_types.positive, default=0.3, help="image measurement noise (px)")


def _count(text: str) -> int:
    """A whole number >= 0 (argparse type)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, not {v}")
    return v


def run(args: argparse.Namespace) -> int:
    if args.rtk:
        sim = simulate_rtk_block(args.seed, n_images=args.images or 96, n_control=args.gcps or 0,
                                 n_check=args.checks, noise_px=args.noise_px,
                                 centre_sigma_m=tuple(args.centre_sigma) if args.centre_sigma else RTK_CENTRE_SIGMA_M)
    else:
        n = args.images or 60
        strips = max(2, round((n / 3.75) ** 0.5))
        pattern = BlockPattern(n_strips=(strips,), images_per_strip=(max(2, round(n / strips)),),
                               terrain_amplitude_m=50.0)
        sim = simulate_block(args.seed, pattern, n_control=12 if args.gcps is None else args.gcps,
                             n_check=args.checks, n_tie=200 * n, noise_px=args.noise_px)
    write_block(sim, args.out)
    extra = ", centres.csv" if sim.centres is not None else ""
    print(f"simulated {len(sim.images)} images, {int((sim.points.role == 'control').sum())} GCPs, "
          f"{int((sim.points.role == 'check').sum())} check points -> {args.out}/measurements.csv, gcp.csv, "
          f"camera.json{extra}, truth_eop.csv, truth.json")
    return 0
