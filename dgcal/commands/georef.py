"""Single-image georeferencing of measured pixels (seed 000 sec. 5.2): each pixel's ground point from its
image's exterior orientation and a known height, a GeoTIFF DEM or a laser range to the image centre, with
propagated covariances, and per point the covariance-weighted average over its images (seed Fig. 19)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "georef"
HELP = "single-image georeferencing of pixels (known height, DEM or laser range) with averaging"
OUTPUTS = {"points": "georef_points.csv", "average": "georef_average.csv", "summary": "georef.json",
           "report": "georef.html"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--camera", required=True, type=Path, help="camera file (camera.json, ...)")
    p.add_argument("--measurements", required=True, type=Path, help="pixels CSV image,id,x,y[,sx,sy]")
    p.add_argument("--crs", required=True, help="map CRS of the EOPs, the DEM and the output")
    p.add_argument("--eop", type=Path, help="EOP CSV (PATB, in --crs)")
    p.add_argument("--trajectory", type=Path, help="trajectory CSV (instead of --eop, with --events --mounting)")
    p.add_argument("--events", type=Path, help="events CSV image,gps_week,gps_sow")
    p.add_argument("--mounting", type=Path, help="mounting.json")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--height", type=arg_types.finite, help="known ground height (m, ellipsoidal)")
    src.add_argument("--dem", type=Path, help="GeoTIFF DEM in --crs")
    src.add_argument("--ranges", type=Path, help="laser ranges CSV image,range_m[,s_range_m] (to the image centre)")
    p.add_argument("--sigma-px", type=arg_types.positive, default=0.5, help="pixel sigma when the CSV has none (px)")
    p.add_argument("--sigma-height", type=arg_types.non_negative, default=0.0, help="sigma of the height / DEM (m)")
    p.add_argument("--sigma-range", type=arg_types.positive, default=0.5,
                   help="laser range sigma when the CSV has none (m)")
    p.add_argument("--out", required=True, type=Path,
                   help="output directory (georef_points.csv, georef_average.csv, georef.json, georef.html)")


def run(args: argparse.Namespace) -> int:
    from dgcal.calib.dg.single_image import GeorefOptions, georeference_files
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.reports.georef import write_georef_outputs

    run_ = georeference_files(GeorefOptions(
        camera=args.camera, measurements=args.measurements, crs=args.crs, eop=args.eop, trajectory=args.trajectory,
        events=args.events, mounting=args.mounting, height=args.height, dem=args.dem, ranges=args.ranges,
        sigma_px=args.sigma_px, sigma_height=args.sigma_height, sigma_range=args.sigma_range))
    with staged_dir(args.out) as tmp:
        write_georef_outputs(tmp, run_, OUTPUTS)
    res = run_.result
    print(f"{int(res.ok.sum())}/{len(res.id)} pixels georeferenced, {len(res.averages)} points averaged -> "
          f"{args.out / OUTPUTS['average']}")
    if res.rejected:
        print(f"warning: {len(res.rejected)} single-image estimate(s) screened out as gross errors: "
              + ", ".join(f"{k} in {i}" for i, k in res.rejected[:5]) + (" ..." if len(res.rejected) > 5 else ""),
              file=sys.stderr)
    return 0
