"""Camera calibration pipeline: target field + measurements (or images, via detection) -> calibrated
camera with sigmas, diagnostics and the output files (camera.json, OpenCV YAML, COLMAP, Metashape XML).

Python use::

    from dgcal.calib.selfcal.calibration import calibrate_camera, write_camera_outputs
    cal = calibrate_camera("field.csv", measurements="meas.csv", image_size=(6016, 4016), model="opencv8")
    print(cal.camera.as_dict(), cal.ba.rms_px, cal.warnings)
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from dataclasses import field as dataclass_field
from functools import partial
from pathlib import Path

import numpy as np

from dgcal.calib.camera.conversions import from_opencv, to_colmap, to_metashape, to_opencv
from dgcal.calib.camera.files import (CONVERSION_WARN_PX, camera_json_dict, conversion_warning, load_camera,
                                      write_colmap_cameras_txt, write_metashape_xml, write_opencv_yaml)
from dgcal.calib.camera.models import CameraModel, model_class
from dgcal.calib.camera.region import ValidRegion, hull_candidates
from dgcal.calib.selfcal.adjustment import IntrinsicBAResult, adjust
from dgcal.calib.selfcal.board_detection import BoardDetector
from dgcal.calib.selfcal.detection import CharucoFieldDetector, detect_folder, read_gray, resolve_field
from dgcal.calib.selfcal.diagnostics import Diagnostics, diagnose
from dgcal.calib.selfcal.frames import VIDEO_SUFFIXES, FrameChoice, choose_frames, detect_sources, expand_sources, \
    video_frames
from dgcal.calib.selfcal.model_choice import ModelComparison, compare_models
from dgcal.calib.selfcal.uncertainty import UncertaintyMap, converted_uncertainty_map, uncertainty_map
from dgcal.fields.progress import track
from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.frames import opk_from_R_cam_to_map
from dgcal.fields.io.csv_tables import atomic_write, write_table
from dgcal.fields.io.formats import (Measurements, Points, read_measurements, read_points, write_measurements,
                                     write_points)
from dgcal.fields.targets.boards import Board, load_board_layout, read_board


@dataclass
class CameraCalibration:
    """A finished calibration: adjustment result, diagnostics, the inputs it used, the model's valid region, its
    projection uncertainty, the model comparison (`--model auto`) and the frames chosen from videos."""

    ba: IntrinsicBAResult
    diagnostics: Diagnostics
    field: Points
    measurements: Measurements
    detected: bool = False
    detection_report: dict | None = None
    region: ValidRegion | None = None
    uncertainty: UncertaintyMap | None = None
    opencv_uncertainty: UncertaintyMap | None = None     # of the OpenCV block when it is a fitted conversion
    comparison: ModelComparison | None = None
    frames: FrameChoice | None = None
    board: Board | None = None
    conversion_errors: dict = dataclass_field(default_factory=dict)  # px inside the valid region, by export

    @property
    def camera(self) -> CameraModel:
        """The calibrated camera (parameters with `sigmas`)."""
        return self.ba.camera

    @property
    def warnings(self) -> list[str]:
        return list(self.diagnostics.warnings)

    def _warn(self, msg: str) -> None:
        if msg not in self.diagnostics.warnings:
            self.diagnostics.warnings.append(msg)

    def finish(self, uncertainty_range_m: float | None = None) -> "CameraCalibration":
        """Valid region, projection uncertainty, the exports' conversion errors and the warnings they call for."""
        ba, cam = self.ba, self.camera
        if self.region is None:
            self.region = ValidRegion.of(cam, hull_candidates(ba.obs_xy, ba.used))
        reg = self.region
        self.uncertainty = uncertainty_map(ba, uncertainty_range_m)
        ocv, err = to_opencv(cam, reg)
        self.conversion_errors = {"opencv": err, "colmap": to_colmap(cam, reg)[2],
                                  "metashape": to_metashape(cam, reg)[1]}
        if err > 0:
            conv_cam = from_opencv(ocv, cam.image_size, "opencv8" if "k4" in ocv else None)
            free = [k for k in conv_cam.PARAMS if k != "B2"]
            self.opencv_uncertainty = converted_uncertainty_map(ba, conv_cam, free, reg, self.uncertainty.range_m)
        frac = reg.fractions()
        if frac["valid"] < 0.9:
            self._warn(f"the model is valid over only {100 * frac['valid']:.0f} % of the frame ({reg.describe()}): "
                       "outside it projections are extrapolated, and programs that undistort whole frames "
                       "(OpenCV, COLMAP, Metashape) extrapolate there; see valid_region and the uncertainty map")
        for name, label in (("opencv", "OpenCV (camera.json opencv block, opencv.yaml)"), ("colmap", "COLMAP"),
                            ("metashape", "Metashape")):
            w = conversion_warning(label, self.conversion_errors[name], reg)
            if w:
                self._warn(w)
        if 0.05 < err <= CONVERSION_WARN_PX:
            self._warn(f"the OpenCV block (and opencv.yaml, cameras.txt) is an approximation of this {cam.NAME} "
                       f"camera: up to {err:.3g} px off inside the valid region")
        rms = ba.per_image_rms()
        vals = np.array([v for v in rms.values() if np.isfinite(v)])
        if len(vals) >= 5:
            med = float(np.median(vals))
            worse = [k for k, v in rms.items() if np.isfinite(v) and v > 3 * med]
            if worse:
                self._warn(f"{len(worse)} image(s) fit much worse than the rest (RMS > 3 x the median {med:.3g} px: "
                           f"{', '.join(worse[:6])}{' ...' if len(worse) > 6 else ''}): motion blur, rolling shutter "
                           "or a bent board? Their observations are kept (per_image_rms_px)")
        return self

    def rms_all_px(self) -> float:
        """RMS residual (px) over every usable observation, rejected ones included (OpenCV calibrateCamera's
        figure when it is given the same observations)."""
        r = self.ba.residuals
        total, count = 0.0, 0
        for a in range(0, len(r), 100_000):      # 100 000 rows at a time: no copy of the residuals
            n2 = np.sum(r[a:a + 100_000] ** 2, axis=1)
            ok = np.isfinite(n2)
            total += float(np.sum(n2[ok]))
            count += int(ok.sum())
        return float(np.sqrt(total / count)) if count else float("nan")

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
            "rms_all_px": self.rms_all_px(),
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
        if ba.board_warp_m is not None:
            w, sw = ba.board_warp_m, ba.board_warp_sigma_m
            out["board_warp"] = {"warp_m": w.tolist(), "sigma_m": sw.tolist(),
                                 "significant": bool(np.any(np.abs(w) > 3 * sw)),
                                 "definition": "bow along the board's two axes, m: each target moved along the "
                                               "board normal by w_x (1 - u^2) + w_y (1 - v^2), u, v in [-1, 1] "
                                               "across the targets (mrcal's calobject_warp)"}
        if self.uncertainty is not None:
            u = {"model": self.uncertainty.to_dict()}
            if self.opencv_uncertainty is not None:
                u["opencv"] = self.opencv_uncertainty.to_dict()
            else:
                u["opencv"] = "the same as the model's (the OpenCV block is an exact conversion)"
            if self.region is not None:
                uv = self.region.grid((41, 29))
                if len(uv):
                    s_in = self.uncertainty.at(uv, infinity=True)
                    u["valid_region_sigma_px_at_infinity"] = {"median": float(np.median(s_in)),
                                                              "max": float(np.max(s_in))}
            u["frame_max_sigma_px_at_infinity"] = float(np.nanmax(self.uncertainty.sigma_infinity))
            out["projection_uncertainty"] = u
        if self.comparison is not None:
            out["model_choice"] = self.comparison.to_dict()
        if self.board is not None:
            out["board"] = self.board.to_dict()
        if self.frames is not None:
            out["frames"] = {"summary": self.frames.summary(), "chosen": [c.label for c in self.frames.chosen],
                             "list": "frames.csv (every frame looked at, with sharpness, corners and why chosen)"}
        out["exports_max_error_px"] = dict(self.conversion_errors)
        return out

    def camera_json(self) -> dict:
        """The camera.json content (see docs/camera_calibration.md)."""
        return camera_json_dict(self.camera, self.camera.sigmas, self.stats(), region=self.region)


def _check_measurements(meas: Measurements, field: Points, image_size) -> None:
    known = set(field.ids.astype(str).tolist())
    ids = meas.id_labels.as_str()          # codes into the distinct ids: each id checked once
    occurs = ids.counts() > 0
    bad_id = np.array([str(k) not in known for k in ids.names.tolist()], bool) & occurs
    if bad_id.any():
        bad = bad_id[ids.codes]
        k = int(np.argmax(bad))
        line = None if meas.lines is None else int(meas.lines[k])
        n_bad = int(bad_id.sum())
        raise InputError(f"target id {str(ids.names[ids.codes[k]])!r} is not in the field file"
                         f"{f' {field.path}' if field.path else ''} ({n_bad} unknown id(s))", meas.path, line, "id")
    n_targets = int(occurs.sum())
    if n_targets < 4:
        raise InputError(f"only {n_targets} different target(s) measured: a calibration needs at least 4 (and many "
                         "more, over several photos)", meas.path, field="id")
    w, h = image_size
    for c, lim, name in ((0, w, "x"), (1, h, "y")):
        out = (meas.xy[:, c] < -0.5) | (meas.xy[:, c] > lim - 0.5)
        if out.any():
            k = int(np.argmax(out))
            line = None if meas.lines is None else int(meas.lines[k])
            raise InputError(f"{meas.xy[k, c]:g} px is outside the image ({w} x {h}); wrong --image-size?",
                             meas.path, line, name)


def _board_of(board: Board | str | Path | None) -> tuple[Board | None, Path | None]:
    """The board and the file it came from."""
    if board is None or isinstance(board, Board):
        return board, None
    return read_board(board), Path(board)


def _single_photo_folder(images) -> Path | None:
    """The folder when `images` names one folder holding only photos (the parallel plate detector's case)."""
    items = [images] if isinstance(images, (str, Path)) else list(images)
    if len(items) != 1 or not Path(items[0]).is_dir():
        return None
    d = Path(items[0])
    return None if any(p.suffix.lower() in VIDEO_SUFFIXES for p in d.iterdir() if p.is_file()) else d


def detect_targets(images, field_path: Path | None, pts: Points, board: Board | None, board_path: Path | None,
                   workers: int | None = None, progress: bool = False, max_frames: int = 100,
                   max_candidates: int = 400) -> tuple[Measurements, dict, FrameChoice | None]:
    """Targets in photos and videos: the rotating plate (field layout beside `field_path`) or a standard `board`;
    video frames chosen by sharpness and coverage (dgcal.calib.selfcal.frames). Returns the measurements, the
    detection report (with `image_size`) and the frame choice (None for a plain photo folder of the plate)."""
    folder = _single_photo_folder(images)
    if board is None and folder is not None:
        meas, rep = detect_folder(folder, field_path, workers=workers, progress=progress)
        return meas, rep, None
    keep = set(str(i) for i in pts.ids)
    if board is not None:
        detector = BoardDetector(board, keep)
        xy_all = board.corner_xyz()[:, :2]

        def board_xy(ids):
            return xy_all[np.asarray(ids).astype(int)]
        source_desc = board.describe()
    else:
        tf, keep_ids, layout = resolve_field(field_path)
        detector = CharucoFieldDetector(tf, keep_ids)
        t_ids, _, t_xyz = tf.targets()
        where = {str(k): i for i, k in enumerate(t_ids)}

        def board_xy(ids):
            return t_xyz[[where[str(k)] for k in ids], :2]
        source_desc = f"rotating plate ({layout})"
    sources = expand_sources(images)
    cands, size = detect_sources(sources, detector.detect, max_candidates, progress)
    if size is None:
        raise InputError("the images differ in size; calibrate one camera (one image size) at a time",
                         sources[0].path)
    videos = [c for c in cands if c.frame is not None]
    for c in cands:
        if c.frame is None:
            c.status = "chosen" if len(c.detection.ids) else "no targets found"
    if videos:
        choose_frames(videos, size, board_xy, max_frames=max_frames)
    choice = FrameChoice(cands)
    chosen = choice.chosen
    if not any(len(c.detection.ids) for c in cands):
        names = ", ".join(dict.fromkeys(src.path.name for src in sources))
        msg = f"no targets of the {source_desc} found in any of the {len(cands)} images/frames of {names}"
        if board is not None:
            msg += ("; check type, columns, rows, dictionary and first_id" if board.type != "chessboard"
                    else "; check columns and rows (squares, not inner corners) and that the whole board is in view")
            flipped = _polarity_hint(sources, detector, max_candidates)
            if flipped:
                msg += (f"; with inverted = {str(not board.inverted).lower()} {flipped} corners are found: set "
                        "inverted in the board file")
        raise InputError(msg, board_path if board is not None else sources[0].path,
                         field="inverted" if board is not None and "inverted =" in msg else None)
    if not chosen:
        raise InputError(f"no image or frame has enough targets ({choice.summary()})", sources[0].path)
    image = np.concatenate([np.full(len(c.detection.ids), c.label, dtype=object) for c in chosen])
    ids = np.concatenate([c.detection.ids for c in chosen]).astype(object)
    xy = np.concatenate([c.detection.xy for c in chosen]).reshape(-1, 2)
    sig = np.concatenate([c.detection.sigma for c in chosen]).reshape(-1, 2)
    report = {"n_images": len(chosen), "n_points": int(len(ids)), "layout": source_desc,
              "image_size": list(size), "frames": choice.summary(),
              "images": {c.label: c.detection.stats for c in chosen}}
    return Measurements(image, ids, xy, sig), report, choice


def _polarity_hint(sources: list, detector: BoardDetector, max_candidates: int, n: int = 12) -> int:
    """Corners found in a few frames with the print polarity the other way round (0: none)."""
    found = 0
    for src in sources:
        frames = [read_gray(src.path)] if src.kind == "image" else \
            [g for k, (_, _, g) in zip(range(n), video_frames(src.path, max(1, max_candidates // 8)))]
        for g in frames:
            found += detector.detect_inverted_polarity(g)
        if found:
            break
    return found


def calibrate_camera(field: Points | str | Path | None = None, measurements: Measurements | str | Path | None = None,
                     image_size: tuple[int, int] | None = None, images=None,
                     model: str = "fraser7", fixed=(), refine_targets: str = "none", reject_k: float = 4.0,
                     progress: bool = True, workers: int | None = None,
                     initial: CameraModel | str | Path | None = None, board: Board | str | Path | None = None,
                     max_frames: int = 100, uncertainty_range_m: float | None = None) -> CameraCalibration:
    """Calibrate one camera from a target field (m) and image measurements (px) or photos / videos.

    With `images` (a folder, photo or video files, or a list of them) the targets are detected and the image size
    is read from them: the rotating plate of the field's layout, or a standard `board` (a Board or its TOML file;
    then `field` may be omitted: the board's own corners are the field). Measurement sigmas `sx,sy` act as
    relative weights; sigma0 scales every reported sigma. `model`: fraser7, opencv8, fisheye, or auto (all three
    compared, dgcal.calib.selfcal.model_choice). `initial`: a camera (or camera file) to start from.
    `uncertainty_range_m`: range of the projection-uncertainty map (default: the median target distance).
    """
    if model != "auto":
        model_class(model)
    brd, board_path = _board_of(board)
    field_path = Path(field) if isinstance(field, (str, Path)) else (None if field is None else field.path)
    if field is None:
        if brd is None:
            raise InputError("give a target field (--field) or a board (--board)")
        pts = brd.points()
    else:
        pts = read_points(field) if isinstance(field, (str, Path)) else field
        if brd is None and images is not None and field_path is not None:
            brd = load_board_layout(field_path)
    detection_report = None
    frames = None
    if images is not None:
        if brd is None and field_path is None:
            raise InputError("detection needs the field file (its layout sits beside it)")
        meas, detection_report, frames = detect_targets(images, field_path, pts, brd, board_path, workers, progress,
                                                        max_frames)
        size = detection_report.get("image_size")
        if size is None:
            raise InputError("the images differ in size; calibrate one camera (one image size) at a time", images)
        if image_size is not None and tuple(image_size) != tuple(size):
            raise InputError(f"--image-size {image_size[0]} {image_size[1]} differs from the images' "
                             f"{size[0]} x {size[1]}", images if isinstance(images, (str, Path)) else None)
        image_size = tuple(int(v) for v in size)
        if len(meas) == 0:
            raise InputError("no targets detected in any image", images if isinstance(images, (str, Path)) else None)
    else:
        if measurements is None:
            raise InputError("give either image measurements or images / videos")
        meas = read_measurements(measurements) if isinstance(measurements, (str, Path)) else measurements
        if image_size is None:
            raise InputError("the image size (width, height in px) is needed with measurements", meas.path)
    if len(image_size) != 2:
        raise InputError(f"the image size is (width, height), not {image_size!r}", field="image_size")
    image_size = validate.image_size(image_size[0], image_size[1], field="image_size")
    _check_measurements(meas, pts, image_size)
    if isinstance(initial, (str, Path)):
        initial = load_camera(initial)
    if initial is not None and tuple(initial.image_size) != image_size:
        raise InputError(f"the initial camera is for {initial.image_size[0]} x {initial.image_size[1]} px images, "
                         f"these are {image_size[0]} x {image_size[1]}", field="initial")
    field_sigma = pts.sigma if np.isfinite(pts.sigma).any() else None
    progress_fn = None
    if progress:
        progress_fn = partial(track, text="initial poses of the images")
    stated = meas.stated_sigma           # None when the file gives none (no NaN array is built for it)
    sigmas_given = stated is not None and bool(np.isfinite(stated).all())
    kw = dict(meas_sigma=stated, field_sigma=field_sigma, refine_targets=refine_targets, reject_k=reject_k,
              initial=initial, progress=progress_fn)
    comparison = None
    src_path = images if isinstance(images, (str, Path)) else (None if images is not None else meas.path)
    try:
        if model == "auto":
            comparison = compare_models(pts.ids, pts.xyz, meas.image_labels, meas.id_labels, meas.xy, image_size,
                                        fixed=tuple(fixed), sigmas_given=sigmas_given, **kw)
            fit = comparison.fits[comparison.chosen]
            ba, dg, region = fit.ba, fit.diagnostics, fit.region
        else:
            ba = adjust(pts.ids, pts.xyz, meas.image_labels, meas.id_labels, meas.xy, image_size, model,
                        fixed=tuple(fixed), **kw)
            dg, region = diagnose(ba, sigmas_given=sigmas_given), None
    except InputError as exc:
        if exc.path is None and exc.field is None:
            raise InputError(str(exc), src_path) from None
        raise
    cal = CameraCalibration(ba=ba, diagnostics=dg, field=pts, measurements=meas, detected=images is not None,
                            detection_report=detection_report, region=region, comparison=comparison, frames=frames,
                            board=brd)
    for r in (comparison.reasons if comparison is not None else []):
        if "do not trust" in r:
            cal._warn(f"model choice: {r}")
    return cal.finish(uncertainty_range_m)


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
                "poses": "poses.csv", "measurements": "measurements.csv", "field_refined": "field_refined.csv",
                "frames": "frames.csv"}


def write_camera_outputs(cal: CameraCalibration, out_dir: str | Path,
                         names: dict[str, str] | None = None) -> dict[str, Path]:
    """Write camera.json, opencv.yaml, cameras.txt (COLMAP), metashape.xml (each converted inside the valid region,
    which they carry as a comment, with a warning when off by more than 1 px), poses.csv, measurements.csv (when
    detected), frames.csv (when frames were chosen from videos) and field_refined.csv (when targets were refined)
    into `out_dir`, named by role in `names` (default `CAMERA_FILES`; `dgcal camera` passes its declared OUTPUTS);
    returns the paths by role."""
    out = Path(out_dir)
    path = {role: out / name for role, name in {**CAMERA_FILES, **(names or {})}.items()}
    paths = {}
    d = cal.camera_json()
    with atomic_write(path["camera"]) as fh:
        json.dump(d, fh, indent=2, allow_nan=False)
        fh.write("\n")
    write_opencv_yaml(path["opencv"], cal.camera, cal.region)
    write_colmap_cameras_txt(path["colmap"], cal.camera, region=cal.region)
    write_metashape_xml(path["metashape"], cal.camera, cal.region)
    write_poses(path["poses"], cal.ba)
    paths.update({k: path[k] for k in ("camera", "opencv", "colmap", "metashape", "poses")})
    if cal.detected:
        write_measurements(path["measurements"], cal.measurements)
        paths["measurements"] = path["measurements"]
    if cal.frames is not None:
        write_table(path["frames"], ["label", "source", "frame", "time_s", "corners", "sharpness", "status"],
                    cal.frames.rows(), fmt="%.6g")
        paths["frames"] = path["frames"]
    if cal.ba.refine_targets != "none":
        # held (datum) and unobserved coordinates have no sigma: NaN, which read_points accepts as "not given"
        sig = np.where(cal.ba.points_free, cal.ba.points_sigma, np.nan)
        refined = Points(cal.field.ids, cal.ba.points_xyz, sig, cal.field.role)
        write_points(path["field_refined"], refined)
        paths["field_refined"] = path["field_refined"]
    return paths


@dataclass
class CameraOptions:
    """Inputs and settings of `dgcal camera`: the target field or a board, measurements (with the image size) or
    photos / videos, the model and what to hold or refine (see `calibrate_camera`)."""

    field: Path | None = None                # target field CSV id,x,y,z[,sx,sy,sz] (m); or
    board: Path | None = None                # a standard board's TOML description
    measurements: Path | None = None         # image,id,x,y[,sx,sy] (px); or
    images: Path | list | None = None        # folders of photos, photo or video files (targets detected)
    image_size: tuple[int, int] | None = None  # (width, height) px; required with measurements
    model: str = "fraser7"                   # fraser7 | opencv8 | fisheye | auto
    fixed: tuple[str, ...] = ()              # parameters held at their initial values
    refine_targets: str = "none"             # none | free | weighted | warp
    reject_k: float = 4.0                    # reject beyond k robust sigmas (0: keep every observation)
    workers: int | None = None               # detection processes
    initial: Path | None = None              # camera file to start from
    progress: bool = False                   # progress bars (detection)
    max_frames: int = 100                    # frames chosen from videos at most
    uncertainty_range_m: float | None = None  # range of the projection-uncertainty map (m; default median distance)


def calibrate_camera_files(opts: CameraOptions) -> CameraCalibration:
    """`dgcal camera`: `calibrate_camera` with the inputs and settings of `opts`."""
    if opts.measurements is not None and opts.image_size is None:
        raise InputError("--image-size W H is required with --measurements", opts.measurements)
    if opts.field is None and opts.board is None:
        raise InputError("give --field FIELD.csv or --board BOARD.toml")
    return calibrate_camera(opts.field, measurements=opts.measurements, images=opts.images,
                            image_size=opts.image_size, model=opts.model, fixed=opts.fixed,
                            refine_targets=opts.refine_targets, reject_k=opts.reject_k, progress=opts.progress,
                            workers=opts.workers, initial=opts.initial, board=opts.board,
                            max_frames=opts.max_frames, uncertainty_range_m=opts.uncertainty_range_m)
