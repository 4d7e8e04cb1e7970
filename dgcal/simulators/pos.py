"""A UAV flight for the POS smoother: raw IMU, RINEX code/Doppler, rover + base carrier phase with outages and
slips, events, truth (dgcal.sim.pos)."""
from __future__ import annotations

import argparse

from dgcal.fields.errors import InputError
from dgcal.sim import pos
from dgcal.sim.gnss import CodeErrorModel
from dgcal.sim.pos import simulate_pos, write_pos_dataset
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "pos"
HELP = "simulate a UAV flight: raw IMU, RINEX code/Doppler, rover + base carrier phase, events, truth"
DESCRIPTION = pos.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=arg_types.finite, default=1200.0, help="flight duration, s")
    p.add_argument("--kind", default="multirotor", choices=("multirotor", "fixed-wing"))
    p.add_argument("--imu-grade", default="adis16488", help="navigation, adis16488, adis16405, consumer")
    p.add_argument("--rate", type=arg_types.positive, default=200.0, help="IMU rate, Hz")
    p.add_argument("--lever-arm", type=arg_types.finite, nargs=3, default=(0.05, -0.10, -0.30), metavar=("X", "Y", "Z"),
                   help="GNSS antenna lever arm, body FRD, m")
    p.add_argument("--nav", default=None, help="RINEX 3 navigation file (default: ../shared/data/rinex-sept)")
    p.add_argument("--outage-sats", type=int, default=3, help="satellites kept during the 60 s outage")
    p.add_argument("--no-carrier", action="store_true", help="no rover.rnx / base.rnx (carrier phase)")
    p.add_argument("--systems", type=arg_types.constellations, default=("G", "E"),
                   help="constellations of obs.rnx, letters of G,E,C,J,R (R: GLONASS, with synthetic "
                   "records written into nav.rnx when the navigation file has none; not in rover/base.rnx)")
    p.add_argument("--airframe-mask", type=arg_types.finite, default=None, metavar="DEG",
                   help="carrier: hide satellites less than DEG above the body's horizontal plane (banks mask the low "
                   "wing's side; dgcal.sim.rover_motion)")
    p.add_argument("--turn-slip-rate", type=arg_types.finite, default=0.0, metavar="P",
                   help="carrier: slip probability per satellite and epoch while banked (one or all frequencies, half "
                   "without LLI)")
    p.add_argument("--half-cycles", type=arg_types.finite, default=0.0, metavar="SHARE",
                   help="carrier: share of new arcs starting with an unresolved half cycle (LLI bit 1)")
    p.add_argument("--no-doppler", action="store_true", help="carrier: a rover receiver without Doppler")
    p.add_argument("--code-errors", type=arg_types.finite, default=None, metavar="SCALE",
                   help="give every satellite of obs.rnx the slow error real broadcast models leave: SCALE x the "
                   "front end's budget (1: as budgeted; dgcal.sim.gnss.CodeErrorModel). Default: none (exact models)")


def run(args: argparse.Namespace) -> int:
    mask = args.airframe_mask if args.airframe_mask is not None else 0.0
    for name, v, lo, hi in (("--turn-slip-rate", args.turn_slip_rate, 0.0, 1.0),
                            ("--half-cycles", args.half_cycles, 0.0, 1.0), ("--airframe-mask", mask, -90.0, 90.0)):
        if not lo <= v <= hi:
            raise InputError(f"must be within {lo:g}..{hi:g}, not {v}", field=name)
    try:
        sim = simulate_pos(seed=args.seed, duration_s=args.duration, kind=args.kind, imu_grade=args.imu_grade,
                           rate_hz=args.rate, lever_arm_b=args.lever_arm, nav=args.nav,
                           outage_sats=args.outage_sats, carrier=not args.no_carrier,
                           code_errors=None if args.code_errors is None else CodeErrorModel(scale=args.code_errors),
                           airframe_mask_deg=args.airframe_mask, turn_slip_rate=args.turn_slip_rate,
                           half_cycle_share=args.half_cycles, carrier_doppler=not args.no_doppler,
                           systems=args.systems)
    except ValueError as exc:  # an unknown IMU grade
        raise InputError(str(exc), field="--imu-grade") from None
    write_pos_dataset(args.out, sim)
    return 0
