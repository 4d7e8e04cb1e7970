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

NAME = "triangulate"
HELP = "aerial triangulation with GCPs: EOPs with covariance, check points, report, exports"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--camera", required=True, help="camera file (camera.json, OpenCV YAML, COLMAP, Metashape, MicMac)")
    p.add_argument("--gcp", help="ground points: CSV, MicMac XML or ODM gcp_list.txt")
    p.add_argument("--crs", required=True, help="map CRS of the ground points and of eop.csv (pyproj text, or 'local')")
    p.add_argument("--images", help="image folder: SIFT tie points (and the image list)")
    p.add_argument("--measurements", nargs="+", metavar="MEAS",
                   help="image measurements: CSV, ODM gcp_list.txt or MicMac XML (several files are merged)")
    p.add_argument("--image-size", nargs=2, type=int, metavar=("W", "H"), help="image size (px) when there are no images")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--sigma-px", type=float, default=0.5, help="measurement sigma (px) where the file gives none")
    p.add_argument("--tie-sigma-px", type=float, default=None, help="sigma of SIFT/tie measurements (px)")
    p.add_argument("--gcp-sigma", nargs=3, type=float, metavar=("SX", "SY", "SZ"),
                   help="ground point sigmas (m), overriding the file's")
    p.add_argument("--fixed-gcps", action="store_true", help="hold control points fixed instead of weighted")
    p.add_argument("--refine", default="", help="camera parameters to refine, comma separated, or 'all'")
    p.add_argument("--geoid", help="geoid undulation (m) or PROJ vertical grid: map heights are orthometric")
    p.add_argument("--approx", help="approximate EOP CSV in --crs (initial values and spatial image pairs)")
    p.add_argument("--gnss", help="EOP CSV in --crs whose X,Y,Z (and sX..sZ) are camera-centre priors")
    p.add_argument("--max-features", type=int, default=4000, help="SIFT features per image")
    p.add_argument("--targets", metavar="DICT", help="detect ArUco GCP targets (e.g. DICT_4X4_50) in --images; "
                   "marker id = point id; measurements in --measurements take precedence")
    p.add_argument("--no-blunder-rejection", action="store_true", help="report suspects without removing them")
    p.add_argument("--formats", default="colmap,pix4d,metashape,odm", help="exports (comma separated)")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from dgcal.bundle.tiepoints import extract_tie_points, list_images, sequential_pairs, spatial_pairs
    from dgcal.bundle.triangulation import TriangulationOptions, triangulate
    from dgcal.calib.camera.files import load_camera
    from dgcal.fields.crs import parse_crs
    from dgcal.fields.io.csv_tables import staged_dir, write_table
    from dgcal.fields.errors import InputError
    from dgcal.fields.io.formats import Measurements, read_eop, write_eop
    from dgcal.fields.io.gcp_files import read_any_measurements, read_any_points
    from dgcal.reports.bundle import write_bundle_report, write_summary_json

    if not args.images and not args.measurements:
        raise InputError("give --images DIR or --measurements MEAS.csv (or both)", field="--measurements")
    camera = load_camera(args.camera)
    local = args.crs.strip().lower() in ("local", "none")
    if not local:
        parse_crs(args.crs)
    points, gcp_crs = (read_any_points(args.gcp) if args.gcp else (None, None))
    meas, meas_points, crs_sources = None, None, [(args.gcp, gcp_crs)]
    for path in args.measurements or []:
        m, c, p = read_any_measurements(path)
        crs_sources.append((path, c))
        meas = m if meas is None else _merge(meas, m)
        meas_points = meas_points if p is None else p
    for src, c in crs_sources:
        if c is not None and not local and parse_crs(c) != parse_crs(args.crs):
            raise InputError(f"the file's CRS {c!r} differs from --crs {args.crs!r}", src, 1, "--crs")
    if points is None:
        if meas_points is None:
            raise InputError("no ground points: give --gcp (or an ODM gcp_list.txt as --measurements)", field="--gcp")
        points = meas_points
    if args.gcp_sigma:
        points.sigma[:] = np.asarray(args.gcp_sigma, float)
    if args.image_size and tuple(args.image_size) != tuple(camera.image_size):
        raise InputError(f"--image-size {tuple(args.image_size)} differs from the camera's {tuple(camera.image_size)}",
                         field="--image-size")
    approx = read_eop(args.approx) if args.approx else None
    gnss = read_eop(args.gnss) if args.gnss else None
    pre_warnings = []
    all_images = None
    if args.images:
        names = list_images(args.images)
        _check_image_size(args.images, names[0], camera)
        all_images = names
        if meas is not None:
            missing = sorted(set(meas.images()) - set(names))
            if missing:
                pre_warnings.append(f"{len(missing)} measured image(s) not in {args.images} (e.g. {missing[0]}): "
                                    "their measurements are used without tie points")
        if approx is not None:
            a_idx = {str(k): i for i, k in enumerate(approx.image)}
            have = [n for n in names if n in a_idx]
            xyz = np.array([approx.xyz[a_idx[n]] for n in have])
            h = np.median(np.abs(xyz[:, 2] - np.median(points.xyz[:, 2])))
            pairs = spatial_pairs(have, xyz, footprint_m=h * camera.image_size[0] / camera.pinhole_K()[0, 0])
            pairs += sequential_pairs([n for n in names if n not in a_idx])
        else:
            pairs = sequential_pairs(names, overlap=len(names) if len(names) <= 30 else 10)
        if args.targets:
            from dgcal.bundle.gcp_targets import detect_gcp_targets
            det = detect_gcp_targets(args.images, names, args.targets, sigma_px=args.sigma_px)
            known = set(points.ids.astype(str))
            unknown = sorted(set(det.id) - known)
            if unknown:
                pre_warnings.append(f"{len(unknown)} detected marker id(s) not in the ground points, ignored: "
                                    + ", ".join(unknown[:10]))
            keep = np.array([i in known for i in det.id.astype(str)], bool)
            if meas is not None:
                have = set(zip(meas.image.astype(str), meas.id.astype(str)))
                keep &= np.array([(a, b) not in have for a, b in zip(det.image.astype(str), det.id.astype(str))], bool)
            det = det.subset(keep)
            pre_warnings.append(f"{len(det)} GCP target measurement(s) detected automatically ({args.targets})")
            if meas is None:
                meas = det
            else:
                meas = Measurements(np.concatenate([meas.image, det.image]), np.concatenate([meas.id, det.id]),
                                    np.concatenate([meas.xy, det.xy]), np.concatenate([meas.sigma, det.sigma]),
                                    None if meas.lines is None else np.concatenate([meas.lines, np.zeros(len(det), int)]),
                                    meas.path)
        tie = extract_tie_points(args.images, names, pairs, max_features=args.max_features,
                                 camera_K=camera.pinhole_K())
        if args.tie_sigma_px:
            tie.sigma[:] = args.tie_sigma_px
        if meas is None:
            meas = tie
        else:
            meas = Measurements(np.concatenate([meas.image, tie.image]), np.concatenate([meas.id, tie.id]),
                                np.concatenate([meas.xy, tie.xy]), np.concatenate([meas.sigma, tie.sigma]),
                                None if meas.lines is None else np.concatenate([meas.lines, np.zeros(len(tie), int)]),
                                meas.path)
    refine = tuple(camera.PARAMS) if args.refine.strip() == "all" else tuple(
        p.strip() for p in args.refine.split(",") if p.strip())
    bad = [p for p in refine if p not in camera.PARAMS]
    if bad:
        raise InputError(f"unknown camera parameter {bad[0]!r} ({camera.NAME} has {', '.join(camera.PARAMS)})",
                         field="--refine")
    opt = TriangulationOptions(sigma_px=args.sigma_px, tie_sigma_px=args.tie_sigma_px, fixed_gcps=args.fixed_gcps,
                               refine=refine, geoid=args.geoid, reject_blunders=not args.no_blunder_rejection)
    res = triangulate(camera, points, meas, None if local else args.crs, opt,
                      image_size=args.image_size, approx=approx, centre_priors=gnss, all_images=all_images)
    res.warnings[:0] = pre_warnings
    res.summary["warnings"] = res.warnings
    with staged_dir(args.out) as tmp:
        formats = [f.strip() for f in args.formats.split(",") if f.strip()]
        if local and formats:
            kept = [f for f in formats if f in ("pix4d", "metashape")]
            if len(kept) < len(formats):
                res.warnings.append("COLMAP and ODM exports need a map CRS: skipped for --crs local")
            formats = kept
        if formats:
            from dgcal.fields.crs import MapGrid
            from dgcal.reports.exports.eop import export_all
            ctrl = {g["id"]: g["xyz"] for g in res.gcp}
            obs = [(meas.image[i], meas.id[i], *meas.xy[i]) for i in range(len(meas)) if str(meas.id[i]) in ctrl]
            export_all(tmp / "exports", res.eop, None if local else MapGrid(args.crs), camera, formats,
                       points_map=ctrl, observations=obs)
        write_eop(tmp / "eop.csv", res.eop)
        write_summary_json(tmp / "summary.json", res)
        write_bundle_report(tmp / "report.html", res)
        X_map = res.georef.to_map(res.bundle.X_world)
        write_table(tmp / "points.csv", ["id", "x", "y", "z", "kind"],
                    ([p, *X_map[j], res.point_kind[j]] for j, p in enumerate(res.point_ids)), fmt="%.6f")
        inp = res.bundle._inp
        write_table(tmp / "residuals.csv", ["image", "id", "rx", "ry"],
                    ([res.images[inp.obs_image[k]], res.point_ids[inp.obs_point[k]], *res.bundle.residuals_px[k]]
                     for k in range(len(inp.obs_image))), fmt="%.4f")
    s = res.summary
    print(f"{s['n_oriented']}/{s['n_images']} images oriented, sigma0 {s['sigma0']:.3f}, "
          f"check RMSE E/N/U {_f(s['check_rmse_m']['E'])}/{_f(s['check_rmse_m']['N'])}/{_f(s['check_rmse_m']['U'])} m, "
          f"{len(res.warnings)} warning(s) -> {args.out}/eop.csv")
    return 0


def _merge(a, b):
    """Two measurement sets as one; a point measured twice in one image is an error naming the second file."""
    import numpy as np

    from dgcal.fields.errors import InputError
    from dgcal.fields.io.formats import Measurements
    seen = set(zip(a.image.astype(str), a.id.astype(str)))
    for i, key in enumerate(zip(b.image.astype(str), b.id.astype(str))):
        if key in seen:
            raise InputError(f"point {key[1]!r} in image {key[0]!r} is also measured in {a.path}", b.path,
                             None if b.lines is None else int(b.lines[i]), "id")
    lines = None if a.lines is None or b.lines is None else np.concatenate([a.lines, b.lines])
    return Measurements(np.concatenate([a.image, b.image]), np.concatenate([a.id, b.id]),
                        np.concatenate([a.xy, b.xy]), np.concatenate([a.sigma, b.sigma]), lines, a.path)


def _f(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def _check_image_size(folder, name, camera) -> None:
    import cv2

    from dgcal.fields.errors import InputError
    from pathlib import Path
    img = cv2.imread(str(Path(folder) / name), cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
    if img is None:
        raise InputError("cannot read image", Path(folder) / name, field="--images")
    if (img.shape[1], img.shape[0]) != tuple(camera.image_size):
        raise InputError(f"image is {img.shape[1]}x{img.shape[0]} but the camera is "
                         f"{camera.image_size[0]}x{camera.image_size[1]}", Path(folder) / name, field="--images")
