"""Calibrate lever arm, boresight and exposure delay from bundle EOPs, the POS trajectory and the events."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

NAME = "mount"
HELP = "system calibration: lever arm, boresight, exposure delay (traditional | proposed | iso)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--eop", required=True, type=Path, help="EOP CSV of the calibration flight (bundle output)")
    p.add_argument("--crs", required=True, help="CRS of the EOPs (and ground points)")
    p.add_argument("--trajectory", required=True, type=Path,
                   help="trajectory.csv, or the events.csv of `dgcal pos` (one row per event)")
    p.add_argument("--events", required=True, type=Path, help="events CSV image,gps_week,gps_sow")
    p.add_argument("--method", default="proposed", choices=("traditional", "proposed", "iso"))
    p.add_argument("--out", required=True, type=Path, help="output directory (mounting.json, report.html)")
    p.add_argument("--no-reject", action="store_true", help="keep every epoch (no chi-square rejection)")
    p.add_argument("--fix-delay", action="store_true", help="proposed/iso: hold the delay at 0")
    p.add_argument("--pos-common-fraction", type=float, default=0.0, metavar="F",
                   help="proposed/iso: share (0-1) of the POS error variance common to the whole flight, added to the "
                        "sigmas (0: independent per photo, as in the seed; 1: conservative for a MEMS smoother)")
    p.add_argument("--measurements", type=Path, help="iso: image measurements of ground points (or gcp_list.txt)")
    p.add_argument("--gcp", type=Path, help="iso: ground control points CSV (role check points are not used)")
    p.add_argument("--camera", type=Path, help="iso: camera file (camera.json, ...)")
    p.add_argument("--refine-intrinsics", default="", metavar="NAMES",
                   help="iso: comma-separated camera parameters to estimate too (e.g. f,cx,cy)")


def run(args: argparse.Namespace) -> int:
    from dgcal.calib.mounting.methods import calibrate_mounting
    from dgcal.fields.crs import MapGrid
    from dgcal.fields.io.csv_tables import atomic_write, staged_dir
    from dgcal.fields.errors import InputError
    from dgcal.fields.io.formats import read_eop, read_events, read_trajectory
    from dgcal.reports.mounting import mount_report_html

    grid = MapGrid(args.crs)
    eop = read_eop(args.eop)
    traj = read_trajectory(args.trajectory)
    events = read_events(args.events)
    if args.method == "iso":
        missing = [o for o in ("measurements", "gcp", "camera") if getattr(args, o) is None]
        if missing:
            raise InputError(f"--method iso needs --{missing[0]}", field=f"--{missing[0]}")
        from dgcal.calib.mounting.integrated import calibrate_iso_files
        refine = tuple(k.strip() for k in args.refine_intrinsics.split(",") if k.strip())
        res = calibrate_iso_files(eop, grid, traj, events, args.measurements, args.gcp, args.camera,
                                  fix_delay=args.fix_delay, refine_intrinsics=refine,
                                  pos_common_fraction=args.pos_common_fraction)
    else:
        kw = {} if args.method == "traditional" else {"reject": not args.no_reject, "fix_delay": args.fix_delay,
                                                      "pos_common_fraction": args.pos_common_fraction}
        res = calibrate_mounting(eop, grid, traj, events, args.method, **kw)
    main = res.to_json()
    others = {}
    if args.method == "iso":
        others["proposed"] = calibrate_mounting(eop, grid, traj, events, "proposed",
                                                pos_common_fraction=args.pos_common_fraction).to_json()
    if args.method != "traditional":
        others["traditional"] = calibrate_mounting(eop, grid, traj, events, "traditional").to_json()
    with staged_dir(args.out) as tmp:
        with atomic_write(tmp / "mounting.json") as fh:
            json.dump(main, fh, indent=2)
            fh.write("\n")
        with atomic_write(tmp / "report.html") as fh:
            fh.write(mount_report_html(main, others))
        _write_epochs(tmp / "epochs.csv", main)
    s = res.sigmas
    print(f"{res.method}: delay {res.delay_s:+.4f} ± {s[0]:.4f} s, lever arm "
          + ", ".join(f"{v:+.3f}±{e:.3f}" for v, e in zip(res.lever_arm_m, s[1:4])) + " m, "
          + f"{res.n_epochs} epochs, {len(res.rejected)} rejected")
    for w in res.warnings:
        print(f"warning: {w}")
    print(args.out / "mounting.json")
    return 0


def _write_epochs(path: Path, d: dict) -> None:
    """Per-epoch values of mounting.json as CSV (lever arm m, boresight deg, residuals, rejection)."""
    from dgcal.fields.io.csv_tables import write_table
    pe = d.get("per_epoch") or {}
    if "image" not in pe:
        return
    cols = [("lever_x", "lever_arm_m", 0), ("lever_y", "lever_arm_m", 1), ("lever_z", "lever_arm_m", 2),
            ("bore_x_deg", "boresight_deg", 0), ("bore_y_deg", "boresight_deg", 1), ("bore_z_deg", "boresight_deg", 2),
            ("res_e_m", "residual_position_m", 0), ("res_n_m", "residual_position_m", 1),
            ("res_u_m", "residual_position_m", 2), ("res_rx_deg", "residual_rotation_deg", 0),
            ("res_ry_deg", "residual_rotation_deg", 1), ("res_rz_deg", "residual_rotation_deg", 2)]
    cols = [c for c in cols if c[1] in pe]
    rows = []
    for i, im in enumerate(pe["image"]):
        rows.append([im] + [pe[k][i][j] for _, k, j in cols] + [int(bool(pe.get("rejected", [False] * (i + 1))[i]))])
    write_table(path, ["image"] + [c[0] for c in cols] + ["rejected"], rows, fmt="%.6f")
