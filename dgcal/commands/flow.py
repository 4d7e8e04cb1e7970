"""GNSS + optic-flow attitude of a forward camera (seed 001): pseudo-roll/pitch/yaw from the GNSS velocity, the
focus of expansion of the de-rotated flow, pitch and yaw with their offsets (angle of attack, drift angle) and the
height above ground, with sigmas, plots and seed 001's Table 2 against a true trajectory."""
from __future__ import annotations

import argparse
from pathlib import Path
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "flow"
HELP = "GNSS + optic-flow attitude, FOE offsets and height above ground of a forward camera (seed 001)"
OUTPUTS = {"pairs": "flow.csv", "summary": "flow.json", "report": "report.html"}
OPTION_FLAGS = {"video_start_gps": "--video-start"}   # FlowOptions fields named in errors -> flags


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--video", type=Path, help="video of the forward camera (frame 0 at --video-start)")
    src.add_argument("--images", type=Path, help="folder of frames (times from --frame-times or frames.csv)")
    p.add_argument("--gnss", required=True, type=Path,
                   help="GNSS velocity: CSV t_gps,vn,ve,vd (or gps_week,gps_sow,...), or a GNSS solution file with "
                   "velocities (dgcal gnss.csv, RTKLIB .pos)")
    p.add_argument("--camera", required=True, type=Path, help="camera file (camera.json, OpenCV YAML, ...)")
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--frame-times", type=Path, default=None,
                   help="CSV image,t_gps of the frames (default: frames.csv in or beside --images)")
    p.add_argument("--video-start", type=arg_types.finite, default=None, help="GPS time of the video's first frame (s)")
    p.add_argument("--fps", type=arg_types.positive, default=None, help="video frame rate (default: the container's)")
    p.add_argument("--pair-every", type=arg_types.positive, default=2.0, help="a frame pair every S s (default 2)")
    p.add_argument("--frame-dt", type=arg_types.positive, default=0.5, help="frames of a pair S s apart (default 0.5)")
    p.add_argument("--velocity-sigma", type=arg_types.positive, default=None,
                   help="GNSS velocity noise per axis (m/s; default: estimated from the data)")
    p.add_argument("--camera-to-body", type=arg_types.finite, nargs=9, default=None, metavar="R",
                   help="R_cam_to_body row-major (default: the camera looks along body x, image right = body y)")
    p.add_argument("--truth", type=Path, default=None,
                   help="true trajectory (trajectory CSV or a simulator's truth_trajectory.csv) for Table 2")
    p.add_argument("--ground-height", type=arg_types.finite, default=None,
                   help="ground's ellipsoidal height (m) for the AGL errors against --truth")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from dgcal.fields.errors import InputError
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.pos.lowcost.flow import FlowOptions, flow_attitude_run
    from dgcal.pos.lowcost.optic_flow import R_CAM_TO_BODY_FORWARD
    from dgcal.reports.flow import write_flow_outputs

    R_cam_to_body = R_CAM_TO_BODY_FORWARD.copy()
    if args.camera_to_body is not None:
        R_cam_to_body = np.asarray(args.camera_to_body, float).reshape(3, 3)
        if not np.allclose(R_cam_to_body @ R_cam_to_body.T, np.eye(3), atol=1e-6) or np.linalg.det(R_cam_to_body) < 0:
            raise InputError("not a rotation matrix", field="--camera-to-body")
    for name, v in (("--pair-every", args.pair_every), ("--frame-dt", args.frame_dt)):
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"must be positive, not {v}", field=name)
    res = flow_attitude_run(FlowOptions(camera=args.camera, gnss=args.gnss, images=args.images, video=args.video,
                                        frame_times=args.frame_times, video_start_gps=args.video_start, fps=args.fps,
                                        R_cam_to_body=R_cam_to_body, pair_every_s=args.pair_every,
                                        frame_dt_s=args.frame_dt, sigma_v_mps=args.velocity_sigma, truth=args.truth,
                                        ground_height_m=args.ground_height, progress=not args.no_progress))
    with staged_dir(args.out) as tmp:
        write_flow_outputs(tmp, res, OUTPUTS)
    s = res.summary
    msg = f"{s['n_pairs']} frame pairs ({s['n_failed']} failed)"
    t2 = s["table2"]
    if t2:
        msg += "; error std roll/pitch/yaw " + "/".join(f"{t2[k]['std_deg']:.3f}" for k in ("roll", "pitch", "yaw"))
        msg += " deg, error/sigma RMS " + "/".join(f"{t2[k]['normalised_rms']:.2f}" for k in ("roll", "pitch", "yaw"))
    print(f"{msg}; report {args.out / OUTPUTS['report']}")
    return 0
