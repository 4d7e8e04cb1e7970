"""Calibrate a camera from a target field or a standard board: self-calibrating bundle adjustment of image
measurements (or of targets detected in photos and videos). Writes camera.json, report.html, opencv.yaml,
cameras.txt (COLMAP), metashape.xml, poses.csv and, when detecting, measurements.csv and frames.csv (see
docs/camera_calibration.md)."""
from __future__ import annotations

import argparse
import sys

from dgcal.steps import Campaign
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "camera"
HELP = "calibrate camera intrinsics from a target field or board (fraser7, opencv8, fisheye or auto)"
SECTION = "camera"
OUTPUTS = {"camera": "camera.json", "report": "report.html", "opencv": "opencv.yaml", "colmap": "cameras.txt",
           "metashape": "metashape.xml", "poses": "poses.csv", "measurements": "measurements.csv",
           "field_refined": "field_refined.csv", "frames": "frames.csv"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--field", metavar="FIELD.csv", help="target field: id,x,y,z[,sx,sy,sz] (m); not needed with "
                   "--board (its corners are the field)")
    p.add_argument("--board", metavar="BOARD.toml", help="a standard board (charuco, chessboard, aruco-grid) to "
                   "detect: type, columns, rows, square_m, marker_m, dictionary, first_id, inverted, legacy")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--images", nargs="+", metavar="DIR|VIDEO",
                     help="folders of photos, photo or video files (targets are detected; video frames are chosen "
                          "by sharpness and coverage and listed in frames.csv)")
    src.add_argument("--measurements", metavar="MEAS.csv", help="image measurements image,id,x,y[,sx,sy] (px)")
    p.add_argument("--image-size", nargs=2, type=int, metavar=("W", "H"), help="image width and height (px)")
    p.add_argument("--model", default="fraser7", choices=("fraser7", "opencv8", "fisheye", "auto"),
                   help="camera model; auto fits all three, compares them (residual pattern, cross-validation) "
                        "and says why it chose one")
    p.add_argument("--fix", nargs="+", default=[], metavar="PARAM",
                   help="camera parameters held at their initial values, e.g. --fix K3 B2; fraser7 with --fix B2 "
                        "is OpenCV's 5-coefficient model")
    p.add_argument("--refine-targets", choices=("none", "free", "weighted", "warp"), default="none",
                   help="also adjust the target coordinates: free network (minimal datum), weighted by the "
                        "field's sx,sy,sz, or warp: a flat board's bow along its two axes (2 unknowns, mrcal's "
                        "model; printed boards are rarely flat to the millimetre) (default: targets fixed)")
    p.add_argument("--initial", metavar="CAMERA",
                   help="start from this camera (camera.json, opencv.yaml, cameras.txt, Metashape XML, ...)")
    p.add_argument("--reject", type=arg_types.non_negative, default=4.0, metavar="K",
                   help="reject observations beyond K robust sigmas of all observations and of their own image "
                        "(default 4; 0 keeps every observation, as OpenCV's calibrateCamera)")
    p.add_argument("--max-frames", type=arg_types.positive_int, default=100, metavar="N",
                   help="frames chosen from videos at most (default 100)")
    p.add_argument("--uncertainty-range", type=arg_types.positive, default=None, metavar="M",
                   help="range (m) of the projection-uncertainty map (default: the median target distance; the map "
                        "at infinity is always given)")
    p.add_argument("--workers", type=arg_types.positive_int, default=None,
                   help="detection processes (default: up to 2)")
    p.add_argument("--no-report", action="store_true", help="skip report.html")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")


def run(args: argparse.Namespace) -> int:
    from dgcal.calib.selfcal.calibration import CameraOptions, calibrate_camera_files
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.reports.camera import write_camera_files

    opts = CameraOptions(field=args.field, board=args.board, measurements=args.measurements, images=args.images,
                         image_size=None if args.image_size is None else tuple(args.image_size), model=args.model,
                         fixed=tuple(args.fix), refine_targets=args.refine_targets, reject_k=args.reject,
                         workers=args.workers, initial=args.initial, progress=sys.stderr.isatty(),
                         max_frames=args.max_frames, uncertainty_range_m=args.uncertainty_range)
    cal = calibrate_camera_files(opts)
    with staged_dir(args.out) as tmp:
        write_camera_files(tmp, cal, OUTPUTS, report=not args.no_report)
    ba = cal.ba
    if cal.frames is not None:
        print(f"frames: {cal.frames.summary()} (frames.csv)")
    if cal.comparison is not None:
        for r in cal.comparison.reasons:
            print(f"model choice: {r}")
    print(f"{cal.camera.NAME}: RMS {ba.rms_px:.3f} px over {ba.n_observations} observations "
          f"({ba.n_rejected} rejected; {cal.rms_all_px():.3f} px with them), "
          f"{len(ba.image_names) - len(ba.dropped_images)} images")
    if cal.region is not None:
        print(f"valid region: {cal.region.describe()}")
    if cal.uncertainty is not None:
        print(f"projection uncertainty: {cal.uncertainty.summary(cal.region)} "
              "(map in report.html, grid in camera.json)")
    for k, v, s, f in zip(cal.camera.PARAMS, cal.camera.params, cal.camera.sigmas, ba.free):
        print(f"  {k:3s} {v: .8g}" + (f" +- {s:.3g}" if f else " (fixed)"))
    for w in cal.warnings:
        print(f"dgcal camera: warning: {w}", file=sys.stderr)
    print(f"wrote {args.out}/{OUTPUTS['camera']}" + ("" if args.no_report else f" and {args.out}/{OUTPUTS['report']}"))
    return 0


def campaign_steps(c: Campaign) -> None:
    """[camera] -> `dgcal camera`: `field`, `measurements` + `image_size` or `images`, `model`, `args`; with
    `camera_json` an existing camera file is used and no step runs."""
    cam = c.section(SECTION)
    if cam is None:
        return
    cam_json = c.path(SECTION, "camera_json", required=False)
    if cam_json is not None:
        c.provide("camera", cam_json)
        return
    field_csv = c.path(SECTION, "field")
    out = c.out / "camera"
    a = [NAME, "--field", str(field_csv), "--model", str(cam.get("model", "fraser7")), "--out", str(out)]
    ins = [field_csv]
    if "images" in cam:
        a += ["--images", str(c.path(SECTION, "images"))]
        ins.append(c.path(SECTION, "images"))
    else:
        a += ["--measurements", str(c.path(SECTION, "measurements")), "--image-size",
              *map(str, c.image_size(SECTION))]
        ins.append(c.path(SECTION, "measurements"))
    a += c.extra_args(SECTION)
    step = c.add(NAME, a, ins, out, OUTPUTS, required=("camera",))
    c.provide("camera", step.files["camera"])
