"""Aerial triangulation over a ground-control field: EOPs in the map CRS with sigmas, report and exports.

Ground points: dgcal CSV (`id,x,y,z[,sx,sy,sz][,role]`), MicMac DicoAppuisFlottant XML or ODM gcp_list.txt.
Measurements: dgcal CSV (`image,id,x,y[,sx,sy]`), ODM gcp_list.txt or MicMac SetOfMesureAppuisFlottants XML;
ids absent from the ground points are tie points; role `check` points are only evaluated. With --images,
SIFT tie points are added (pycolmap). `--crs local` treats coordinates as a local Cartesian frame.
Writes DIR/eop.csv, DIR/summary.json, DIR/report.html, DIR/points.csv, DIR/residuals.csv and
DIR/exports/ (COLMAP model, Pix4D, Metashape OPK, ODM geo.txt).
"""
from __future__ import annotations

import argparse
import sys
import warnings

from dgcal.steps import Campaign
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "triangulate"
HELP = "aerial triangulation with GCPs: EOPs with covariance, check points, report, exports"
SECTION = "triangulation"
OUTPUTS = {"eop": "eop.csv", "summary": "summary.json", "report": "report.html", "points": "points.csv",
           "residuals": "residuals.csv", "exports": "exports", "camera_refined": "camera_refined.json"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--camera", required=True, help="camera file (camera.json, OpenCV YAML, COLMAP, Metashape, MicMac)")
    p.add_argument("--gcp", help="ground points: CSV, MicMac XML or ODM gcp_list.txt")
    p.add_argument("--crs", required=True, help="map CRS of the ground points and of eop.csv (pyproj text, or 'local')")
    p.add_argument("--images", help="image folder: SIFT tie points (and the image list)")
    p.add_argument("--measurements", nargs="+", metavar="MEAS",
                   help="image measurements: CSV, ODM gcp_list.txt or MicMac XML (several files are merged)")
    p.add_argument("--image-size", nargs=2, type=int, metavar=("W", "H"),
                   help="image size (px) when there are no images")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--sigma-px", type=arg_types.positive, default=0.5,
                   help="measurement sigma (px) where the file gives none")
    p.add_argument("--tie-sigma-px", type=arg_types.positive, default=None, help="sigma of SIFT/tie measurements (px)")
    p.add_argument("--gcp-sigma", nargs=3, type=arg_types.positive, metavar=("SX", "SY", "SZ"),
                   help="ground point sigmas (m), overriding the file's")
    p.add_argument("--fixed-gcps", action="store_true", help="hold control points fixed instead of weighted")
    p.add_argument("--refine", default="", help="camera parameters to refine, comma separated, or 'all'")
    p.add_argument("--geoid", help="geoid undulation (m) or PROJ vertical grid: map heights are orthometric")
    p.add_argument("--approx", help="approximate EOP CSV in --crs (initial values and spatial image pairs)")
    p.add_argument("--pixel-size-mm", type=arg_types.positive, default=None, metavar="MM",
                   help="the sensor's pixel pitch (mm): needed to read a Pix4D/BINGO measurement file (sensor mm)")
    p.add_argument("--gnss", help="GNSS camera centres: EOP CSV in --crs, image,X,Y,Z[,sX,sY,sZ] (angles may be "
                                  "blank), or DJI images (a folder of JPEGs, or one) whose XMP/EXIF positions are "
                                  "read: centre priors that fix the datum with or without control points")
    p.add_argument("--antenna-offset", nargs=3, type=arg_types.finite, metavar=("DX", "DY", "DZ"),
                   help="with --gnss: the antenna phase centre in camera axes (x right, y down, z forward, m) from "
                        "the perspective centre, applied with each image's rotation")
    p.add_argument("--flight-shift", action="store_true",
                   help="with --gnss and control points: estimate a shift (E, N, Up) of the centres per flight "
                        "(their 'flight' column, else one for all)")
    p.add_argument("--max-features", type=arg_types.positive_int, default=4000, help="SIFT features per image")
    p.add_argument("--targets", metavar="DICT", help="detect ArUco GCP targets (e.g. DICT_4X4_50) in --images; "
                   "marker id = point id; measurements in --measurements take precedence")
    p.add_argument("--no-blunder-rejection", action="store_true", help="report suspects without removing them")
    p.add_argument("--formats", default="colmap,pix4d,metashape,odm", help="exports (comma separated)")
    p.add_argument("--approx-from-pos", nargs=2, metavar=("TRAJ", "EVENTS"),
                   help="approximate EOPs by direct georeferencing of a trajectory at the events (POS-assisted AT)")
    p.add_argument("--nominal-mounting", metavar="MOUNTING_JSON",
                   help="mounting for --approx-from-pos (default: nadir camera, image top forward, at the IMU)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--check-as-tie", dest="check_as_tie", action="store_true", default=None,
                   help="use check-point measurements as tie points (default for measurement-only input)")
    g.add_argument("--no-check-as-tie", dest="check_as_tie", action="store_false",
                   help="leave check points out of the adjustment (intersect them afterwards)")
    p.add_argument("--no-mapper", action="store_true",
                   help="initial orientation by resection and growth from control, not pycolmap's mapper")
    p.add_argument("--accept-poor", action="store_true",
                   help="write a result that fails the quality checks (not converged, sigma0 > 3, images left "
                        "out) instead of exiting with an error; the report's first line says so")
    p.add_argument("--no-progress", action="store_true", help="no stage messages on stderr")


def run(args: argparse.Namespace) -> int:
    from dgcal.bundle.inputs import TriangulateOptions, triangulate_files
    from dgcal.calib.dg.eop import approx_eop_from_pos
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.reports.triangulation_outputs import write_triangulation_outputs

    approx_eop = (approx_eop_from_pos(args.crs, *args.approx_from_pos, args.nominal_mounting)
                  if args.approx_from_pos else None)
    opts = TriangulateOptions(
        camera=args.camera, crs=args.crs, gcp=args.gcp, images=args.images,
        measurements=tuple(args.measurements or ()), pixel_size_mm=args.pixel_size_mm,
        image_size=None if args.image_size is None else tuple(args.image_size),
        sigma_px=args.sigma_px, tie_sigma_px=args.tie_sigma_px,
        gcp_sigma_m=None if args.gcp_sigma is None else tuple(args.gcp_sigma), fixed_gcps=args.fixed_gcps,
        refine=_words(args.refine), geoid=args.geoid, approx=args.approx, gnss=args.gnss,
        antenna_offset_cam=None if args.antenna_offset is None else tuple(args.antenna_offset),
        flight_shift=args.flight_shift,
        max_features=args.max_features, targets=args.targets, reject_blunders=not args.no_blunder_rejection,
        formats=_words(args.formats), approx_eop=approx_eop, check_as_tie=args.check_as_tie,
        accept_poor=args.accept_poor, use_mapper=not args.no_mapper,
        progress=None if args.no_progress else _progress)
    # the library reports each warning through `warnings` too (for Python users): printed here once, our way
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UserWarning)
        try:
            tri = triangulate_files(opts)
        except Exception:
            _print_warnings([str(w.message) for w in caught if issubclass(w.category, UserWarning)])
            raise
    _print_warnings(tri.result.warnings)
    with staged_dir(args.out) as tmp:
        write_triangulation_outputs(tmp, tri, OUTPUTS)
    s, res = tri.result.summary, tri.result
    print(f"{s['n_oriented']}/{s['n_images']} images oriented, sigma0 {s['sigma0']:.3f}, "
          f"check RMSE E/N/U {_f(s['check_rmse_m']['E'])}/{_f(s['check_rmse_m']['N'])}/{_f(s['check_rmse_m']['U'])} m, "
          f"{len(res.warnings)} warning(s) -> {args.out}/{OUTPUTS['eop']}")
    if res.problems:
        print("NOT TRUSTED (--accept-poor): " + "; ".join(res.problems))
    return 0


MAX_PRINTED_WARNINGS = 20   # the rest are in summary.json and the report


def _print_warnings(texts: list[str]) -> None:
    """Each warning once on stderr, at most MAX_PRINTED_WARNINGS."""
    texts = list(dict.fromkeys(texts))
    for t in texts[:MAX_PRINTED_WARNINGS]:
        print(f"[{NAME}] warning: {t}", file=sys.stderr)
    if len(texts) > MAX_PRINTED_WARNINGS:
        print(f"[{NAME}] ... {len(texts) - MAX_PRINTED_WARNINGS} more warning(s) in summary.json", file=sys.stderr)


def _progress(text: str) -> None:
    print(f"[{NAME}] {text}", file=sys.stderr, flush=True)


def _words(text: str) -> tuple[str, ...]:
    """The comma-separated words of an option."""
    return tuple(w.strip() for w in text.split(",") if w.strip())


def _f(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def campaign_steps(c: Campaign) -> None:
    """[triangulation] -> `dgcal triangulate`: `gcp`, `measurements` and/or `images`, `args`; with `eop` an
    existing EOP file is used and no step runs. Provides the eop, gcp and measurements to later steps."""
    tri = c.section(SECTION)
    if tri is None:
        return
    eop = c.path(SECTION, "eop", required=False)
    gcp = c.path(SECTION, "gcp", required=False)
    meas = c.path(SECTION, "measurements", required=False)
    if meas is not None:
        c.provide("measurements", meas)
    if eop is not None:
        c.provide("eop", eop)
        if gcp is not None:
            c.provide("gcp", gcp)
        return
    cam = c.provided.get("camera")
    if cam is None:
        raise c.error("[triangulation] needs a [camera] section or camera_json", "camera")
    gcp = c.path(SECTION, "gcp")
    out = c.out / "triangulation"
    a = [NAME, "--camera", str(cam), "--gcp", str(gcp), "--crs", c.crs, "--out", str(out)]
    ins = [cam, gcp]
    if "images" in tri:
        a += ["--images", str(c.path(SECTION, "images"))]
        ins.append(c.path(SECTION, "images"))
    if meas is not None:
        a += ["--measurements", str(meas)]
        ins.append(meas)
    if "images" not in tri and meas is None:
        raise c.error("[triangulation] needs 'measurements' or 'images'", "triangulation.measurements")
    a += c.extra_args(SECTION)
    step = c.add(NAME, a, ins, out, OUTPUTS, required=("eop",), after=c.step_names(), weight=2.0)
    c.provide("eop", step.files["eop"])
    c.provide("gcp", gcp)
