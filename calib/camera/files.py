"""Camera model files: dgcal's camera.json, OpenCV FileStorage YAML, COLMAP cameras.txt, Metashape
calibration XML (read and write) and MicMac V1 / MMVII calibration XML (read).

`load_camera` recognises the format by the file's content, not its name. Writers are atomic
(temporary file + rename). Parameter conventions are converted by dgcal.calib.camera.conversions.
"""
from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np
import yaml

from dgcal.calib.camera import conversions as conv
from dgcal.calib.camera.models import MODELS, CameraModel, Fisheye, model_class
from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.atomic import atomic_write
from dgcal.fields.io.text_files import read_text


# ---------------------------------------------------------------------------------------------
# camera.json
# ---------------------------------------------------------------------------------------------
CONVERSION_WARN_PX = 1.0   # a converted block off by more than this (inside the valid region) carries a warning


def conversion_warning(target: str, err: float, region=None) -> str | None:
    """The warning a converted camera (OpenCV, COLMAP, Metashape) carries when it is more than CONVERSION_WARN_PX
    off the calibrated model inside the valid region (or the frame without a region); None when it is not."""
    if not err > CONVERSION_WARN_PX:
        return None
    where = "inside the valid region" if region is not None else "over the frame"
    return (f"the {target} camera is only an approximation of the calibrated model: up to {err:.3g} px off {where} "
            f"(more than {CONVERSION_WARN_PX:g} px); use camera.json or the model's own form where precision matters")


def region_comment(region) -> str | None:
    """One line on the valid region for an export's comment (None when the whole frame is valid)."""
    if region is None or region.whole_frame:
        return None
    return (f"valid region: {region.describe()}; outside it (see valid_region in camera.json) the model "
            "extrapolates: do not trust projections or undistortion there")


def camera_json_dict(model: CameraModel, sigmas=None, stats: dict | None = None, region=None) -> dict:
    """The camera.json content: model, image_size, parameters and sigmas by name (px or unitless), the OpenCV
    block with its conversion error (px; fitted and measured inside the valid `region` when given, with the
    region itself and the error over the whole frame), then everything in `stats` (rms_px, ...)."""
    if sigmas is None:
        sigmas = model.sigmas
    out = {"model": model.NAME, "image_size": [int(model.image_size[0]), int(model.image_size[1])]}
    out["parameters"] = model.as_dict()
    if sigmas is not None:
        s = np.asarray(sigmas, float)
        if s.shape != (len(model.PARAMS),):
            raise ValueError(f"sigmas must have {len(model.PARAMS)} entries, got {s.shape}")
        out["sigmas"] = {k: _num(v) for k, v in zip(model.PARAMS, s)}
    ocv, err = conv.to_opencv(model, region)
    out["opencv"] = {k: float(v) for k, v in ocv.items()}
    out["opencv_max_error_px"] = float(err)
    if region is not None:
        if err > 0:
            back = conv.from_opencv(ocv, model.image_size, "opencv8" if "k4" in ocv else None)
            out["opencv_max_error_frame_px"] = _num(conv.max_projection_difference(model, back))
        warn = conversion_warning("OpenCV", err, region)
        if warn:
            out["opencv_warning"] = warn
        out["valid_region"] = region.to_dict()
    if isinstance(model, Fisheye):
        out["opencv_fisheye"] = {k: float(v) for k, v in model.as_dict().items()}
    for k, v in (stats or {}).items():
        out[k] = _jsonable(v)
    return out


def _num(v):
    v = float(v)
    return v if math.isfinite(v) else None


def _jsonable(v):
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return _num(v)
    return v


def write_camera_json(path: str | Path, model: CameraModel, sigmas=None, stats: dict | None = None) -> dict:
    """Write camera.json atomically; returns the written dict."""
    d = camera_json_dict(model, sigmas, stats)
    with atomic_write(path) as fh:
        json.dump(d, fh, indent=2)
        fh.write("\n")
    return d


def camera_from_json_dict(d: dict, path: str | Path | None = None) -> CameraModel:
    """A camera model (with sigmas, if any) from a camera.json dict; every value checked (image size, finite
    parameters, positive focal length) with an InputError naming the file and field."""
    for key in ("model", "image_size"):
        if key not in d:
            raise InputError("camera.json lacks this field", path, field=key)
    if not isinstance(d["model"], str) or d["model"] not in MODELS:
        raise InputError(f"unknown camera model {str(d['model'])[:40]!r} ({', '.join(MODELS)})", path, field="model")
    cls = model_class(d["model"])
    size = d["image_size"]
    if not (isinstance(size, list) and len(size) == 2):
        raise InputError("image_size must be [width, height]", path, field="image_size")
    size = validate.image_size(size[0], size[1], path, field="image_size")
    params = d.get("parameters")
    if not isinstance(params, dict):
        # camera.json written by others may hold only the opencv block
        ocv = d.get("opencv")
        if isinstance(ocv, dict):
            missing = [k for k in ("fx", "fy", "cx", "cy") if k not in ocv]
            if missing:
                raise InputError(f"the opencv block lacks {', '.join(missing)}", path, field=f"opencv.{missing[0]}")
            vals = {k: _param(v, path, None, f"opencv.{k}") for k, v in ocv.items() if k in conv.OPENCV8_KEYS}
            for k in ("fx", "fy"):
                _focal(vals[k], path, None, f"opencv.{k}")
            try:
                cam = conv.from_opencv(vals, size, d["model"])
            except InputError as e:
                raise _relocated(e, path, None, "opencv.") from None
            return check_camera(cam, path)
        raise InputError("camera.json lacks the parameters", path, field="parameters")
    missing = [k for k in cls.PARAMS if k not in params]
    if missing:
        raise InputError(f"missing parameter {missing[0]!r} of {cls.NAME}", path, field=f"parameters.{missing[0]}")
    cam = cls(size, [_param(params[k], path, None, f"parameters.{k}") for k in cls.PARAMS])
    check_camera(cam, path)
    sig = d.get("sigmas")
    if isinstance(sig, dict) and all(k in sig for k in cls.PARAMS):
        cam.sigmas = np.array([np.nan if sig[k] is None else validate.non_negative(sig[k], path, None,
                                                                                   f"sigmas.{k}", validate.MAX_PIXEL)
                               for k in cls.PARAMS])
    return cam


def _relocated(e: InputError, path, line=None, prefix: str = "") -> InputError:
    """The InputError `e` of a conversion (which knows no file) again, naming the file and line."""
    return InputError(e.reason, path, line if line is not None else e.line,
                      None if e.field is None else prefix + e.field)


MAX_CAMERA_PARAM = 1e7   # |any camera parameter| (px or unitless): larger is a broken file
MAX_FOCAL_PX = 1e7       # px


def _param(v, path, line, field) -> float:
    return validate.in_range(v, -MAX_CAMERA_PARAM, MAX_CAMERA_PARAM, path, line, field)


def _focal(v, path, line, field) -> float:
    """A focal length: finite, positive, below MAX_FOCAL_PX (a negative one would turn every kappa by 180 deg)."""
    v = validate.finite(v, path, line, field)
    if not v > 0:
        raise InputError(f"the focal length must be positive, got {v:.6g}", path, line, field)
    if v > MAX_FOCAL_PX:
        raise InputError(f"implausible focal length {v:.6g} px (more than {MAX_FOCAL_PX:g})", path, line, field)
    return v


_FOCALS = {"fraser7": (("f", "f"), ("f + B1", "f+B1")), "opencv8": (("fx", "fx"), ("fy", "fy")),
           "fisheye": (("fx", "fx"), ("fy", "fy"))}


def check_camera(cam: CameraModel, path=None, line=None) -> CameraModel:
    """`cam` when its image size is plausible (1..100000 px), every parameter finite and its focal lengths positive;
    else an InputError naming the file and the parameter (`parameters.NAME`)."""
    validate.image_size(*cam.image_size, path, line, "image_size")
    for k, v in zip(cam.PARAMS, cam.params):
        _param(v, path, line, f"parameters.{k}")
    d = cam.as_dict()
    for expr, name in _FOCALS.get(cam.NAME, ()):
        val = d["f"] + d["B1"] if expr == "f + B1" else d[expr]
        _focal(val, path, line, f"parameters.{name}")
    return cam


# ---------------------------------------------------------------------------------------------
# OpenCV FileStorage YAML
# ---------------------------------------------------------------------------------------------
def opencv_yaml_string(model: CameraModel, region=None) -> tuple[str, float]:
    """OpenCV FileStorage YAML (camera_matrix, distortion_coefficients, image_width, image_height) and
    the conversion's max error (px; fitted inside `region` when given). The valid region is carried as a comment
    and as the polygon `valid_region_px`; a conversion off by more than CONVERSION_WARN_PX carries a warning
    comment. A fisheye model also writes `fisheye_camera_matrix`, `fisheye_distortion_coefficients` (cv::fisheye)."""
    d, err = conv.to_opencv(model, region)
    K, dist = conv.opencv_K_dist(d)
    fs = cv2.FileStorage("camera.yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    for line in (conversion_warning("OpenCV", err, region), region_comment(region)):
        if line:
            fs.writeComment(("WARNING: " if "approximation" in line else "") + line)
    fs.write("image_width", int(model.image_size[0]))
    fs.write("image_height", int(model.image_size[1]))
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", dist.reshape(1, -1))
    fs.write("dgcal_model", model.NAME)
    fs.write("conversion_max_error_px", float(err))
    if isinstance(model, Fisheye):
        fs.write("fisheye_camera_matrix", model.pinhole_K())
        fs.write("fisheye_distortion_coefficients", model.params[4:].reshape(1, -1))
    if region is not None and not region.whole_frame:
        poly = region.observed if region.observed is not None else region.monotonic
        fs.write("valid_region_px", np.asarray(poly, float))
    return fs.releaseAndGetString(), err


def write_opencv_yaml(path: str | Path, model: CameraModel, region=None) -> float:
    """Write an OpenCV FileStorage YAML atomically; returns the conversion's max error (px)."""
    text, err = opencv_yaml_string(model, region)
    with atomic_write(path) as fh:
        fh.write(text)
    return err


class _OpenCVYamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader that also reads OpenCV's `!!opencv-matrix` (and any `!!opencv-*`) nodes as plain
    mappings (rows, cols, dt, data)."""


def _opencv_tagged(loader: yaml.SafeLoader, suffix: str, node):
    if isinstance(node, yaml.MappingNode):
        return loader.construct_mapping(node, deep=True)
    if isinstance(node, yaml.SequenceNode):
        return loader.construct_sequence(node, deep=True)
    return loader.construct_scalar(node)


_OpenCVYamlLoader.add_multi_constructor("tag:yaml.org,2002:opencv-", _opencv_tagged)
# OpenCV writes `%YAML:1.0` (older versions) or `%YAML 1.2`: PyYAML reads YAML 1.1 and knows no `%YAML:` form
_OPENCV_YAML_HEADER = re.compile(r"\A\ufeff?[ \t]*%YAML[: \t][ \t]*1\.[0-9]+[^\n]*")


def _load_yaml(text: str, path, loader=yaml.SafeLoader):
    """The document of a YAML text; syntax errors (and documents too deep to build) raise InputError with the
    line."""
    try:
        return yaml.load(text, Loader=loader)   # a SafeLoader (or _OpenCVYamlLoader, a SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        problem = " ".join(str(getattr(exc, "problem", None) or type(exc).__name__).split())[:120]
        raise InputError(f"invalid YAML ({problem})", path, None if mark is None else mark.line + 1) from None
    except RecursionError:
        raise InputError("invalid YAML (nested too deeply)", path) from None


def _opencv_yaml_dict(text: str, path) -> dict:
    d = _load_yaml(_OPENCV_YAML_HEADER.sub("%YAML 1.1", text, count=1), path, _OpenCVYamlLoader)
    if not isinstance(d, dict):
        raise InputError("an OpenCV FileStorage YAML must hold a mapping of names to values", path)
    return d


def _opencv_xml_dict(text: str, path) -> dict:
    """The top-level nodes of an OpenCV FileStorage XML (<opencv_storage>): matrices (type_id="opencv-matrix")
    as {rows, cols, dt, data}, other nodes as their text."""
    root = _xml_root(text, path)
    if root.tag != "opencv_storage":
        raise InputError(f"expected <opencv_storage>, found <{root.tag[:40]}>", path)
    out: dict = {}
    for el in root:
        if len(el):
            out[el.tag] = {c.tag: (c.text or "").strip() for c in el}
            if "data" in out[el.tag]:
                out[el.tag]["data"] = out[el.tag]["data"].split()
        else:
            out[el.tag] = (el.text or "").strip()
    return out


def _opencv_matrix(node, path, line, name: str) -> np.ndarray:
    """An OpenCV matrix node {rows, cols, dt, data} (or a plain list of numbers) as a (rows, cols) array of
    finite numbers."""
    if isinstance(node, dict):
        missing = [k for k in ("rows", "cols", "data") if k not in node]
        if missing:
            raise InputError(f"an OpenCV matrix needs rows, cols and data (missing {', '.join(missing)})", path,
                             line, name)
        rows = validate.integer(node["rows"], 1, 64, path, line, f"{name}.rows")
        cols = validate.integer(node["cols"], 1, 64, path, line, f"{name}.cols")
        data = node["data"]
    elif isinstance(node, list):
        rows, cols, data = None, None, node
    else:
        raise InputError("must be an OpenCV matrix (!!opencv-matrix with rows, cols, data)", path, line, name)
    if isinstance(data, list) and data and all(isinstance(r, list) for r in data):
        data = [x for r in data for x in r]
    if not isinstance(data, list):
        raise InputError("matrix data must be a list of numbers", path, line, f"{name}.data")
    if rows is None:
        rows, cols = 1, len(data)
    if len(data) != rows * cols:
        raise InputError(f"matrix data holds {len(data)} numbers, rows x cols = {rows} x {cols} needs {rows * cols}",
                         path, line, f"{name}.data")
    vals = [validate.in_range(x, -MAX_CAMERA_PARAM, MAX_CAMERA_PARAM, path, line, f"{name}.data") for x in data]
    return np.array(vals, float).reshape(rows, cols)


def _opencv_node(d: dict, line_of, path, *names: str, required: bool = True):
    for n in names:
        if n in d and d[n] is not None:
            return d[n], n, line_of(n)
    if required:
        raise InputError("missing in the OpenCV FileStorage file", path, None, names[0])
    return None, names[0], None


def camera_from_opencv_dict(d: dict, path=None, line_of=lambda key: None) -> CameraModel:
    """A camera model from the nodes of an OpenCV FileStorage file (camera_matrix, distortion_coefficients,
    image_width, image_height, dgcal_model; the usual other names of the first two too), every value checked."""
    Kn, kname, kline = _opencv_node(d, line_of, path, "camera_matrix", "K", "cameraMatrix")
    K = _opencv_matrix(Kn, path, kline, kname)
    if K.shape != (3, 3):
        if K.size != 9:
            raise InputError(f"camera_matrix must be a 3x3 matrix, got {K.shape[0]} x {K.shape[1]}", path, kline,
                             kname)
        K = K.reshape(3, 3)
    Dn, dname, dline = _opencv_node(d, line_of, path, "distortion_coefficients", "dist_coeffs", "D", "distCoeffs")
    dist = _opencv_matrix(Dn, path, dline, dname).ravel()
    if dist.size not in (4, 5, 8, 12, 14):
        raise InputError(f"needs 4, 5, 8, 12 or 14 distortion coefficients, got {dist.size}", path, dline, dname)
    _check_K(K, path, kline, kname)
    wn, wname, wline = _opencv_node(d, line_of, path, "image_width", "width")
    hn, hname, hline = _opencv_node(d, line_of, path, "image_height", "height")
    size = (validate.image_side(wn, path, wline, wname), validate.image_side(hn, path, hline, hname))
    name = d.get("dgcal_model")
    name = name if name in ("fraser7", "opencv8") else None
    ocv = conv.opencv_from_K_dist(K, dist)
    try:
        return conv.from_opencv(ocv, size, name)
    except InputError as e:
        raise _relocated(e, path, dline) from None


def _check_K(K: np.ndarray, path, line, name: str) -> None:
    """A camera matrix [fx 0 cx; 0 fy cy; 0 0 1] with positive focal lengths."""
    if K[0, 1] != 0:
        raise InputError("camera_matrix with skew is not supported", path, line, name)
    if K[1, 0] or K[2, 0] or K[2, 1] or abs(K[2, 2] - 1.0) > 1e-12:
        raise InputError("camera_matrix must be [fx 0 cx; 0 fy cy; 0 0 1]", path, line, name)
    for v, what in ((K[0, 0], "fx"), (K[1, 1], "fy")):
        _focal(v, path, line, f"{name}.{what}")
    for v, what in ((K[0, 2], "cx"), (K[1, 2], "cy")):
        validate.in_range(v, -validate.MAX_PIXEL, validate.MAX_PIXEL, path, line, f"{name}.{what}")


def parse_opencv_yaml(text: str, path: str | Path | None = None) -> CameraModel:
    """A camera model from OpenCV FileStorage text, YAML (`%YAML:1.0`, `!!opencv-matrix`) or XML
    (<opencv_storage>), read with PyYAML / ElementTree: a malformed file is an InputError naming the file, line
    and field, never a cv2 error or a native abort (cv2.FileStorage is not used to read)."""
    if text.lstrip("\ufeff \t\r\n").startswith("<"):
        d = _opencv_xml_dict(text, path)

        def line_of(key):
            m = re.search(rf"<{re.escape(key)}[\s>/]", text)
            return None if m is None else text.count("\n", 0, m.start()) + 1
    else:
        d = _opencv_yaml_dict(text, path)

        def line_of(key):
            return _yaml_line(text, key)
    return camera_from_opencv_dict(d, path, line_of)


# ---------------------------------------------------------------------------------------------
# COLMAP cameras.txt
# ---------------------------------------------------------------------------------------------
def colmap_cameras_txt_string(model: CameraModel, camera_id: int = 1, region=None) -> tuple[str, float]:
    """COLMAP cameras.txt text with one camera and the conversion's max error (px); warning and valid-region
    comments as in `opencv_yaml_string`."""
    name, params, err = conv.to_colmap(model, region)
    notes = [f"# {'WARNING: ' if 'approximation' in n else ''}{n}"
             for n in (conversion_warning("COLMAP", err, region), region_comment(region)) if n]
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
             "# Number of cameras: 1", *notes,
             " ".join([str(camera_id), name, str(model.image_size[0]), str(model.image_size[1])]
                      + [repr(float(p)) for p in params])]
    return "\n".join(lines) + "\n", err


def write_colmap_cameras_txt(path: str | Path, model: CameraModel, camera_id: int = 1, region=None) -> float:
    """Write COLMAP cameras.txt atomically; returns the conversion's max error (px)."""
    text, err = colmap_cameras_txt_string(model, camera_id, region)
    with atomic_write(path) as fh:
        fh.write(text)
    return err


def parse_colmap_cameras_txt(text: str, path: str | Path | None = None,
                             camera_id: int | None = None) -> CameraModel:
    """The camera `camera_id` of a COLMAP cameras.txt (default: the only one; several different cameras without
    an id are an error naming them, identical ones are one camera)."""
    if camera_id is None:
        rows = [(n, ln.split()) for n, ln in enumerate(text.splitlines(), 1)
                if ln.strip() and not ln.strip().startswith("#")]
        distinct = {tuple(t[1:]) for _, t in rows if len(t) >= 4}
        if len(distinct) > 1:
            ids = ", ".join(t[0] for _, t in rows[:8]) + (", ..." if len(rows) > 8 else "")
            raise InputError(f"{len(rows)} different cameras (ids {ids}): choose one as FILE#CAMERA_ID", path,
                             rows[1][0], "CAMERA_ID")
    for lineno, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        tok = s.split()
        if len(tok) < 4:
            raise InputError("a camera line needs CAMERA_ID MODEL WIDTH HEIGHT PARAMS", path, lineno)
        cid = validate.integer(tok[0], 0, 2 ** 63 - 1, path, lineno, "CAMERA_ID")
        w = validate.image_side(tok[2], path, lineno, "WIDTH")
        h = validate.image_side(tok[3], path, lineno, "HEIGHT")
        if camera_id is not None and cid != camera_id:
            continue
        keys = conv.COLMAP_PARAMS.get(tok[1], ())
        params = [_param(t, path, lineno, keys[i] if i < len(keys) else "PARAMS") for i, t in enumerate(tok[4:])]
        for i, k in enumerate(keys[:len(params)]):
            if k in ("f", "fx", "fy"):
                _focal(params[i], path, lineno, k)
        try:
            return conv.from_colmap(tok[1], w, h, params)
        except InputError as e:
            raise _relocated(e, path, lineno) from None
    raise InputError("no camera found" + ("" if camera_id is None else f" with id {camera_id}"), path,
                     field="CAMERA_ID")


# ---------------------------------------------------------------------------------------------
# Metashape calibration XML
# ---------------------------------------------------------------------------------------------
def metashape_xml_string(model: CameraModel, region=None) -> tuple[str, float]:
    """Metashape frame-camera calibration XML (as Tools > Camera Calibration > Export writes it) and the
    conversion's max error (px); warning and valid-region comments as in `opencv_yaml_string`."""
    d, err = conv.to_metashape(model, region)
    root = ET.Element("calibration")
    for n in (conversion_warning("Metashape", err, region), region_comment(region)):
        if n:
            root.append(ET.Comment(f" {'WARNING: ' if 'approximation' in n else ''}{n.replace('--', '-')} "))
    ET.SubElement(root, "projection").text = "frame"
    ET.SubElement(root, "width").text = str(int(model.image_size[0]))
    ET.SubElement(root, "height").text = str(int(model.image_size[1]))
    for k in conv.METASHAPE_KEYS:
        if k in ("f", "cx", "cy") or d[k] != 0.0:
            ET.SubElement(root, k).text = repr(float(d[k]))
    ET.SubElement(root, "date").text = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n", err


def write_metashape_xml(path: str | Path, model: CameraModel, region=None) -> float:
    """Write a Metashape calibration XML atomically; returns the conversion's max error (px)."""
    text, err = metashape_xml_string(model, region)
    with atomic_write(path) as fh:
        fh.write(text)
    return err


def _xml_root(text: str, path) -> ET.Element:
    try:
        return ET.fromstring(text)
    except ET.ParseError as e:
        raise InputError(f"invalid XML ({e})", path, e.position[0] if e.position else None) from None


def _text(el: ET.Element | None, path, name: str) -> str:
    if el is None or el.text is None:
        raise InputError("missing", path, field=name)
    return el.text.strip().strip('"')


def _size2(el: ET.Element | None, path, name: str) -> tuple[int, int]:
    """An image size `W H` (MicMac SzIm, NbPix)."""
    parts = _text(el, path, name).split()
    if len(parts) != 2:
        raise InputError(f"needs 2 numbers, got {len(parts)}", path, field=name)
    return validate.image_size(parts[0], parts[1], path, field=name)


def _float(el: ET.Element | None, path, name: str, n: int = 1):
    """The `n` finite numbers of an XML element's text (a float when n = 1)."""
    if el is None or el.text is None:
        raise InputError("missing", path, field=name)
    parts = el.text.split()
    if len(parts) != n:
        raise InputError(f"needs {n} number(s), got {len(parts)}", path, field=name)
    v = [_param(t.strip('"'), path, None, name) for t in parts]
    return v[0] if n == 1 else np.array(v)


def metashape_calibration_element(root: ET.Element, path=None, sensor_id: int | None = None) -> ET.Element:
    """The <calibration> of a Metashape cameras/project XML: the `class="adjusted"` one (the result of the
    alignment) over `class="initial"` (the start values); with several calibrated sensors `sensor_id` must choose."""
    sensors = [s for s in root.iter("sensor") if s.find("calibration") is not None]
    if sensors:
        if sensor_id is not None:
            chosen = [s for s in sensors if s.get("id") == str(sensor_id)]
            if not chosen:
                ids = ", ".join(str(s.get("id")) for s in sensors)
                raise InputError(f"no calibrated sensor with id {sensor_id} (ids: {ids})", path, field="sensor")
            sensor = chosen[0]
        elif len(sensors) > 1:
            desc = "; ".join(f"id {s.get('id')} {s.get('label', '')!r}" for s in sensors)
            raise InputError(f"{len(sensors)} calibrated sensors ({desc}): choose one as FILE#ID", path,
                             field="sensor")
        else:
            sensor = sensors[0]
        cals = sensor.findall("calibration")
    else:
        cals = list(root.iter("calibration"))
    if not cals:
        raise InputError("no <calibration> element", path, field="calibration")
    for cls in ("adjusted", "initial"):
        for c in cals:
            if c.get("class") == cls:
                return c
    return cals[0]


def parse_metashape_xml(text: str, path=None, name: str = "fraser7",
                        sensor_id: int | None = None) -> tuple[CameraModel, float]:
    """A dgcal model from a Metashape calibration XML (a lone <calibration> or a cameras/project export's sensor,
    its `class="adjusted"` calibration over the initial one); returns (model, max error px: 0 unless k4/p3/p4
    force a fit)."""
    root = _xml_root(text, path)
    cal = root if root.tag == "calibration" else metashape_calibration_element(root, path, sensor_id)
    proj = cal.findtext("projection") or cal.get("type") or "frame"
    if proj.strip() != "frame":
        raise InputError(f"only frame cameras are supported, not {proj.strip()!r}", path, field="projection")
    res = cal.find("resolution")
    if res is not None:
        if res.get("width") is None or res.get("height") is None:
            raise InputError("resolution needs width and height", path, field="resolution")
        size = validate.image_size(res.get("width"), res.get("height"), path, field="resolution")
    else:
        size = tuple(validate.image_side(_text(cal.find(k), path, k), path, None, k) for k in ("width", "height"))
    vals = {"f": _focal(_float(cal.find("f"), path, "f"), path, None, "f")}
    for k in conv.METASHAPE_KEYS[1:]:
        el = cal.find(k)
        if el is not None:
            vals[k] = _float(el, path, k)
    try:
        return conv.from_metashape(vals, size, name)
    except InputError as e:
        raise _relocated(e, path) from None


# ---------------------------------------------------------------------------------------------
# MicMac
# ---------------------------------------------------------------------------------------------
def parse_micmac_v1(text: str, path=None) -> conv.MicMacV1:
    """MicMac V1 `CalibrationInternConique` (AutoCal_*.xml) with a ModRad or ModPhgrStd distortion."""
    root = _xml_root(text, path)
    cic = root if root.tag == "CalibrationInternConique" else root.find(".//CalibrationInternConique")
    if cic is None:
        raise InputError("no <CalibrationInternConique>", path, field="CalibrationInternConique")
    conv_name = (cic.findtext("KnownConv") or "eConvApero_DistM2C").strip()
    if conv_name != "eConvApero_DistM2C":
        raise InputError(f"only eConvApero_DistM2C calibrations are supported, not {conv_name}", path,
                         field="KnownConv")
    PP = _float(cic.find("PP"), path, "PP", 2)
    F = _focal(_float(cic.find("F"), path, "F"), path, None, "F")
    size = _size2(cic.find("SzIm"), path, "SzIm")
    dists = cic.findall("CalibDistortion")
    if len(dists) != 1:
        raise InputError("exactly one <CalibDistortion> is supported", path, field="CalibDistortion")
    dist = dists[0]
    rad = dist.find("ModRad")
    extra = {}
    if rad is None:
        std = dist.find("ModPhgrStd")
        if std is None:
            kinds = ", ".join(c.tag for c in dist) or "none"
            raise InputError(f"distortion model {kinds} is not supported (ModRad, ModPhgrStd are)", path,
                             field="CalibDistortion")
        rad = std.find("RadialePart")
        if rad is None:
            raise InputError("ModPhgrStd lacks RadialePart", path, field="RadialePart")
        for k in ("P1", "P2", "b1", "b2"):
            el = std.find(k)
            extra[k] = 0.0 if el is None else _float(el, path, k)
    cdist = _float(rad.find("CDist"), path, "CDist", 2)
    coeffs = np.array([_float(c, path, "CoeffDist") for c in rad.findall("CoeffDist")])
    return conv.MicMacV1(size, F, PP, cdist, coeffs, **extra)


def parse_mmvii_calib(text: str, path=None) -> conv.MicMacMMVII:
    """MMVII `InternalCalibration` (Calib-PerspCentral-*.xml) with a Stenope projection and Fraser-type
    distortion (radial K1.., decentric p1 p2, polynomial b1 b2)."""
    root = _xml_root(text, path)
    ic = root.find(".//InternalCalibration")
    if ic is None:
        raise InputError("no <InternalCalibration>", path, field="InternalCalibration")
    proj = (ic.findtext("Projection") or "").strip().strip('"')
    if proj != "Stenope":
        raise InputError(f"only the Stenope projection is supported, not {proj!r}", path, field="Projection")
    size = _size2(ic.find("PixelFrame/NbPix"), path, "NbPix")
    F = _focal(_float(ic.find("PerfectProj/F"), path, "F"), path, None, "F")
    PP = _float(ic.find("PerfectProj/PP"), path, "PP", 2)
    dist = ic.find("Distorsion")
    K, kw = [], {}
    if dist is not None:
        for group in dist:
            for el in group:
                name = el.tag
                val = _float(el, path, name)
                m = re.fullmatch(r"K(\d+)", name)
                if group.tag == "Radial" and m:
                    i = int(m.group(1))
                    K += [0.0] * (i - len(K))
                    K[i - 1] = val
                elif name in ("p1", "p2", "b1", "b2"):
                    kw[name] = val
                elif val != 0.0:
                    raise InputError(f"distortion term {group.tag}/{name} is not supported", path, field=name)
    return conv.MicMacMMVII(size, F, PP, np.array(K), **kw)


def parse_micmac(text: str, path=None):
    """A MicMac calibration (V1 or MMVII) as a conversions.MicMacV1 / MicMacMMVII model."""
    if "InternalCalibration" in text:
        return parse_mmvii_calib(text, path)
    return parse_micmac_v1(text, path)


# ---------------------------------------------------------------------------------------------
# any camera file
# ---------------------------------------------------------------------------------------------
def parse_ros_camera_info(text: str, path=None) -> CameraModel:
    """A ROS `camera_info` calibration YAML (camera_calibration_parsers: image_width, image_height,
    camera_matrix/distortion_coefficients {rows, cols, data}, distortion_model plumb_bob | rational_polynomial).
    ROS pixels (image_geometry) follow OpenCV: the top-left pixel's centre is (0, 0), as dgcal's."""
    d = _load_yaml(text, path)
    if not isinstance(d, dict):
        raise InputError("a camera_info YAML must hold a mapping", path)

    def mat(key: str, n: tuple[int, ...]) -> np.ndarray:
        node, line = d.get(key), _yaml_line(text, key)
        if not isinstance(node, dict) or "data" not in node:
            raise InputError("missing {rows, cols, data}", path, line, key)
        data = node["data"]
        if not isinstance(data, list):
            raise InputError("data must be a list of numbers", path, line, key)
        if len(data) not in n:
            raise InputError(f"data must hold {' or '.join(map(str, n))} finite numbers, got {len(data)}", path,
                             line, key)
        return np.array([_param(x, path, line, key) for x in data], float)

    size = tuple(validate.image_side(d.get(key), path, _yaml_line(text, key), key)
                 for key in ("image_width", "image_height"))
    K = mat("camera_matrix", (9,)).reshape(3, 3)
    model_name = str(d.get("distortion_model", "plumb_bob")).strip()
    if model_name not in ("plumb_bob", "rational_polynomial"):
        raise InputError(f"distortion model {model_name[:40]!r} is not supported (plumb_bob, rational_polynomial)",
                         path, _yaml_line(text, "distortion_model"), "distortion_model")
    dist = mat("distortion_coefficients", (4, 5) if model_name == "plumb_bob" else (8, 12, 14))
    _check_K(K, path, _yaml_line(text, "camera_matrix"), "camera_matrix")
    try:
        return conv.from_opencv(conv.opencv_from_K_dist(K, dist), size, None)
    except InputError as e:
        raise _relocated(e, path, _yaml_line(text, "distortion_coefficients")) from None


def _yaml_line(text: str, key: str) -> int | None:
    m = re.search(rf"^\s*{re.escape(key)}\s*:", text, re.M)
    return None if m is None else text.count("\n", 0, m.start()) + 1


def _split_camera_id(path: Path) -> tuple[Path, int | None]:
    """`FILE#ID` -> (FILE, ID) when FILE exists and FILE#ID does not (a COLMAP camera or Metashape sensor id)."""
    m = re.fullmatch(r"(.+)#(\d+)", str(path))
    if m and not path.exists() and Path(m.group(1)).is_file():
        return Path(m.group(1)), int(m.group(2))
    return path, None


def read_camera_with_error(path: str | Path, model: str | None = None) -> tuple[CameraModel, float]:
    """A camera model from any supported file, recognised by content: camera.json, OpenCV YAML/XML, ROS
    camera_info YAML, COLMAP cameras.txt, Metashape XML, MicMac V1/MMVII XML; `FILE#ID` picks one camera of a
    multi-camera COLMAP or Metashape file. `model` ('fraser7'/'opencv8') asks for a conversion. Returns (model,
    max error px of any fitted conversion, 0 if exact)."""
    path, cam_id = _split_camera_id(Path(path))
    text = read_text(path)
    head = text.lstrip()[:4000]
    if head.startswith("{"):
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise InputError(f"invalid JSON ({e.msg})", path, e.lineno) from None
        except (ValueError, RecursionError) as e:   # a 5000-digit integer, nesting too deep
            raise InputError(f"invalid JSON ({_one_line(e)})", path) from None
        if not isinstance(d, dict):
            raise InputError("camera.json must hold an object", path)
        cam, err = camera_from_json_dict(d, path), 0.0
    elif "distortion_model" in head or re.search(r"^camera_matrix:\s*$\s+rows:", head, re.M):
        cam, err = parse_ros_camera_info(text, path), 0.0
    elif head.startswith("%YAML") or "opencv_storage" in head or "camera_matrix" in head:
        cam, err = parse_opencv_yaml(text, path), 0.0
    elif head.startswith("<"):
        if "CalibrationInternConique" in head or "InternalCalibration" in head:
            mm = parse_micmac(text, path)
            cam, err = _converting(path, lambda: conv.from_micmac(mm, model or "fraser7"))
            return check_camera(cam, path), err
        if "<calibration" in text:
            cam, err = _converting(path, lambda: parse_metashape_xml(text, path, model or "fraser7", cam_id))
            return check_camera(cam, path), err
        raise InputError("unrecognised XML camera file (expected Metashape, MicMac or OpenCV)", path)
    elif re.search(r"^\s*\d+\s+[A-Z_]+\s+[-+.\w]+\s+[-+.\w]+", text, re.M):
        cam, err = parse_colmap_cameras_txt(text, path, cam_id), 0.0
    else:
        raise InputError("unrecognised camera file (expected camera.json, OpenCV YAML, COLMAP cameras.txt, "
                         "Metashape or MicMac XML)", path)
    check_camera(cam, path)
    if model is not None and model != cam.NAME:
        cam, err2 = _converting(path, lambda: conv.convert_model(cam, model))
        check_camera(cam, path)
        err = max(err, err2)
    return cam, err


def _one_line(exc: BaseException, limit: int = 120) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _converting(path, convert):
    """`convert()` (a fitted conversion between camera models); a camera whose numbers make the fit fail
    (overflowing projections, a singular system) is an InputError naming the file."""
    try:
        with np.errstate(all="ignore"):
            out = convert()
    except InputError:
        raise
    except (np.linalg.LinAlgError, ValueError, FloatingPointError, OverflowError, ZeroDivisionError) as exc:
        raise InputError(f"this camera cannot be converted ({type(exc).__name__}: {_one_line(exc)}); are its "
                         "parameters plausible?", path) from None
    return out


def read_camera(path: str | Path, model: str | None = None) -> CameraModel:
    """A camera model from any supported camera file (see `read_camera_with_error`)."""
    return read_camera_with_error(path, model)[0]


load_camera = read_camera   # the older name


CAMERA_WRITERS = {".json": "camera.json", ".yaml": "OpenCV YAML", ".yml": "OpenCV YAML", ".txt": "COLMAP cameras.txt",
                  ".xml": "Metashape XML"}


def write_camera(path: str | Path, model: CameraModel, stats: dict | None = None) -> float:
    """Write a camera file in the format its suffix names (CAMERA_WRITERS); returns the conversion's max error
    (px, 0 when exact). camera.json keeps the model's sigmas and `stats`."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".json":
        write_camera_json(path, model, model.sigmas, stats)
        return 0.0
    if suffix in (".yaml", ".yml"):
        return write_opencv_yaml(path, model)
    if suffix == ".txt":
        return write_colmap_cameras_txt(path, model)
    if suffix == ".xml":
        return write_metashape_xml(path, model)
    raise InputError(f"unknown camera file type {suffix!r} (one of {', '.join(CAMERA_WRITERS)})", path)
