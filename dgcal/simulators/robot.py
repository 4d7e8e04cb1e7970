"""A slow ground robot's ROS log: a consumer MEMS IMU at 30 Hz and NavSatFix fixes at 2.5 Hz in one bag, with the
truth (dgcal.sim.robot_motion)."""
from __future__ import annotations

import argparse

from dgcal.fields.errors import InputError
from dgcal.sim import robot_motion
from dgcal.sim.robot_motion import simulate_robot, write_robot_dataset
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "robot"
HELP = "simulate a slow ground robot's ROS bag (sensor_msgs/Imu 30 Hz, NavSatFix 2.5 Hz) with its truth"
DESCRIPTION = robot_motion.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=arg_types.positive, default=420.0, help="s")
    p.add_argument("--imu-rate", type=arg_types.positive, default=30.0, help="IMU messages per second")
    p.add_argument("--gnss-rate", type=arg_types.positive, default=2.5,
                   help="NavSatFix messages per second (the IMU rate must be a multiple of it)")
    p.add_argument("--grade", default="consumer", help="IMU error model: a preset (navigation, adis16488, adis16405, "
                   "consumer) or a datasheet TOML file")
    p.add_argument("--speed", type=arg_types.positive, nargs=2, default=(0.3, 1.5), metavar=("MIN", "MAX"),
                   help="cruise speeds of the legs, m/s")
    p.add_argument("--gnss-sigma", type=arg_types.positive, nargs=2, default=(1.2, 2.0), metavar=("H", "V"),
                   help="Gauss-Markov error sigma of the fixes per horizontal axis and vertical, m")
    p.add_argument("--gnss-tau", type=arg_types.positive, default=60.0, help="their correlation time, s")
    p.add_argument("--ros", type=int, choices=(1, 2), default=2, help="ROS 1 bag file or ROS 2 bag folder")


def run(args: argparse.Namespace) -> int:
    if args.speed[0] > args.speed[1]:
        raise InputError(f"--speed MIN {args.speed[0]:g} is above MAX {args.speed[1]:g}", field="--speed")
    ratio = args.imu_rate / args.gnss_rate
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise InputError(f"--imu-rate {args.imu_rate:g} is not a multiple of --gnss-rate {args.gnss_rate:g}",
                         field="--gnss-rate")
    try:
        sim = simulate_robot(seed=args.seed, duration_s=args.duration, imu_rate_hz=args.imu_rate,
                             gnss_hz=args.gnss_rate, grade=args.grade, sigma_h_m=args.gnss_sigma[0],
                             sigma_v_m=args.gnss_sigma[1], tau_s=args.gnss_tau, speed_mps=tuple(args.speed))
    except ValueError as exc:      # an unknown grade name
        raise InputError(str(exc), field="--grade") from None
    write_robot_dataset(args.out, sim, ros_version=args.ros)
    return 0
