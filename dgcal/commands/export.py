"""Direct georeferencing of a mapping flight and export of its EOPs to COLMAP, Pix4D, Metashape, ODM and eop.csv;
`--calibration` exports the system calibration itself (lever arm, boresight, delay) for Metashape's GPS/INS
offset, POSPac, Inertial Explorer and Pix4D (dgcal.reports.exports.calibration)."""
from __future__ import annotations

import argparse
from pathlib import Path
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "export"
HELP = "DG EOPs of a flight -> COLMAP, Pix4D, Metashape, ODM geo.txt, eop.csv; or the calibration -> Metashape, " \
       "POSPac, Inertial Explorer, Pix4D"
# file names are the formats' own (dgcal.reports.exports.eop): colmap/, pix4d_external_orientation.txt,
# metashape_opk.csv, geo.txt, eop.csv; with --calibration (dgcal.reports.exports.calibration.FILE_NAMES)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mounting", required=True, type=Path, help="mounting.json of `dgcal mount`")
    p.add_argument("--trajectory", type=Path,
                   help="trajectory.csv (or events.csv of dgcal pos, or an SBET .out with its smrmsg beside it)")
    p.add_argument("--events", type=Path, help="events: dgcal CSV image,gps_week,gps_sow, DJI .MRK or image,utc CSV")
    p.add_argument("--crs", help="map CRS of the exported EOPs")
    p.add_argument("--camera", type=Path, help="camera file (needed for COLMAP)")
    p.add_argument("--formats", default=None,
                   help="comma-separated: colmap, pix4d, metashape, odm, eop (default all; colmap needs --camera); "
                   "with --calibration: metashape, pospac, inertial-explorer, pix4d (default all)")
    p.add_argument("--calibration", action="store_true",
                   help="export the lever arm, boresight and delay of --mounting in the programs' conventions "
                   "(no flight needed)")
    p.add_argument("--reference-lever-arm", type=arg_types.finite, nargs=3, default=(0.0, 0.0, 0.0),
                   metavar=("X", "Y", "Z"),
                   help="--calibration: IMU -> the position reference point (GNSS antenna) in body FRD, m, for the "
                   "camera-frame offsets of Metashape and Pix4D (default 0: positions of the IMU)")
    p.add_argument("--out", required=True, type=Path, help="output directory")


def run(args: argparse.Namespace) -> int:
    from dgcal.fields.errors import InputError
    from dgcal.fields.io.csv_tables import staged_dir

    if args.calibration:
        from dgcal.calib.mounting.common import read_mounting_json
        from dgcal.reports.exports.calibration import CALIBRATION_FORMATS, write_calibration_exports
        formats = CALIBRATION_FORMATS if args.formats is None else tuple(
            f.strip().lower() for f in args.formats.split(",") if f.strip())
        bad = [f for f in formats if f not in CALIBRATION_FORMATS]
        if bad:
            raise InputError(f"unknown calibration format {bad[0]!r} (one of {', '.join(CALIBRATION_FORMATS)})",
                             field="--formats")
        mount = read_mounting_json(args.mounting)
        with staged_dir(args.out) as tmp:
            paths = write_calibration_exports(tmp, mount, formats, args.reference_lever_arm)
        for f, p in paths.items():
            print(f"{f}: {args.out / p.relative_to(tmp)}")
        return 0
    for name in ("trajectory", "events", "crs"):
        if getattr(args, name) is None:
            raise InputError("required (unless --calibration)", field=f"--{name}")
    from dgcal.calib.dg.eop import ExportOptions, dg_eop_files
    from dgcal.reports.exports.eop import write_dg_exports

    formats = None if args.formats is None else tuple(args.formats.split(","))
    flight = dg_eop_files(ExportOptions(args.mounting, args.trajectory, args.events, args.crs, args.camera))
    with staged_dir(args.out) as tmp:
        paths = write_dg_exports(tmp, flight, formats)
    for f, p in paths.items():
        print(f"{f}: {args.out / p.relative_to(tmp)}")
    return 0
