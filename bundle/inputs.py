"""The inputs of an aerial triangulation from files (`dgcal triangulate`): camera, ground points, image
measurements merged from several files, ArUco GCP targets detected in the images, SIFT tie points on
spatial or sequential image pairs; then `triangulate_files` runs dgcal.bundle.triangulation.triangulate.

Ground points: dgcal CSV, MicMac XML or ODM gcp_list.txt; measurements: dgcal CSV, ODM gcp_list.txt or
MicMac XML (pixels, OpenCV convention). Measured ids absent from the ground points are tie points.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from dgcal.bundle.gcp_targets import detect_gcp_targets
from dgcal.bundle.tiepoints import extract_tie_points, sequential_pairs, spatial_pairs
from dgcal.bundle.triangulation import TriangulationOptions, TriangulationResult, triangulate
from dgcal.calib.camera.files import load_camera
from dgcal.calib.camera.models import CameraModel
from dgcal.fields.crs import parse_crs
from dgcal.bundle.triangulation import centres_in_block, no_datum_reason
from dgcal.fields.errors import InputError
from dgcal.fields.io.centres import read_centres_with_flights
from dgcal.fields.io.dji_images import is_jpeg, read_any_centres
from dgcal.fields.io.image_folders import list_image_names
from dgcal.fields.io.formats import EOP, Measurements, Points, read_eop
from dgcal.fields.io.gcp_files import read_any_measurements, read_any_points

LOCAL_CRS_NAMES = ("local", "none")  # --crs values meaning a local Cartesian frame (no map projection)


@dataclass
class TriangulateOptions:
    """Inputs and settings of `dgcal triangulate` (paths; pixels, metres). `crs` "local" treats coordinates as
    a local Cartesian frame."""

    camera: Path
    crs: str
    gcp: Path | None = None
    images: Path | None = None                   # image folder: SIFT tie points and the image list
    measurements: tuple[Path, ...] = ()          # merged; a point measured twice in one image is an error
    pixel_size_mm: float | None = None           # the sensor's pixel pitch: BINGO files hold sensor millimetres
    image_size: tuple[int, int] | None = None    # (width, height) px, checked against the camera
    sigma_px: float = 0.5                        # measurement sigma where a file gives none
    tie_sigma_px: float | None = None            # sigma of SIFT tie measurements
    gcp_sigma_m: tuple[float, float, float] | None = None  # overrides the ground point file's sigmas
    fixed_gcps: bool = False
    refine: tuple[str, ...] = ()                 # camera parameters to refine, or ("all",)
    geoid: str | None = None                     # undulation (m) or PROJ vertical grid
    approx: Path | None = None                   # approximate EOP CSV (initial values, spatial pairs)
    gnss: Path | None = None                     # EOP CSV whose X,Y,Z (sX..sZ) are camera-centre priors
    antenna_offset_cam: tuple[float, float, float] | None = None   # m, camera axes (see TriangulationOptions)
    flight_shift: bool = False                   # a shift of the centres per flight (`flight` column, else one)
    max_features: int = 4000                     # SIFT features per image
    targets: str | None = None                   # ArUco dictionary of GCP targets to detect in the images
    reject_blunders: bool = True
    formats: tuple[str, ...] = ("colmap", "pix4d", "metashape", "odm")  # exports
    approx_eop: EOP | None = None                # approximate EOPs already in memory (e.g. from a POS)
    check_as_tie: bool | None = None             # None: on for measurement-only input
    accept_poor: bool = False                    # return (and write) an untrusted result, with its problems
    use_mapper: bool = True                      # pycolmap's incremental mapper for the initial orientation
    progress: Callable[[str], None] | None = None   # told what each long stage is doing

    @property
    def local(self) -> bool:
        """True when `crs` names a local Cartesian frame."""
        return self.crs.strip().lower() in LOCAL_CRS_NAMES


@dataclass
class TriangulationInputs:
    """Everything `triangulate` is given: camera, ground points, all measurements (control, check, tie) and
    the optional approximate EOPs, centre priors and image list; warnings found while gathering them."""

    camera: CameraModel
    points: Points
    measurements: Measurements | None
    approx: EOP | None = None
    centre_priors: EOP | None = None
    centre_flights: np.ndarray | None = None            # flight label per row of the centres (their `flight` column)
    all_images: list[str] | None = None
    warnings: list[str] = field(default_factory=list)
    tie_stats: dict = field(default_factory=dict)       # SIFT features, matches, tracks and times (with images)


@dataclass
class TriangulationRun:
    """A triangulation from files: its result, the inputs it used, the CRS (None: local) and the exports
    to write (COLMAP and ODM need a map CRS)."""

    result: TriangulationResult
    inputs: TriangulationInputs
    crs: str | None
    formats: list[str]


def merge_measurements(a: Measurements, b: Measurements) -> Measurements:
    """Two measurement sets as one; a point measured twice in one image is an error naming the second file."""
    seen = set(zip(a.image.astype(str), a.id.astype(str)))
    for i, key in enumerate(zip(b.image.astype(str), b.id.astype(str))):
        if key in seen:
            raise InputError(f"point {key[1]!r} in image {key[0]!r} is also measured in {a.path}", b.path,
                             None if b.lines is None else int(b.lines[i]), "id")
    lines = None if a.lines is None or b.lines is None else np.concatenate([a.lines, b.lines])
    return Measurements(np.concatenate([a.image, b.image]), np.concatenate([a.id, b.id]),
                        np.concatenate([a.xy, b.xy]), np.concatenate([a.sigma, b.sigma]), lines, a.path)


def append_measurements(meas: Measurements | None, more: Measurements) -> Measurements:
    """`meas` followed by `more` (detected or tie measurements, without file lines), keeping `meas`'s file."""
    if meas is None:
        return more
    return Measurements(np.concatenate([meas.image, more.image]), np.concatenate([meas.id, more.id]),
                        np.concatenate([meas.xy, more.xy]), np.concatenate([meas.sigma, more.sigma]),
                        None if meas.lines is None else np.concatenate([meas.lines, np.zeros(len(more), int)]),
                        meas.path)


def gather_measurements(opts: TriangulateOptions, camera: CameraModel | None = None,
                        image_names: list[str] | None = None) -> tuple[Points, Measurements | None]:
    """Ground points and the merged measurements of every --measurements file; every file's CRS must be
    `opts.crs`; without --gcp the ground points of an ODM gcp_list.txt are used. `camera` gives a BINGO file's
    image size, `image_names` the file names that Pix4D's and Metashape's labels (without extension) stand for."""
    local = opts.local
    if not local:
        parse_crs(opts.crs)
    points, gcp_crs = read_any_points(opts.gcp) if opts.gcp else (None, None)
    meas, meas_points, crs_sources = None, None, [(opts.gcp, gcp_crs)]
    read = []
    for path in opts.measurements:
        m, c, p = read_any_measurements(path, None if camera is None else tuple(camera.image_size),
                                        opts.pixel_size_mm, image_names)
        crs_sources.append((path, c))
        read.append(m)
        meas_points = meas_points if p is None else p
    if image_names is None and len(read) > 1:   # labels without extension (Pix4D, Metashape) -> the others' names
        read = [_names_from_others(m, [o for o in read if o is not m]) for m in read]
    for m in read:
        meas = m if meas is None else merge_measurements(meas, m)
    for src, c in crs_sources:
        if c is not None and not local and parse_crs(c) != parse_crs(opts.crs):
            raise InputError(f"the file's CRS {c!r} differs from --crs {opts.crs!r}", src, 1, "--crs")
    if points is None:
        if meas_points is None:
            raise InputError("no ground points: give --gcp (or an ODM gcp_list.txt as --measurements)", field="gcp")
        points = meas_points
    if opts.gcp_sigma_m:
        points.sigma[:] = np.asarray(opts.gcp_sigma_m, float)
    return points, meas


def check_image_size(folder: Path, name: str, camera: CameraModel) -> None:
    """InputError naming the image when `folder/name` cannot be read or differs from the camera's size (px)."""
    path = Path(folder) / name
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
    if img is None:
        raise InputError("cannot read image", path, field="images")
    if (img.shape[1], img.shape[0]) != tuple(camera.image_size):
        raise InputError(f"image is {img.shape[1]}x{img.shape[0]} but the camera is "
                         f"{camera.image_size[0]}x{camera.image_size[1]}", path, field="images")


def image_pairs(names: list[str], camera: CameraModel, points: Points, approx: EOP | None) -> list[tuple[str, str]]:
    """Image pairs to match: by footprint overlap where approximate EOPs give the centres (m), sequential
    (by file name) for the rest."""
    if approx is None:
        return sequential_pairs(names, overlap=len(names) if len(names) <= 30 else 10)
    a_idx = {str(k): i for i, k in enumerate(approx.image)}
    have = [n for n in names if n in a_idx]
    xyz = np.array([approx.xyz[a_idx[n]] for n in have])
    h = np.median(np.abs(xyz[:, 2] - np.median(points.xyz[:, 2])))
    pairs = spatial_pairs(have, xyz, footprint_m=h * camera.image_size[0] / camera.pinhole_K()[0, 0])
    return pairs + sequential_pairs([n for n in names if n not in a_idx])


def add_gcp_targets(meas: Measurements | None, folder: Path, names: list[str], dictionary: str,
                    points: Points, sigma_px: float) -> tuple[Measurements, list[str]]:
    """`meas` plus the ArUco GCP targets detected in the images (marker id = point id); ids not among the
    ground points are ignored, measurements already given take precedence. Returns them and the warnings."""
    warnings = []
    det = detect_gcp_targets(folder, names, dictionary, sigma_px=sigma_px)
    known = set(points.ids.astype(str))
    unknown = sorted(set(det.id) - known)
    if unknown:
        warnings.append(f"{len(unknown)} detected marker id(s) not in the ground points, ignored: "
                        + ", ".join(unknown[:10]))
    keep = np.array([i in known for i in det.id.astype(str)], bool)
    if meas is not None:
        have = set(zip(meas.image.astype(str), meas.id.astype(str)))
        keep &= np.array([(a, b) not in have for a, b in zip(det.image.astype(str), det.id.astype(str))], bool)
    det = det.subset(keep)
    warnings.append(f"{len(det)} GCP target measurement(s) detected automatically ({dictionary})")
    return append_measurements(meas, det), warnings


def _names_from_others(m: Measurements, others: list[Measurements]) -> Measurements:
    """`m` with image labels that drop the extension (`IMG_0001` for `IMG_0001.JPG`, as Pix4D and Metashape write
    them) named as the other files name the images: when all of the others' names share one extension, every
    label of `m` without one gets it; else each label that one other name has as its stem is renamed."""
    names = {str(n) for o in others for n in o.image.tolist()}
    labels = {str(x) for x in m.image.tolist()}
    suffixes = {Path(n).suffix for n in names}
    stems = {Path(n).stem: n for n in names}
    if not labels & stems.keys() - names:
        return m
    if len(suffixes) == 1 and next(iter(suffixes)) and not any(Path(lab).suffix for lab in labels):
        rename = {lab: lab + next(iter(suffixes)) for lab in labels}
    else:
        by_stem: dict[str, set[str]] = {}
        for n in names:
            by_stem.setdefault(Path(n).stem, set()).add(n)
        rename = {lab: next(iter(by_stem[lab])) for lab in labels
                  if lab not in names and len(by_stem.get(lab, ())) == 1}
    image = np.array([rename.get(str(x), str(x)) for x in m.image.tolist()], dtype=object)
    return Measurements(image, m.id, m.xy, m.stated_sigma, m.lines, m.path)


def _known_image_names(folder_names: list[str] | None, *eops: EOP | None) -> list[str] | None:
    """The images' file names where the inputs give them (the image folder's, else the image column of the centres
    or the approximate EOPs): what other programs' extension-less labels are matched to."""
    if folder_names is not None:
        return folder_names
    return next(([str(n) for n in e.image] for e in eops if e is not None and len(e)), None)


def _read_gnss_centres(opts: TriangulateOptions) -> tuple[EOP | None, np.ndarray | None]:
    """`--gnss`: a centres CSV (with its optional `flight` column), or DJI images (a folder or one JPEG) whose
    XMP/EXIF positions are converted into the map CRS."""
    if not opts.gnss:
        return None, None
    p = Path(opts.gnss)
    if p.is_dir() or is_jpeg(p):
        return read_any_centres(p, opts.crs), None
    return read_centres_with_flights(p)


def gather_inputs(opts: TriangulateOptions) -> TriangulationInputs:
    """Read and assemble every input of the triangulation: camera, ground points, merged measurements and,
    with an image folder, the image list, detected GCP targets and SIFT tie points (see the module doc)."""
    if not opts.images and not opts.measurements:
        raise InputError("give --images DIR or --measurements MEAS.csv (or both)", field="measurements")
    camera = load_camera(opts.camera)
    approx = read_eop(opts.approx) if opts.approx else opts.approx_eop
    centres, flights = _read_gnss_centres(opts)
    names = list_image_names(opts.images) if opts.images else None
    points, meas = gather_measurements(opts, camera, _known_image_names(names, centres, approx))
    if opts.image_size and tuple(opts.image_size) != tuple(camera.image_size):
        raise InputError(f"--image-size {tuple(opts.image_size)} differs from the camera's {tuple(camera.image_size)}",
                         field="image_size")
    inp = TriangulationInputs(camera, points, meas, approx=approx, centre_priors=centres, centre_flights=flights)
    if opts.images:
        check_image_size(opts.images, names[0], camera)
        inp.all_images = names
        if meas is not None:
            missing = sorted(set(meas.images()) - set(names))
            if missing:
                inp.warnings.append(f"{len(missing)} measured image(s) not in {opts.images} (e.g. {missing[0]}): "
                                    "their measurements are used without tie points")
        # spatial pairs from the approximate EOPs, else from the camera centres (strips side by side share images
        # that the sequential pairs of file names never pair)
        pairs = image_pairs(names, camera, points, inp.approx if inp.approx is not None else inp.centre_priors)
        if opts.targets:
            meas, w = add_gcp_targets(meas, opts.images, names, opts.targets, points, opts.sigma_px)
            inp.warnings += w
        refuse_without_datum(points, meas, inp.centre_priors, names)   # before the expensive SIFT stage
        _say(opts, f"tie points: SIFT features and matching of {len(pairs)} pairs of {len(names)} images")
        tie = extract_tie_points(opts.images, names, pairs, max_features=opts.max_features,
                                 camera_K=camera.pinhole_K(), stats=inp.tie_stats)
        _say(opts, f"tie points: {inp.tie_stats['n_features']} features, {inp.tie_stats['n_matches']} verified "
                   f"matches, {inp.tie_stats['n_tracks']} tracks in {inp.tie_stats['seconds_extract_match']:.1f} s")
        if opts.tie_sigma_px:
            tie.sigma[:] = opts.tie_sigma_px
        inp.measurements = append_measurements(meas, tie)
    return inp


def refuse_without_datum(points: Points, meas: Measurements | None, centres: EOP | None,
                         names: list[str] | None = None) -> None:
    """InputError unless a control point is measured or camera centres name a measured (or listed) image: without
    either the block has no datum, and nothing later (SIFT, the adjustment) can give it one."""
    role = {str(k): str(r) for k, r in zip(points.ids, points.role)}
    if meas is not None and any(role.get(i) == "control" for i in set(meas.id.astype(str))):
        return
    if centres is not None and names:
        if set(centres.image.astype(str)[np.isfinite(centres.xyz).all(1)]) & set(names):
            return
    if centres is not None and meas is not None and len(centres_in_block(centres, meas)):
        return
    raise InputError(no_datum_reason(centres), None if meas is None else meas.path, field="gcp")


def _say(opts: TriangulateOptions, text: str) -> None:
    if opts.progress is not None:
        opts.progress(text)


def refine_parameters(camera: CameraModel, refine: tuple[str, ...]) -> tuple[str, ...]:
    """The camera parameters to refine in flight: `refine` checked against the model, ("all",) for all."""
    names = tuple(camera.PARAMS) if tuple(refine) == ("all",) else tuple(p for p in refine if p)
    bad = [p for p in names if p not in camera.PARAMS]
    if bad:
        raise InputError(f"unknown camera parameter {bad[0]!r} ({camera.NAME} has {', '.join(camera.PARAMS)})",
                         field="refine")
    return names


def triangulate_files(opts: TriangulateOptions) -> TriangulationRun:
    """`dgcal triangulate`: gather the inputs (`gather_inputs`), run the triangulation (EOPs in the map CRS
    with covariance) and choose the exports; the gathering warnings come first in the result's warnings."""
    inp = gather_inputs(opts)
    sol = TriangulationOptions(sigma_px=opts.sigma_px, tie_sigma_px=opts.tie_sigma_px, fixed_gcps=opts.fixed_gcps,
                               refine=refine_parameters(inp.camera, opts.refine), geoid=opts.geoid,
                               reject_blunders=opts.reject_blunders, check_as_tie=opts.check_as_tie,
                               accept_poor=opts.accept_poor, use_mapper=opts.use_mapper,
                               antenna_offset_cam=opts.antenna_offset_cam, flight_shift=opts.flight_shift)
    crs = None if opts.local else opts.crs
    _say(opts, f"adjustment: initial orientation and bundle adjustment of {len(inp.measurements)} measurements")
    res = triangulate(inp.camera, inp.points, inp.measurements, crs, sol, image_size=opts.image_size,
                      approx=inp.approx, centre_priors=inp.centre_priors, all_images=inp.all_images,
                      centre_flights=inp.centre_flights)
    _say(opts, f"adjustment: {res.summary['initial_orientation']}, {res.summary['rounds']['adjustments']} "
               f"adjustment(s) in {sum(res.summary['timings_s'].get(k, 0) for k in ('initialised', 'adjusted')):.1f} s")
    res.warnings[:0] = inp.warnings
    res.summary["warnings"] = res.warnings
    if inp.tie_stats:
        res.summary["tie_points_from_images"] = inp.tie_stats
    formats = [f for f in opts.formats if f]
    if opts.local and formats:
        kept = [f for f in formats if f in ("pix4d", "metashape")]
        if len(kept) < len(formats):
            res.warnings.append("COLMAP and ODM exports need a map CRS: skipped for --crs local")
        formats = kept
    return TriangulationRun(res, inp, crs, formats)
