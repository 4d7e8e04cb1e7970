"""Direct georeferencing of a mapping flight and export of its EOPs to COLMAP, Pix4D, Metashape, ODM and eop.csv."""
from __future__ import annotations

import argparse
from pathlib import Path

NAME = "export"
HELP = "DG EOPs of a flight -> COLMAP, Pix4D, Metashape, ODM geo.txt, eop.csv"
# file names are the formats' own (dgcal.reports.exports.eop): colmap/, pix4d_external_orientation.txt,
# metashape_opk.csv, geo.txt, eop.csv


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mounting", required=True, type=Path, help="mounting.json of `dgcal mount`")
    p.add_argument("--trajectory", required=True, type=Path, help="trajectory.csv (or events.csv of dgcal pos)")
    p.add_argument("--events", required=True, type=Path, help="events CSV image,gps_week,gps_sow")
    p.add_argument("--crs", required=True, help="map CRS of the exported EOPs")
    p.add_argument("--camera", type=Path, help="camera file (needed for COLMAP)")
    p.add_argument("--formats", default=None,
                   help="comma-separated: colmap, pix4d, metashape, odm, eop (default all; colmap needs --camera)")
    p.add_argument("--out", required=True, type=Path, help="output directory")


def run(args: argparse.Namespace) -> int:
    from dgcal.calib.dg.eop import ExportOptions, dg_eop_files
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.reports.exports.eop import write_dg_exports

    formats = None if args.formats is None else tuple(args.formats.split(","))
    flight = dg_eop_files(ExportOptions(args.mounting, args.trajectory, args.events, args.crs, args.camera))
    with staged_dir(args.out) as tmp:
        paths = write_dg_exports(tmp, flight, formats)
    for f, p in paths.items():
        print(f"{f}: {args.out / p.relative_to(tmp)}")
    return 0
