"""RINEX 3 observations of a static or circling receiver from broadcast orbits, with truth (dgcal.sim.gnss)."""
from __future__ import annotations

import argparse
from pathlib import Path

from dgcal.sim import gnss
from dgcal.sim.gnss import simulate_gnss_dataset
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "gnss"
HELP = "simulate RINEX 3 GNSS observations of a static or moving receiver from broadcast orbits"
DESCRIPTION = gnss.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--nav", default=None, help="RINEX 3 navigation file (default: the bundled "
                   "SEPT078M.21P, i.e. 2021-03-19); it is copied to DIR/nav.rnx")
    p.add_argument("--t0", type=arg_types.finite, default=None,
                   help="start, continuous GPS seconds (default 2021-03-19 12:00 GPS)")
    p.add_argument("--duration", type=arg_types.finite, default=300.0, help="s")
    p.add_argument("--rate", type=arg_types.positive, default=1.0, help="Hz")
    p.add_argument("--lat", type=arg_types.finite, default=35.3, help="deg (default: near the SEPT station)")
    p.add_argument("--lon", type=arg_types.finite, default=139.5, help="deg")
    p.add_argument("--height", type=arg_types.finite, default=100.0, help="m, ellipsoidal")
    p.add_argument("--radius", type=arg_types.finite, default=0.0, help="circle radius (m); 0 = static")
    p.add_argument("--speed", type=arg_types.finite, default=10.0, help="m/s along the circle")
    p.add_argument("--sigma-pr", type=arg_types.finite, default=0.5, help="zenith code noise, m")
    p.add_argument("--sigma-doppler", type=arg_types.finite, default=0.05, help="zenith range-rate noise, m/s")
    p.add_argument("--systems", type=arg_types.constellations, default=("G", "E"),
                   help="constellation letters, e.g. GEC")


def run(args: argparse.Namespace) -> int:
    obs = simulate_gnss_dataset(args.out, seed=args.seed, nav=args.nav, t0_gps=args.t0, duration_s=args.duration,
                                rate_hz=args.rate, lat=args.lat, lon=args.lon, height=args.height,
                                radius_m=args.radius, speed_mps=args.speed, sigma_pr=args.sigma_pr,
                                sigma_doppler=args.sigma_doppler, systems=args.systems)
    print(Path(args.out) / obs.name)
    return 0
