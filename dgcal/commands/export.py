"""Direct georeferencing of a mapping flight and export of its EOPs to COLMAP, Pix4D, Metashape, ODM and eop.csv."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

NAME = "export"
HELP = "DG EOPs of a flight -> COLMAP, Pix4D, Metashape, ODM geo.txt, eop.csv"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mounting", required=True, type=Path, help="mounting.json of `dgcal mount`")
    p.add_argument("--trajectory", required=True, type=Path, help="trajectory.csv (or events.csv of dgcal pos)")
    p.add_argument("--events", required=True, type=Path, help="events CSV image,gps_week,gps_sow")
    p.add_argument("--crs", required=True, help="map CRS of the exported EOPs")
    p.add_argument("--camera", type=Path, help="camera file (needed for COLMAP)")
    p.add_argument("--formats", default="colmap,pix4d,metashape,odm,eop",
                   help="comma-separated: colmap, pix4d, metashape, odm, eop (default all; colmap needs --camera)")
    p.add_argument("--out", required=True, type=Path, help="output directory")


def run(args: argparse.Namespace) -> int:
    from dgcal.calib.dg.eop import dg_eop
    from dgcal.calib.mounting.common import MountingResult
    from dgcal.fields.crs import MapGrid
    from dgcal.fields.errors import InputError
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.fields.io.formats import read_events, read_trajectory
    from dgcal.reports.exports.eop import FORMATS, export_all

    formats = [f.strip().lower() for f in args.formats.split(",") if f.strip()]
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise InputError(f"unknown format {bad[0]!r} (one of {', '.join(FORMATS)})", field="--formats")
    if "colmap" in formats and args.camera is None:
        if args.formats == "colmap,pix4d,metashape,odm,eop":
            formats.remove("colmap")  # default list without a camera: everything but COLMAP
        else:
            raise InputError("the COLMAP export needs --camera", field="--camera")
    camera = None
    if args.camera is not None:
        from dgcal.calib.camera.files import load_camera
        camera = load_camera(args.camera)
    try:
        mount = MountingResult.from_json(json.loads(args.mounting.read_text()), str(args.mounting))
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read mounting file ({exc})", args.mounting) from None
    grid = MapGrid(args.crs)
    traj = read_trajectory(args.trajectory)
    events = read_events(args.events)
    eop, _, _ = dg_eop(grid, traj, events, mount)
    with staged_dir(args.out) as tmp:
        paths = export_all(tmp, eop, grid, camera, formats)
    for f, p in paths.items():
        print(f"{f}: {args.out / p.relative_to(tmp)}")
    return 0
