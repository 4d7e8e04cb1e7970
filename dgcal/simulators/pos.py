"""A UAV flight for the POS smoother: raw IMU, RINEX code/Doppler, rover + base carrier phase with outages and
slips, events, truth (dgcal.sim.pos)."""
from __future__ import annotations

import argparse

from dgcal.fields.errors import InputError
from dgcal.sim import pos
from dgcal.sim.gnss import CodeErrorModel
from dgcal.sim.pos import simulate_pos, write_pos_dataset

NAME = "pos"
HELP = "simulate a UAV flight: raw IMU, RINEX code/Doppler, rover + base carrier phase, events, truth"
DESCRIPTION = pos.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=1200.0, help="flight duration, s")
    p.add_argument("--kind", default="multirotor", choices=("multirotor", "fixed-wing"))
    p.add_argument("--imu-grade", default="adis16488", help="navigation, adis16488, adis16405, consumer")
    p.add_argument("--rate", type=float, default=200.0, help="IMU rate, Hz")
    p.add_argument("--lever-arm", type=float, nargs=3, default=(0.05, -0.10, -0.30), metavar=("X", "Y", "Z"),
                   help="GNSS antenna lever arm, body FRD, m")
    p.add_argument("--nav", default=None, help="RINEX 3 navigation file (default: ../shared/data/rinex-sept)")
    p.add_argument("--outage-sats", type=int, default=3, help="satellites kept during the 60 s outage")
    p.add_argument("--no-carrier", action="store_true", help="no rover.rnx / base.rnx (carrier phase)")
    p.add_argument("--code-errors", type=float, default=None, metavar="SCALE",
                   help="give every satellite of obs.rnx the slow error real broadcast models leave: SCALE x the "
                   "front end's budget (1: as budgeted; dgcal.sim.gnss.CodeErrorModel). Default: none (exact models)")


def run(args: argparse.Namespace) -> int:
    try:
        sim = simulate_pos(seed=args.seed, duration_s=args.duration, kind=args.kind, imu_grade=args.imu_grade,
                           rate_hz=args.rate, lever_arm_b=args.lever_arm, nav=args.nav,
                           outage_sats=args.outage_sats, carrier=not args.no_carrier,
                           code_errors=None if args.code_errors is None else CodeErrorModel(scale=args.code_errors))
    except ValueError as exc:  # an unknown IMU grade
        raise InputError(str(exc), field="--imu-grade") from None
    write_pos_dataset(args.out, sim)
    return 0
