"""Single-image georeferencing of measured pixels (seed 000 sec. 5.2): each pixel's ground point from its
image's exterior orientation and a known height, a GeoTIFF DEM or a laser range to the image centre, with
propagated covariances, and per point the covariance-weighted average over its images (seed Fig. 19)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

NAME = "georef"
HELP = "single-image georeferencing of pixels (known height, DEM or laser range) with averaging"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--camera", required=True, type=Path, help="camera file (camera.json, ...)")
    p.add_argument("--measurements", required=True, type=Path, help="pixels CSV image,id,x,y[,sx,sy]")
    p.add_argument("--crs", required=True, help="map CRS of the EOPs, the DEM and the output")
    p.add_argument("--eop", type=Path, help="EOP CSV (PATB, in --crs)")
    p.add_argument("--trajectory", type=Path, help="trajectory CSV (instead of --eop, with --events --mounting)")
    p.add_argument("--events", type=Path, help="events CSV image,gps_week,gps_sow")
    p.add_argument("--mounting", type=Path, help="mounting.json")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--height", type=float, help="known ground height (m, ellipsoidal)")
    src.add_argument("--dem", type=Path, help="GeoTIFF DEM in --crs")
    src.add_argument("--ranges", type=Path, help="laser ranges CSV image,range_m[,s_range_m] (to the image centre)")
    p.add_argument("--sigma-px", type=float, default=0.5, help="pixel sigma when the CSV has none (px)")
    p.add_argument("--sigma-height", type=float, default=0.0, help="sigma of the height / DEM (m)")
    p.add_argument("--sigma-range", type=float, default=0.5, help="laser range sigma when the CSV has none (m)")
    p.add_argument("--out", required=True, type=Path,
                   help="output directory (georef_points.csv, georef_average.csv, georef.json, georef.html)")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from dgcal.calib.camera.files import load_camera
    from dgcal.calib.dg.dem import read_geotiff_dem
    from dgcal.calib.dg.single_image import georeference_images
    from dgcal.fields.crs import MapGrid, parse_crs
    from dgcal.fields.io.csv_tables import atomic_write, read_table, staged_dir, write_table
    from dgcal.fields.errors import InputError
    from dgcal.fields.io.formats import read_eop, read_events, read_measurements, read_trajectory

    grid = MapGrid(args.crs)
    camera = load_camera(args.camera)
    meas = read_measurements(args.measurements)
    if args.eop is not None:
        eop = read_eop(args.eop)
    elif args.trajectory and args.events and args.mounting:
        from dgcal.calib.dg.eop import dg_eop
        from dgcal.calib.mounting.common import MountingResult
        try:
            d = json.loads(Path(args.mounting).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise InputError(f"cannot read mounting file ({exc})", args.mounting) from None
        eop = dg_eop(grid, read_trajectory(args.trajectory), read_events(args.events),
                     MountingResult.from_json(d, str(args.mounting)))[0]
    else:
        raise InputError("give --eop, or --trajectory with --events and --mounting", field="--eop")
    dem = ranges = None
    if args.dem is not None:
        dem = read_geotiff_dem(args.dem)
        if dem.crs is not None and parse_crs(dem.crs, str(args.dem)) != grid.crs:
            raise InputError(f"DEM CRS {dem.crs} differs from --crs {args.crs}", args.dem, field="CRS")
    if args.ranges is not None:
        tab = read_table(args.ranges, ("image", "range_m"), ("s_range_m",))
        r = np.asarray(tab["range_m"], float)
        bad = np.flatnonzero(~np.isfinite(r) | (r <= 0))
        if len(bad):
            raise InputError("range must be a positive number", args.ranges, line=int(tab.lines[bad[0]]),
                             field="range_m")
        s = np.asarray(tab["s_range_m"], float) if "s_range_m" in tab else np.full(len(r), np.nan)
        ranges = {str(k): (float(a), float(b)) for k, a, b in zip(tab["image"], r, s)}
    res = georeference_images(camera, meas, eop, height=args.height, dem=dem, ranges=ranges,
                              sigma_px=args.sigma_px, sigma_height=args.sigma_height, sigma_range=args.sigma_range)
    sig = np.sqrt(np.einsum("nii->ni", res.cov))
    with staged_dir(args.out) as tmp:
        write_table(tmp / "georef_points.csv", ["image", "id", "x", "y", "z", "sx", "sy", "sz", "ok"],
                    [[res.image[i], res.id[i], *res.xyz[i], *sig[i], int(res.ok[i])] for i in range(len(res.id))],
                    fmt="%.4f")
        rows, js = [], {}
        for pid, (av, z) in res.averages.items():
            s2 = np.sqrt(np.diag(av.cov_weighted))
            rows.append([pid, *av.weighted, z, *s2, av.n, av.chi2_dof, *av.mean])
            js[pid] = {"xy_weighted": av.weighted.tolist(), "sigma_xy": s2.tolist(), "xy_mean": av.mean.tolist(),
                       "z": z, "n_images": av.n, "chi2_dof": av.chi2_dof}
        write_table(tmp / "georef_average.csv", ["id", "x", "y", "z", "sx", "sy", "n_images", "chi2_dof", "x_mean",
                                                 "y_mean"], rows, fmt="%.4f")
        _html(res, args).write(tmp / "georef.html")
        with atomic_write(tmp / "georef.json") as fh:
            json.dump({"crs": args.crs, "n_points": int(len(res.id)), "n_ok": int(res.ok.sum()),
                       "height_source": "dem" if dem is not None else "ranges" if ranges is not None else "height",
                       "averages": js}, fh, indent=2)
    print(f"{int(res.ok.sum())}/{len(res.id)} pixels georeferenced, {len(res.averages)} points averaged -> "
          f"{args.out / 'georef_average.csv'}")
    return 0


def _html(res, args):
    """One-file report: per point the spread of its single-image estimates around the average (seed Fig. 19)."""
    import numpy as np

    from dgcal.reports.html import HtmlReport, new_figure
    rep = HtmlReport("dgcal single-image georeferencing")
    src = "DEM " + str(args.dem) if args.dem else "laser ranges " + str(args.ranges) if args.ranges else \
        f"known height {args.height} m"
    rep.kv_table([("CRS", args.crs), ("height source", src), ("pixels", len(res.id)),
                  ("georeferenced", int(res.ok.sum())), ("points averaged", len(res.averages))])
    rows = []
    for pid, (av, z) in res.averages.items():
        s = np.sqrt(np.diag(av.cov_weighted))
        rows.append([pid, av.n, *np.round(av.weighted, 3), round(z, 3), *np.round(s, 3), round(av.chi2_dof, 2)])
    rep.table(["id", "images", "x", "y", "z", "sx", "sy", "chi2/dof"], rows)
    ids = list(res.averages)[:6]
    if ids:
        fig, axes = new_figure(4.0 * len(ids), 4.0, ncols=len(ids), squeeze=False)
        t = np.linspace(0, 2 * np.pi, 100)
        for ax, pid in zip(axes[0], ids):
            av, _ = res.averages[pid]
            m = (res.id == pid) & res.ok
            d = res.xyz[m][:, :2] - av.weighted
            ax.scatter(d[:, 0], d[:, 1], s=14, label="single images")
            w, V = np.linalg.eigh(res.cov[m][:, :2, :2].mean(axis=0))
            ell = (V * np.sqrt(np.maximum(w, 0) * 5.99)) @ np.vstack([np.cos(t), np.sin(t)])
            ax.plot(ell[0], ell[1], "C1", lw=1, label="mean single-image 95 %")
            ax.plot(0, 0, "k+", ms=12, label="weighted average")
            ax.set_title(str(pid))
            ax.set_xlabel("dE (m)")
            ax.set_ylabel("dN (m)")
            ax.set_aspect("equal", adjustable="datalim")
        axes[0][0].legend(fontsize=7)
        rep.figure(fig, "Single-image estimates around their covariance-weighted average")
    return rep
