"""A UAV flight's IMU data, true trajectory, camera events and truth (dgcal.sim.imu)."""
from __future__ import annotations

import argparse
from pathlib import Path

from dgcal.sim import imu
from dgcal.sim.imu import simulate_imu_dataset
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "imu"
HELP = "simulate a UAV flight's IMU data (KF-GINS text), true trajectory, camera events and truth.json"
DESCRIPTION = imu.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--grade", default="adis16488", help="navigation | adis16488 | adis16405 | consumer")
    p.add_argument("--platform", default="fixed-wing", choices=["fixed-wing", "multirotor"])
    p.add_argument("--heights", type=arg_types.finite, nargs="+", default=[300.0],
                   help="flying heights above ground, m")
    p.add_argument("--strips", type=int, default=4, help="strips per height")
    p.add_argument("--duration", type=arg_types.finite, default=None, help="s (default: the flight plan's length)")
    p.add_argument("--rate", type=arg_types.positive, default=200.0, help="IMU rate, Hz")
    p.add_argument("--event-distance", type=arg_types.finite, default=100.0, help="camera trigger spacing on strips, m")
    p.add_argument("--delay", type=arg_types.finite, default=0.0, help="exposure delay t_exposure - t_event, s")
    p.add_argument("--lat", type=arg_types.finite, default=23.0, help="site latitude, deg")
    p.add_argument("--lon", type=arg_types.finite, default=120.2, help="site longitude, deg")


def run(args: argparse.Namespace) -> int:
    info = simulate_imu_dataset(args.out, seed=args.seed, grade=args.grade, kind=args.platform,
                                heights_agl=tuple(args.heights), n_strips=args.strips, duration_s=args.duration,
                                rate_hz=args.rate, event_distance_m=args.event_distance, delay_s=args.delay,
                                lat0=args.lat, lon0=args.lon)
    print(Path(args.out) / "truth.json", f"({len(info['segments'])} flight segments)")
    return 0
