"""Calibrate lever arm, boresight and exposure delay from bundle EOPs, the POS trajectory and the events.

Methods: two-step (per-epoch lever arm and boresight, delay 0; the seed's "traditional"), joint (delay,
lever arm and boresight together; the seed's "proposed", the default) and iso (one bundle adjustment of
the image measurements). mounting.json's `method` is the name given, `method_canonical` the method's name.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from dgcal.steps import Campaign
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "mount"
HELP = "system calibration: lever arm, boresight, exposure delay (methods two-step, joint, iso)"
SECTION = "mount"
OUTPUTS = {"mounting": "mounting.json", "report": "report.html", "epochs": "epochs.csv"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--eop", required=True, type=Path, help="EOP CSV of the calibration flight (bundle output)")
    p.add_argument("--crs", required=True, help="CRS of the EOPs (and ground points)")
    p.add_argument("--trajectory", required=True, type=Path,
                   help="trajectory.csv, or the events.csv of `dgcal pos` (one row per event)")
    p.add_argument("--events", required=True, type=Path, help="events CSV image,gps_week,gps_sow")
    p.add_argument("--method", default=None, metavar="METHOD",
                   help="two-step, joint (default) or iso; the seed paper's names traditional (= two-step) and "
                        "proposed (= joint) are accepted too")
    p.add_argument("--out", required=True, type=Path, help="output directory (mounting.json, report.html)")
    p.add_argument("--no-reject", action="store_true", help="keep every epoch (no chi-square rejection)")
    p.add_argument("--fix-delay", action="store_true", help="joint/iso: hold the delay at 0")
    p.add_argument("--pos-common-fraction", type=arg_types.fraction, default=None, metavar="F",
                   help="joint/iso: share (0-1) of the POS error variance common to the whole flight, added to the "
                        "sigmas (default 1, as in dgcal run: a MEMS smoother's attitude error is mostly a bias over a "
                        "flight; 0: independent per photo, as in the seed)")
    p.add_argument("--measurements", type=Path, help="iso: image measurements of ground points (or gcp_list.txt)")
    p.add_argument("--gcp", type=Path, help="iso: ground control points CSV (role check points are not used)")
    p.add_argument("--camera", type=Path, help="iso: camera file (camera.json, ...)")
    p.add_argument("--refine-intrinsics", default="", metavar="NAMES",
                   help="iso: comma-separated camera parameters to estimate too (e.g. f,cx,cy)")


def run(args: argparse.Namespace) -> int:
    from dgcal.calib.mounting.methods import DEFAULT_METHOD, MountOptions, calibrate_mounting_files
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.reports.mounting import write_mount_outputs

    opts = MountOptions(eop=args.eop, crs=args.crs, trajectory=args.trajectory, events=args.events,
                        method=args.method or DEFAULT_METHOD, reject=not args.no_reject, fix_delay=args.fix_delay,
                        measurements=args.measurements, gcp=args.gcp, camera=args.camera,
                        refine_intrinsics=tuple(k.strip() for k in args.refine_intrinsics.split(",") if k.strip()))
    if args.pos_common_fraction is not None:          # else the library's one default
        opts.pos_common_fraction = args.pos_common_fraction
    cal = calibrate_mounting_files(opts)
    with staged_dir(args.out) as tmp:
        write_mount_outputs(tmp, cal, OUTPUTS)
    res, s = cal.result, cal.result.sigmas
    delay = "not estimated (0)" if s[0] == 0 else f"{res.delay_s:+.4f} ± {s[0]:.4f} s"
    print(f"{res.method}: delay {delay}, lever arm "
          + ", ".join(f"{v:+.3f}±{e:.3f}" for v, e in zip(res.lever_arm_m, s[1:4])) + " m, "
          + f"{res.n_epochs} epochs, {len(res.rejected)} rejected")
    for w in res.warnings:
        print(f"warning: {w}")
    print(args.out / OUTPUTS["mounting"])
    return 0


def campaign_steps(c: Campaign) -> None:
    """[mount] -> one `dgcal mount` per method: `method` (default joint), `compare` = [more methods],
    `measurements` (iso; default the triangulation's), `pos_common_fraction` (joint, iso), `args`."""
    mnt = c.section(SECTION)
    if mnt is None:
        return
    eop, traj, events = (c.provided.get(k) for k in ("eop", "trajectory", "events"))
    if eop is None or traj is None or events is None:
        raise c.error("[mount] needs [triangulation] (or its eop) and [pos] (or its trajectory and events)", "mount")
    from dgcal.calib.mounting.methods import DEFAULT_METHOD, METHOD_NAMES, mounting_method
    method = str(mnt.get("method", DEFAULT_METHOD))
    methods = [method] + [str(m) for m in mnt.get("compare", []) if m != method]
    for m in methods:
        if m.strip().lower() not in METHOD_NAMES:
            raise c.error(f"unknown mounting method {m!r} ({', '.join(METHOD_NAMES)})", "mount.method")
    dep = c.step_names()
    for m in methods:
        info = mounting_method(m)
        out = c.out / f"mount_{m}"
        a = [NAME, "--eop", str(eop), "--crs", c.crs, "--trajectory", str(traj), "--events", str(events),
             "--method", m, "--out", str(out)]
        ins = [eop, traj, events]
        if info.needs_image_measurements:
            meas = c.path(SECTION, "measurements", required=False) or c.provided.get("measurements")
            gcp, cam = c.provided.get("gcp"), c.provided.get("camera")
            if meas is None or gcp is None or cam is None:
                raise c.error(f"mount method {m} needs the triangulation's gcp and measurements and a camera",
                              "mount.compare")
            a += ["--camera", str(cam), "--gcp", str(gcp), "--measurements", str(meas)]
            ins += [cam, gcp, meas]
        if info.uses_pos_common_fraction and "pos_common_fraction" in mnt:
            a += ["--pos-common-fraction", str(float(mnt["pos_common_fraction"]))]
        a += c.extra_args(SECTION)
        c.add(f"mount_{m}", a, ins, out, OUTPUTS, required=("mounting",), after=dep, label=m,
              weight=3.0 if info.needs_image_measurements else 1.0)   # iso: a bundle adjustment
