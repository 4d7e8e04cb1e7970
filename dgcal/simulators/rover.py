"""A kinematic GNSS rover and its base: a UAV survey flight or a car in a street grid, with airframe or building
masking, slips on turns, half cycles, optionally no Doppler (dgcal.sim.rover_motion)."""
from __future__ import annotations

import argparse

from dgcal.fields.errors import InputError
from dgcal.sim import rover_motion
from dgcal.sim.rover_motion import ROVER_KINDS, simulate_kinematic_rover, write_rover_dataset
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "rover"
HELP = "simulate a moving rover + base (RINEX 3 carrier phase): UAV flight or car, masking, slips, truth"
DESCRIPTION = rover_motion.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--kind", default="uav", choices=ROVER_KINDS, help="uav (survey flight) or car (stop-and-go)")
    p.add_argument("--uav", default="fixed-wing", choices=("fixed-wing", "multirotor"),
                   help="airframe of --kind uav (fixed-wing 25 m/s, multirotor 10 m/s unless --speed)")
    p.add_argument("--speed", type=arg_types.positive, default=None, help="UAV speed, m/s")
    p.add_argument("--bank", type=arg_types.positive, default=30.0, help="UAV bank angle in turns, deg")
    p.add_argument("--duration", type=arg_types.positive, default=600.0, help="s")
    p.add_argument("--rate", type=arg_types.positive, default=1.0, help="GNSS epochs per second")
    p.add_argument("--no-doppler", action="store_true", help="a rover receiver that outputs no Doppler")
    p.add_argument("--slip-rate", type=arg_types.fraction, default=0.01,
                   help="slip probability per satellite and epoch while turning (twice below 25 deg elevation)")
    p.add_argument("--half-cycles", type=arg_types.fraction, default=0.3,
                   help="share of new arcs that start with an unresolved half cycle (LLI bit 1)")
    p.add_argument("--base-distance", type=arg_types.positive, default=4000.0, help="base to rover, m")
    p.add_argument("--urban", type=arg_types.finite, default=0.3, help="car: building height / distance on both sides")
    p.add_argument("--frequencies", type=int, default=2, choices=(1, 2, 3))
    p.add_argument("--nav", default=None, help="RINEX 3 navigation file (default: ../shared/data/rinex-sept)")


def run(args: argparse.Namespace) -> int:
    if args.urban < 0:
        raise InputError(f"--urban must be >= 0, not {args.urban}", field="--urban")
    sim = simulate_kinematic_rover(args.kind, seed=args.seed, duration_s=args.duration, rate_hz=args.rate,
                                   doppler=not args.no_doppler, slip_rate=args.slip_rate,
                                   half_cycle_share=args.half_cycles, base_distance_m=args.base_distance,
                                   n_freq=args.frequencies, nav=args.nav, uav_kind=args.uav, bank_deg=args.bank,
                                   speed_mps=args.speed, urban=args.urban)
    write_rover_dataset(args.out, sim)
    return 0
