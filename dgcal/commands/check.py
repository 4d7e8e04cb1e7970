"""Direct georeferencing on check points: intersect measured check points from DG EOPs (POS + mounting) and
report the errors as seed 003 Table 2, improvement rates, ASPRS 2023 statistics and the predicted budget."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

NAME = "check"
HELP = "DG accuracy on check points (seed Table 2, ASPRS 2023, predicted error budget)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mounting", required=True, type=Path, nargs="+",
                   help="mounting.json file(s); with several, the first is the reference of the improvement rates")
    p.add_argument("--trajectory", required=True, type=Path, help="trajectory.csv (or events.csv of dgcal pos)")
    p.add_argument("--events", required=True, type=Path, help="events CSV image,gps_week,gps_sow")
    p.add_argument("--measurements", required=True, type=Path, help="image measurements of the check points")
    p.add_argument("--gcp", required=True, type=Path, help="ground points CSV (points with role check are used)")
    p.add_argument("--camera", required=True, type=Path, help="camera file (camera.json, ...)")
    p.add_argument("--crs", required=True, help="CRS of the ground points")
    p.add_argument("--all-points", action="store_true", help="use control points as check points too")
    p.add_argument("--pos-correlation-time", type=float, default=None, metavar="S",
                   help="correlation time (s) of the POS errors between images in the predicted budget "
                        "(default: the median straight-strip duration of the trajectory; 0: independent)")
    p.add_argument("--out", required=True, type=Path, help="output directory (check.json, check.html, check_points.csv)")


def _label(path: Path, method: str, seen: set) -> str:
    name = method
    if name in seen:
        name = f"{method} ({path.parent.name or path.name})"
    seen.add(name)
    return name


def run(args: argparse.Namespace) -> int:
    from dgcal.calib.camera.files import load_camera
    from dgcal.calib.dg.accuracy import check_points_dg, improvement_table
    from dgcal.calib.mounting.common import MountingResult
    from dgcal.fields.crs import MapGrid
    from dgcal.fields.io.csv_tables import atomic_write, staged_dir, write_table
    from dgcal.fields.errors import InputError
    from dgcal.fields.io.formats import read_events, read_points, read_trajectory
    from dgcal.reports.mounting import check_report_html

    if args.pos_correlation_time is not None and not args.pos_correlation_time >= 0:
        raise InputError(f"must be a time >= 0 s, not {args.pos_correlation_time}", field="--pos-correlation-time")
    grid = MapGrid(args.crs)
    traj = read_trajectory(args.trajectory)
    events = read_events(args.events)
    meas = read_measurements_any(args.measurements)
    pts = read_points(args.gcp)
    camera = load_camera(args.camera)
    roles = ("check", "control") if args.all_points else ("check",)
    checks, seen = {}, set()
    for path in args.mounting:
        try:
            d = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise InputError(f"cannot read mounting file ({exc})", path) from None
        m = MountingResult.from_json(d, str(path))
        tau = "auto" if args.pos_correlation_time is None else args.pos_correlation_time
        checks[_label(Path(path), m.method, seen)] = check_points_dg(grid, traj, events, m, camera, meas, pts, roles,
                                                                     pos_correlation_time_s=tau)
    names = list(checks)
    js = {k: v.to_json() for k, v in checks.items()}
    imp = improvement_table({k: v.stats for k, v in checks.items()}, names[0]) if len(names) > 1 else None
    with staged_dir(args.out) as tmp:
        with atomic_write(tmp / "check.json") as fh:
            json.dump({"checks": js, "improvement_over_" + names[0]: imp}, fh, indent=2)
        with atomic_write(tmp / "check.html") as fh:
            fh.write(check_report_html(js, imp))
        rows = []
        for k, c in checks.items():
            for i in range(len(c.ids)):
                rows.append([k, c.ids[i], *c.xyz_dg[i], *c.err_enu[i], *c.sigma_pred[i], int(c.n_rays[i])])
        write_table(tmp / "check_points.csv", ["method", "id", "x", "y", "z", "dE", "dN", "dU", "sE_pred",
                                               "sN_pred", "sU_pred", "n_rays"], rows, fmt="%.4f")
    for k, c in checks.items():
        r = c.stats["rms"]
        print(f"{k}: {c.stats['n']} check points, RMS E {r['E']:.3f} N {r['N']:.3f} U {r['U']:.3f} "
              f"2D {r['2D']:.3f} 3D {r['3D']:.3f} m (predicted 3D {c.budget['predicted_rms']['3D']:.3f} m)")
    print(args.out / "check.html")
    return 0


def read_measurements_any(path: Path):
    """Image measurements from a dgcal CSV or an ODM gcp_list.txt."""
    from dgcal.fields.io.formats import read_measurements
    try:
        from dgcal.fields.io.gcp_files import is_odm_gcp_list, read_odm_gcp_list
    except ImportError:
        return read_measurements(path)
    return read_odm_gcp_list(path)[2] if is_odm_gcp_list(path) else read_measurements(path)
