"""Direct georeferencing on check points: intersect measured check points from DG EOPs (POS + mounting) and
report the errors as seed 003 Table 2, improvement rates, ASPRS 2023 statistics and the predicted budget."""
from __future__ import annotations

import argparse
from pathlib import Path

from dgcal.steps import Campaign
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "check"
HELP = "DG accuracy on check points (seed Table 2, ASPRS 2023, predicted error budget)"
SECTION = "check"
OUTPUTS = {"check": "check.json", "report": "check.html", "points": "check_points.csv"}


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
    p.add_argument("--pos-correlation-time", type=arg_types.non_negative, default=None, metavar="S",
                   help="correlation time (s) of the POS errors between images in the predicted budget "
                        "(default: the median straight-strip duration of the trajectory; 0: independent)")
    p.add_argument("--out", required=True, type=Path,
                   help="output directory (check.json, check.html, check_points.csv)")


def run(args: argparse.Namespace) -> int:
    from dgcal.calib.dg.accuracy import CheckOptions, check_dg_files
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.reports.mounting import write_check_outputs

    opts = CheckOptions(mounting=tuple(args.mounting), trajectory=args.trajectory, events=args.events,
                        measurements=args.measurements, gcp=args.gcp, camera=args.camera, crs=args.crs,
                        all_points=args.all_points, pos_correlation_time_s=args.pos_correlation_time)
    res = check_dg_files(opts)
    with staged_dir(args.out) as tmp:
        write_check_outputs(tmp, res, OUTPUTS)
    for k, c in res.checks.items():
        r = c.stats["rms"]
        print(f"{k}: {c.stats['n']} check points, RMS E {r['E']:.3f} N {r['N']:.3f} U {r['U']:.3f} "
              f"2D {r['2D']:.3f} 3D {r['3D']:.3f} m (predicted 3D {c.budget['predicted_rms']['3D']:.3f} m)")
    print(args.out / OUTPUTS["report"])
    return 0


def campaign_steps(c: Campaign) -> None:
    """[check] -> `dgcal check` of every mounting step (two-step first: the reference of the improvement rates):
    `gcp`, `measurements`, `events`, `trajectory` of a DG check flight (default: the calibration flight), `args`."""
    mounts = c.steps_of("mount")
    if c.section(SECTION) is None or not mounts:
        return
    cam = c.provided.get("camera")
    if cam is None:
        raise c.error("[check] needs a camera", "camera")
    from dgcal.calib.mounting.methods import canonical_method
    mounts.sort(key=lambda s: canonical_method(s.label) != "two-step")
    gcp = c.path(SECTION, "gcp", required=False) or c.provided.get("gcp")
    meas = c.path(SECTION, "measurements", required=False) or c.provided.get("measurements")
    events = c.path(SECTION, "events", required=False) or c.provided["events"]
    traj = c.path(SECTION, "trajectory", required=False) or c.provided["trajectory"]
    if gcp is None or meas is None:
        raise c.error("[check] needs gcp and measurements", "check.gcp")
    files = [s.files["mounting"] for s in mounts]
    out = c.out / "check"
    a = [NAME, "--mounting", *map(str, files), "--camera", str(cam), "--trajectory", str(traj), "--events",
         str(events), "--gcp", str(gcp), "--measurements", str(meas), "--crs", c.crs, "--out", str(out)]
    a += c.extra_args(SECTION)
    c.add(NAME, a, [*files, cam, traj, events, gcp, meas], out, OUTPUTS, required=("check",), after=c.step_names())
