"""A complete calibration campaign with truth and its campaign.toml (dgcal.sim.campaign)."""
from __future__ import annotations

import argparse
from pathlib import Path

from dgcal.sim import campaign
from dgcal.sim.campaign import DEFAULT_CRS, simulate_campaign
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "campaign"
HELP = "a complete calibration campaign (camera field, control-field flight, IMU, GNSS, events) with truth"
DESCRIPTION = campaign.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--crs", default=DEFAULT_CRS, help="map CRS of the ground points (default %(default)s)")
    p.add_argument("--gnss-mode", choices=("carrier", "lc", "tc"), default="carrier",
                   help="carrier (default): rover + base RINEX with carrier phase, POS step TC with carrier phase; "
                   "lc: POS step LC from cm-level antenna positions (PPK-like gnss.csv, written in every mode); "
                   "tc: rover RINEX pseudoranges only (metre-level)")
    p.add_argument("--delay", type=arg_types.finite, default=-0.14, help="exposure delay t_exposure - t_event (s)")
    p.add_argument("--heights", type=arg_types.finite, nargs="+", default=[300.0, 600.0],
                   help="flying heights above ground (m)")
    p.add_argument("--strips", type=int, default=4, help="strips per height (alternating headings)")
    p.add_argument("--n-tie", type=int, default=1500, help="number of simulated tie points")
    p.add_argument("--field-images", type=int, default=36, help="photos of the target plate")


def run(args: argparse.Namespace) -> int:
    truth = simulate_campaign(args.out, args.seed, crs=args.crs, gnss_mode=args.gnss_mode, delay_s=args.delay,
                              heights_agl=tuple(args.heights), n_strips=args.strips, n_tie=args.n_tie,
                              field_images=args.field_images)
    print(f"simulated {truth['flight']['n_images']} images over {truth['n_control']} control and "
          f"{truth['n_check']} check points, {truth['flight']['duration_s']:.0f} s flight -> "
          f"{Path(args.out) / 'campaign.toml'}")
    return 0
