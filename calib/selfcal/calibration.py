"""Camera calibration pipeline: target field + measurements (or images, via detection) -> calibrated
camera with sigmas, diagnostics and the output files (camera.json, OpenCV YAML, COLMAP, Metashape XML).

Python use::

    from dgcal.calib.selfcal.calibration import calibrate_camera, write_camera_outputs
    cal = calibrate_camera("field.csv", measurements="meas.csv", image_size=(6016, 4016), model="opencv8")
    print(cal.camera.as_dict(), cal.ba.rms_px, cal.warnings)
"""
from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dgcal.calib.camera.files import (camera_json_dict, load_camera, write_colmap_cameras_txt, write_metashape_xml,
                                      write_opencv_yaml)
from dgcal.calib.camera.models import CameraModel, model_class
from dgcal.calib.selfcal.adjustment import IntrinsicBAResult, adjust
from dgcal.calib.selfcal.detection import detect_folder
from dgcal.calib.selfcal.diagnostics import Diagnostics, diagnose
from dgcal.fields.errors import InputError
from dgcal.fields.frames import opk_from_R_cam_to_map
from dgcal.fields.io.csv_tables import atomic_write, write_table
from dgcal.fields.io.formats import (Measurements, Points, read_measurements, read_points, write_measurements,
                                     write_points)


@dataclass
class CameraCalibration:
    """A finished calibration: adjustment result, diagnostics and the inputs it used."""

    ba: IntrinsicBAResult
    diagnostics: Diagnostics
    field: Points
    measurements: Measurements
    detected: bool = False
    detection_report: dict | None = None

    @property
    def camera(self) -> CameraModel:
        """The calibrated camera (parameters with `sigmas`)."""
        return self.ba.camera

    @property
    def warnings(self) -> list[str]:
        return list(self.diagnostics.warnings)

    def stats(self) -> dict:
        """Statistics and diagnostics for camera.json (everything beyond model, parameters and opencv)."""
        ba = self.ba
        names = list(ba.camera.PARAMS)
        corr = np.where(np.isfinite(ba.correlation), np.round(ba.correlation, 4), np.nan)
        out = {
            "rms_px": ba.rms_px,
            "n_observations": ba.n_observations,
            "n_rejected": ba.n_rejected,
            "n_images": len(ba.image_names) - len(ba.dropped_images),
            "sigma0": ba.sigma0,
            "redundancy": ba.redundancy,
            "fixed_parameters": [k for k, f in zip(names, ba.free) if not f],
            "refine_targets": ba.refine_targets,
            "converged": ba.converged,
            "rejection_settled": ba.rejection_settled,
            "iterations": ba.iterations,
            "rms_definition": "sqrt(mean(|projected - measured|^2)) over used observations, px (as OpenCV)",
            "correlation": {"parameters": names, "matrix": corr},
            "significance_t": self.diagnostics.significance,
            "residual_pattern": self.diagnostics.as_dict()["residual_pattern"],
            "warnings": self.warnings,
            "per_image_rms_px": ba.per_image_rms(),
            "dropped_images": ba.dropped_images,
            "rejected": [{"image": r.image, "id": r.id, "residual_px": r.residual_px, "reason": r.reason}
                         for r in ba.rejected],
        }
        if ba.refine_targets != "none":
            moved = np.linalg.norm(ba.points_xyz - self.field.xyz, axis=1)
            out["targets_moved_max_m"] = float(moved.max())
        return out

    def camera_json(self) -> dict:
        """The camera.json content (see docs/camera_calibration.md)."""
        d = camera_json_dict(self.camera, self.camera.sigmas, self.stats())
        err = d.get("opencv_max_error_px") or 0.0
        if err > 0.05:
            msg = (f"the OpenCV block (and opencv.yaml, cameras.txt) is an approximation of this {self.camera.NAME} "
                   f"camera: up to {err:.3g} px off over the frame")
            if msg not in self.diagnostics.warnings:
                self.diagnostics.warnings.append(msg)
            d["warnings"] = self.warnings
        return d


def _check_measurements(meas: Measurements, field: Points, image_size) -> None:
    known = set(field.ids.astype(str).tolist())
    ids = meas.id.astype(str)
    bad = ~np.isin(ids, list(known))
    if bad.any():
        k = int(np.argmax(bad))
        line = None if meas.lines is None else int(meas.lines[k])
        n_bad = len(set(ids[bad].tolist()))
        raise InputError(f"target id {ids[k]!r} is not in the field file{f' {field.path}' if field.path else ''}"
                         f" ({n_bad} unknown id(s))", meas.path, line, "id")
    w, h = image_size
    for c, lim, name in ((0, w, "x"), (1, h, "y")):
        out = (meas.xy[:, c] < -0.5) | (meas.xy[:, c] > lim - 0.5)
        if out.any():
            k = int(np.argmax(out))
            line = None if meas.lines is None else int(meas.lines[k])
            raise InputError(f"{meas.xy[k, c]:g} px is outside the image ({w} x {h}); wrong --image-size?",
                             meas.path, line, name)


def calibrate_camera(field: Points | str | Path, measurements: Measurements | str | Path | None = None,
                     image_size: tuple[int, int] | None = None, images: str | Path | None = None,
                     model: str = "fraser7", fixed=(), refine_targets: str = "none", reject_k: float = 4.0,
                     progress: bool = True, workers: int | None = None,
                     initial: CameraModel | str | Path | None = None) -> CameraCalibration:
    """Calibrate one camera from a target field (m) and image measurements (px) or a folder of images.

    With `images`, the targets are detected (dgcal.calib.selfcal.detection) and the image size is read from the images.
    Measurement sigmas `sx,sy` act as relative weights; sigma0 scales every reported sigma. `initial`: a
    camera (or a camera file load_camera reads) to start from instead of the built-in initial values.
    """
    model_class(model)
    field_path = Path(field) if isinstance(field, (str, Path)) else field.path
    pts = read_points(field) if isinstance(field, (str, Path)) else field
    detection_report = None
    if images is not None:
        if field_path is None:
            raise InputError("detection needs the field file (its layout sits beside it)")
        meas, detection_report = detect_folder(images, field_path, workers=workers, progress=progress)
        size = detection_report.get("image_size")
        if size is None:
            raise InputError("the images differ in size; calibrate one camera (one image size) at a time", images)
        if image_size is not None and tuple(image_size) != tuple(size):
            raise InputError(f"--image-size {image_size[0]} {image_size[1]} differs from the images' "
                             f"{size[0]} x {size[1]}", images)
        image_size = tuple(int(v) for v in size)
        if len(meas) == 0:
            raise InputError("no targets detected in any image", images)
    else:
        if measurements is None:
            raise InputError("give either image measurements or an image folder")
        meas = read_measurements(measurements) if isinstance(measurements, (str, Path)) else measurements
        if image_size is None:
            raise InputError("the image size (width, height in px) is needed with measurements", meas.path)
    image_size = (int(image_size[0]), int(image_size[1]))
    if image_size[0] <= 0 or image_size[1] <= 0:
        raise InputError(f"image size must be positive, got {image_size}", field="image_size")
    _check_measurements(meas, pts, image_size)
    if isinstance(initial, (str, Path)):
        initial = load_camera(initial)
    if initial is not None and tuple(initial.image_size) != image_size:
        raise InputError(f"the initial camera is for {initial.image_size[0]} x {initial.image_size[1]} px images, "
                         f"these are {image_size[0]} x {image_size[1]}", field="initial")
    field_sigma = pts.sigma if np.isfinite(pts.sigma).any() else None
    progress_fn = None
    if progress:
        progress_fn = partial(tqdm, desc="initial poses", unit="img", file=sys.stderr, leave=False)
    try:
        ba = adjust(pts.ids, pts.xyz, meas.image, meas.id, meas.xy, image_size, model,
                    meas_sigma=meas.sigma, field_sigma=field_sigma, fixed=tuple(fixed),
                    refine_targets=refine_targets, reject_k=reject_k, initial=initial, progress=progress_fn)
    except InputError as exc:
        if exc.path is None and exc.field is None:
            raise InputError(str(exc), images if images is not None else meas.path) from None
        raise
    sigmas_given = bool(np.isfinite(meas.sigma).all())
    return CameraCalibration(ba=ba, diagnostics=diagnose(ba, sigmas_given=sigmas_given), field=pts, measurements=meas,
                             detected=images is not None, detection_report=detection_report)


def write_poses(path: str | Path, ba: IntrinsicBAResult) -> None:
    """Per-image poses in the field frame: projection centre X,Y,Z (m) and PATB omega, phi, kappa (deg) of
    R_photo_to_field, their sigmas (centre m; rotation deg about the camera axes), RMS (px) and count."""
    C, sC = ba.camera_centres()
    rms = ba.per_image_rms()
    n = np.bincount(ba.obs_image[ba.used], minlength=len(ba.image_names))
    rows = []
    for i, name in enumerate(ba.image_names):
        if name in ba.dropped_images:
            continue
        opk = opk_from_R_cam_to_map(ba.R_field_to_cam[i].T)
        rows.append([name, *C[i], *opk, *sC[i], *ba.pose_sigma[i, 3:], rms[name], int(n[i])])
    write_table(path, ["image", "X", "Y", "Z", "omega", "phi", "kappa", "sX", "sY", "sZ", "s_rx_deg",
                       "s_ry_deg", "s_rz_deg", "rms_px", "n_obs"], rows, fmt="%.8g")


CAMERA_FILES = {"camera": "camera.json", "opencv": "opencv.yaml", "colmap": "cameras.txt", "metashape": "metashape.xml",
                "poses": "poses.csv", "measurements": "measurements.csv", "field_refined": "field_refined.csv"}


def write_camera_outputs(cal: CameraCalibration, out_dir: str | Path,
                         names: dict[str, str] | None = None) -> dict[str, Path]:
    """Write camera.json, opencv.yaml, cameras.txt (COLMAP), metashape.xml, poses.csv, measurements.csv (when
    detected) and field_refined.csv (when targets were refined) into `out_dir`, named by role in `names`
    (default `CAMERA_FILES`; `dgcal camera` passes its declared OUTPUTS); returns the paths by role."""
    out = Path(out_dir)
    path = {role: out / name for role, name in (names or CAMERA_FILES).items()}
    paths = {}
    d = cal.camera_json()
    with atomic_write(path["camera"]) as fh:
        json.dump(d, fh, indent=2, allow_nan=False)
        fh.write("\n")
    write_opencv_yaml(path["opencv"], cal.camera)
    write_colmap_cameras_txt(path["colmap"], cal.camera)
    write_metashape_xml(path["metashape"], cal.camera)
    write_poses(path["poses"], cal.ba)
    paths.update({k: path[k] for k in ("camera", "opencv", "colmap", "metashape", "poses")})
    if cal.detected:
        write_measurements(path["measurements"], cal.measurements)
        paths["measurements"] = path["measurements"]
    if cal.ba.refine_targets != "none":
        # held (datum) and unobserved coordinates have no sigma: NaN, which read_points accepts as "not given"
        sig = np.where(cal.ba.points_free, cal.ba.points_sigma, np.nan)
        refined = Points(cal.field.ids, cal.ba.points_xyz, sig, cal.field.role)
        write_points(path["field_refined"], refined)
        paths["field_refined"] = path["field_refined"]
    return paths


@dataclass
class CameraOptions:
    """Inputs and settings of `dgcal camera`: the target field, measurements (with the image size) or an
    image folder, the model and what to hold or refine (see `calibrate_camera`)."""

    field: Path                              # target field CSV id,x,y,z[,sx,sy,sz] (m)
    measurements: Path | None = None         # image,id,x,y[,sx,sy] (px); or
    images: Path | None = None               # a folder of images (targets detected)
    image_size: tuple[int, int] | None = None  # (width, height) px; required with measurements
    model: str = "fraser7"
    fixed: tuple[str, ...] = ()              # parameters held at their initial values
    refine_targets: str = "none"             # none | free | weighted
    reject_k: float = 4.0                    # reject beyond k robust sigmas
    workers: int | None = None               # detection processes
    initial: Path | None = None              # camera file to start from
    progress: bool = False                   # progress bars (detection)


def calibrate_camera_files(opts: CameraOptions) -> CameraCalibration:
    """`dgcal camera`: `calibrate_camera` with the inputs and settings of `opts`."""
    if opts.measurements is not None and opts.image_size is None:
        raise InputError("--image-size W H is required with --measurements", opts.measurements)
    return calibrate_camera(opts.field, measurements=opts.measurements, images=opts.images,
                            image_size=opts.image_size, model=opts.model, fixed=opts.fixed,
                            refine_targets=opts.refine_targets, reject_k=opts.reject_k, progress=opts.progress,
                            workers=opts.workers, initial=opts.initial)
