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
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.errors import InputError


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
    """A camera model (with sigmas, if any) from a camera.json dict."""
    for key in ("model", "image_size"):
        if key not in d:
            raise InputError("camera.json lacks this field", path, field=key)
    if not isinstance(d["model"], str) or d["model"] not in MODELS:
        raise InputError(f"unknown camera model {d['model']!r} ({', '.join(MODELS)})", path, field="model")
    cls = model_class(d["model"])
    size = d["image_size"]
    if not (isinstance(size, list) and len(size) == 2):
        raise InputError("image_size must be [width, height]", path, field="image_size")
    params = d.get("parameters")
    if not isinstance(params, dict):
        # camera.json written by others may hold only the opencv block
        if isinstance(d.get("opencv"), dict):
            return conv.from_opencv(d["opencv"], tuple(size), d["model"])
        raise InputError("camera.json lacks the parameters", path, field="parameters")
    missing = [k for k in cls.PARAMS if k not in params]
    if missing:
        raise InputError(f"missing parameter {missing[0]!r} of {cls.NAME}", path, field=f"parameters.{missing[0]}")
    try:
        cam = cls(tuple(size), [float(params[k]) for k in cls.PARAMS])
    except (TypeError, ValueError):
        raise InputError("parameters must be numbers", path, field="parameters") from None
    sig = d.get("sigmas")
    if isinstance(sig, dict) and all(k in sig for k in cls.PARAMS):
        cam.sigmas = np.array([np.nan if sig[k] is None else float(sig[k]) for k in cls.PARAMS])
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


def parse_opencv_yaml(text: str, path: str | Path | None = None) -> CameraModel:
    """A camera model from OpenCV FileStorage text (YAML or XML)."""
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as e:
        last = (str(e).strip().splitlines() or [type(e).__name__])[-1]
        raise InputError(f"not a readable OpenCV FileStorage file ({last})", path) from None
    try:
        def node(*names):
            for n in names:
                nd = fs.getNode(n)
                if not nd.empty():
                    return nd, n
            raise InputError("missing in OpenCV FileStorage file", path, field=names[0])

        Kn, _ = node("camera_matrix", "K", "cameraMatrix")
        Dn, dname = node("distortion_coefficients", "dist_coeffs", "D", "distCoeffs")
        try:
            K, dist = Kn.mat(), Dn.mat()
        except cv2.error:
            raise InputError("camera_matrix and the distortion must be OpenCV matrices (!!opencv-matrix)", path,
                             field="camera_matrix") from None
        if K is None or K.shape != (3, 3):
            raise InputError("camera_matrix must be a 3x3 matrix", path, field="camera_matrix")
        if dist is None:
            raise InputError("distortion coefficients must be a matrix", path, field=dname)
        wn, _ = node("image_width", "width")
        hn, _ = node("image_height", "height")
        size = (int(wn.real()), int(hn.real()))
        name = fs.getNode("dgcal_model").string() or None
    finally:
        fs.release()
    if abs(K[0, 1]) > 0:
        raise InputError("camera_matrix with skew is not supported", path, field="camera_matrix")
    d = conv.opencv_from_K_dist(K, dist)
    if name not in ("fraser7", "opencv8"):
        name = None
    try:
        return conv.from_opencv(d, size, name)
    except InputError as e:
        raise InputError(str(e), path, field=e.field) from None


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
        try:
            cid, w, h = int(tok[0]), int(tok[2]), int(tok[3])
        except ValueError:
            raise InputError("CAMERA_ID, WIDTH, HEIGHT must be integers", path, lineno, "CAMERA_ID") from None
        if camera_id is not None and cid != camera_id:
            continue
        try:
            params = [float(t) for t in tok[4:]]
        except ValueError:
            raise InputError("camera params must be numbers", path, lineno, "PARAMS") from None
        try:
            return conv.from_colmap(tok[1], w, h, params)
        except InputError as e:
            raise InputError(str(e), path, lineno, e.field) from None
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


def _float(el: ET.Element | None, path, name: str, n: int = 1):
    if el is None or el.text is None:
        raise InputError("missing", path, field=name)
    try:
        v = [float(t.strip('"')) for t in el.text.split()]
    except ValueError:
        raise InputError(f"not a number: {el.text.strip()!r}", path, field=name) from None
    if len(v) != n:
        raise InputError(f"needs {n} number(s), got {len(v)}", path, field=name)
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
        try:
            size = (int(res.get("width")), int(res.get("height")))
        except (TypeError, ValueError):
            raise InputError("resolution needs width and height", path, field="resolution") from None
    else:
        size = (int(_float(cal.find("width"), path, "width")), int(_float(cal.find("height"), path, "height")))
    vals = {"f": _float(cal.find("f"), path, "f")}
    for k in conv.METASHAPE_KEYS[1:]:
        el = cal.find(k)
        if el is not None:
            vals[k] = _float(el, path, k)
    try:
        return conv.from_metashape(vals, size, name)
    except InputError as e:
        raise InputError(str(e), path, field=e.field) from None


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
    F = _float(cic.find("F"), path, "F")
    size = tuple(int(v) for v in _float(cic.find("SzIm"), path, "SzIm", 2))
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
    size = tuple(int(v) for v in _float(ic.find("PixelFrame/NbPix"), path, "NbPix", 2))
    F = _float(ic.find("PerfectProj/F"), path, "F")
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
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise InputError(f"invalid YAML ({getattr(exc, 'problem', None) or 'syntax'})", path,
                         None if mark is None else mark.line + 1) from None
    if not isinstance(d, dict):
        raise InputError("a camera_info YAML must hold a mapping", path)

    def mat(key: str, n: tuple[int, ...]) -> np.ndarray:
        node = d.get(key)
        if not isinstance(node, dict) or "data" not in node:
            raise InputError("missing {rows, cols, data}", path, _yaml_line(text, key), key)
        try:
            a = np.asarray(node["data"], float).ravel()
        except (TypeError, ValueError):
            raise InputError("data must be numbers", path, _yaml_line(text, key), key) from None
        if a.size not in n or not np.all(np.isfinite(a)):
            raise InputError(f"data must hold {' or '.join(map(str, n))} finite numbers, got {a.size}", path,
                             _yaml_line(text, key), key)
        return a

    for key in ("image_width", "image_height"):
        v = d.get(key)
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise InputError(f"must be a positive whole number, not {v!r}", path, _yaml_line(text, key), key)
    K = mat("camera_matrix", (9,)).reshape(3, 3)
    model_name = str(d.get("distortion_model", "plumb_bob")).strip()
    if model_name not in ("plumb_bob", "rational_polynomial"):
        raise InputError(f"distortion model {model_name!r} is not supported (plumb_bob, rational_polynomial)", path,
                         _yaml_line(text, "distortion_model"), "distortion_model")
    dist = mat("distortion_coefficients", (4, 5) if model_name == "plumb_bob" else (8, 12, 14))
    if abs(K[0, 1]) > 0 or abs(K[2, 2] - 1.0) > 1e-12 or K[1, 0] or K[2, 0] or K[2, 1]:
        raise InputError("camera_matrix must be [fx 0 cx; 0 fy cy; 0 0 1]", path, _yaml_line(text, "camera_matrix"),
                         "camera_matrix")
    size = (int(d["image_width"]), int(d["image_height"]))
    try:
        return conv.from_opencv(conv.opencv_from_K_dist(K, dist), size, None)
    except InputError as e:
        raise InputError(str(e), path, field=e.field) from None


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
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise InputError(f"cannot read camera file ({e.strerror})", path) from None
    head = text.lstrip()[:4000]
    if head.startswith("{"):
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise InputError(f"invalid JSON ({e.msg})", path, e.lineno) from None
        if not isinstance(d, dict):
            raise InputError("camera.json must hold an object", path)
        cam, err = camera_from_json_dict(d, path), 0.0
    elif "distortion_model" in head or re.search(r"^camera_matrix:\s*$\s+rows:", head, re.M):
        cam, err = parse_ros_camera_info(text, path), 0.0
    elif head.startswith("%YAML") or "opencv_storage" in head or "camera_matrix" in head:
        cam, err = parse_opencv_yaml(text, path), 0.0
    elif head.startswith("<"):
        if "CalibrationInternConique" in head or "InternalCalibration" in head:
            return conv.from_micmac(parse_micmac(text, path), model or "fraser7")
        if "<calibration" in text:
            return parse_metashape_xml(text, path, model or "fraser7", cam_id)
        raise InputError("unrecognised XML camera file (expected Metashape, MicMac or OpenCV)", path)
    elif re.search(r"^\s*\d+\s+[A-Z_]+\s+\d+\s+\d+", text, re.M):
        cam, err = parse_colmap_cameras_txt(text, path, cam_id), 0.0
    else:
        raise InputError("unrecognised camera file (expected camera.json, OpenCV YAML, COLMAP cameras.txt, "
                         "Metashape or MicMac XML)", path)
    if model is not None and model != cam.NAME:
        cam, err2 = conv.convert_model(cam, model)
        err = max(err, err2)
    return cam, err


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
