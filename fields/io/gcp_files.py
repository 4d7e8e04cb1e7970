"""Ground-control files of other software: ODM `gcp_list.txt` (read/write), MicMac XML (read), the dispatch.

- ODM/OpenDroneMap `gcp_list.txt`: first line the CRS (EPSG code, PROJ string or WGS84 UTM name), then
  one measurement per line, whitespace separated: `geo_x geo_y geo_z im_x im_y image_name [gcp_name [extra]]`.
  OpenSfM normalises pixels as `(x + 0.5 - w/2) / size`, i.e. pixel (0,0) is the centre of the top-left
  pixel: the same convention as dgcal (no shift). Lines without a name are grouped by their exact coordinates (as
  ODM's GCPEntry.coords_key does) and named `gcp_1`, `gcp_2`, ... in order of appearance, skipping names the file
  uses itself. The CRS line may be an EPSG code, a PROJ string, `WGS84 UTM <zone><N|S>` or `WGS84 longlat`
  (EPSG:4326, geo_x = longitude, geo_y = latitude); `#` comment lines may come before it.
- MicMac `DicoAppuisFlottant` (ground points: `Pt`, `NamePt`, `Incertitude`) and
  `SetOfMesureAppuisFlottants` (image measurements: `NameIm`, `NamePt`, `PtIm`). MicMac V1 measures
  pixels from the top-left pixel's centre too (its calibration PP of an ideal camera is (w-1)/2), so no shift.
- `read_any_points` / `read_any_measurements` recognise these, Metashape's markers XML
  (`dgcal.fields.io.metashape_markers`), Pix4D's BINGO export (`dgcal.fields.io.bingo`), its GCP and marks
  files (`dgcal.fields.io.pix4d_marks`) and COLMAP models
  (`dgcal.fields.io.colmap_tracks`) by content, not by extension.
"""
from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from dgcal.fields.io import validate
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.errors import InputError
from dgcal.fields.io.text_files import read_text
from dgcal.fields.io.formats import Measurements, Points, read_measurements, read_points
from dgcal.fields.io.bingo import is_bingo, read_bingo
from dgcal.fields.io.colmap_tracks import colmap_model_files, read_colmap_tracks
from dgcal.fields.io.metashape_markers import is_metashape_markers, read_metashape_markers
from dgcal.fields.io.pix4d_marks import is_pix4d_gcps, is_pix4d_marks, read_pix4d_gcps, read_pix4d_marks

_WGS84_UTM = re.compile(r"^\s*WGS84\s+UTM\s+(\d{1,2})\s*([NS])\s*$", re.I)
_WGS84_LONGLAT = re.compile(r"^\s*WGS84\s+(long?lat|lonlat|latlong?)\s*$", re.I)


def odm_crs_to_pyproj(text: str) -> str:
    """The pyproj text of an ODM CRS line ('EPSG:32651', a PROJ string, 'WGS84 UTM 51N', 'WGS84 longlat')."""
    m = _WGS84_UTM.match(text)
    if m:
        zone, hemi = int(m.group(1)), m.group(2).upper()
        return f"EPSG:{32600 + zone if hemi == 'N' else 32700 + zone}"
    if _WGS84_LONGLAT.match(text):
        return "EPSG:4326"
    return text.strip().strip("'")


def is_odm_gcp_list(path: str | Path) -> bool:
    """True when a file looks like an ODM gcp_list.txt (a CRS line, then whitespace-separated rows)."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            first = ""
            for _ in range(200):
                line = fh.readline()
                if not line:
                    break
                if line.strip() and not line.lstrip().startswith("#"):
                    first = line.strip()
                    break
    except OSError:
        return False
    return bool(first) and "," not in first and (
        first.upper().startswith("EPSG:") or first.startswith(("+proj", "'+proj")) or bool(_WGS84_UTM.match(first))
        or bool(_WGS84_LONGLAT.match(first)) or first.upper().startswith(("PROJCS", "PROJCRS", "GEOGCS")))


def read_odm_gcp_list(path: str | Path) -> tuple[str, Points, Measurements]:
    """Read an ODM gcp_list.txt: (CRS text for pyproj, ground points, image measurements in px).

    The same point name appearing with different coordinates is an error naming both lines.
    """
    path = Path(path)
    lines = read_text(path).splitlines()
    crs_line = None
    pts: dict[str, tuple[np.ndarray, int]] = {}
    img, pid, xy, ln = [], [], [], []
    named = {f[6] for f in (raw.split() for raw in lines) if len(f) > 6 and not f[0].startswith("#")}
    auto: dict[tuple[float, float, float], str] = {}
    for no, raw in enumerate(lines, start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        if crs_line is None:
            crs_line = odm_crs_to_pyproj(s)
            continue
        f = s.split()
        if len(f) < 6:
            raise InputError(f"expected 'geo_x geo_y geo_z im_x im_y image_name [gcp_name]', got {len(f)} fields",
                             path, no)
        vals = [validate.in_range(t, -lim, lim, path, no, name) for t, name, lim in
                zip(f[:5], ("geo_x", "geo_y", "geo_z", "im_x", "im_y"), _ODM_LIMITS)]
        X = np.array(vals[:3])
        if len(f) > 6:
            name = f[6]
        else:
            key = (vals[0], vals[1], vals[2])
            if key not in auto:
                k = len(auto) + 1
                while f"gcp_{k}" in named:
                    k += 1
                auto[key] = f"gcp_{k}"
                named.add(auto[key])
            name = auto[key]
        if name in pts and np.max(np.abs(pts[name][0] - X)) > 1e-6:
            raise InputError(f"point {name!r} has other coordinates than on line {pts[name][1]}", path, no, "geo_x")
        pts.setdefault(name, (X, no))
        img.append(f[5])
        pid.append(name)
        xy.append(vals[3:5])
        ln.append(no)
    if crs_line is None:
        raise InputError("empty gcp_list.txt: the first line must be the CRS", path, 1)
    if not img:
        raise InputError("no measurements after the CRS line", path)
    names = list(pts)
    points = Points(np.array(names, dtype=object), np.array([pts[k][0] for k in names]),
                    np.full((len(names), 3), np.nan), np.array(["control"] * len(names), dtype=object),
                    np.array([pts[k][1] for k in names]), path)
    meas = Measurements(np.array(img, dtype=object), np.array(pid, dtype=object), np.array(xy, float),
                        np.full((len(img), 2), np.nan), np.array(ln), path)
    _no_duplicate_measurements(meas)
    return crs_line, points, meas


def write_odm_gcp_list(path: str | Path, crs: str, points: Points, meas: Measurements) -> None:
    """Write an ODM gcp_list.txt (atomic) for the measurements of points that have coordinates."""
    idx = points.index()
    with atomic_write(path) as fh:
        fh.write(crs.strip() + "\n")
        for i in range(len(meas)):
            p = str(meas.id[i])
            if p not in idx:
                continue
            X = points.xyz[idx[p]]
            fh.write("%.6f %.6f %.6f %.4f %.4f %s %s\n" % (*X, *meas.xy[i], meas.image[i], p))


_ODM_LIMITS = (validate.MAX_COORDINATE_M,) * 3 + (validate.MAX_PIXEL,) * 2


def _no_duplicate_measurements(meas: Measurements) -> None:
    seen: dict[tuple[str, str], int] = {}
    for i in range(len(meas)):
        key = (str(meas.image[i]), str(meas.id[i]))
        if key in seen:
            raise InputError(f"point {key[1]!r} measured twice in image {key[0]!r}", meas.path,
                             None if meas.lines is None else int(meas.lines[i]), "id")
        seen[key] = i


# ---------------------------------------------------------------------------------------------
def _xml(path: Path, root_tag: str) -> tuple[ET.Element, str]:
    text = read_text(path)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise InputError(f"invalid XML ({exc})", path, exc.position[0] if exc.position else None) from None
    if root.tag != root_tag:
        found = root.find(f".//{root_tag}")
        if found is None:
            raise InputError(f"expected a <{root_tag}> file, found <{root.tag}>", path, field=root_tag)
        root = found
    return root, text


def _line_of(text: str, needle: str, start: int = 0) -> tuple[int | None, int]:
    pos = text.find(needle, start)
    return (None, start) if pos < 0 else (text.count("\n", 0, pos) + 1, pos + 1)


def _numbers(el: ET.Element | None, n: int, path, line, field, limit: float = validate.MAX_COORDINATE_M) \
        -> np.ndarray:
    if el is None or el.text is None:
        raise InputError("missing value", path, line, field)
    parts = el.text.split()
    if len(parts) != n:
        raise InputError(f"expected {n} numbers, got {len(parts)}", path, line, field)
    return np.array([validate.in_range(v, -limit, limit, path, line, field) for v in parts])


def read_micmac_points(path: str | Path) -> Points:
    """Read a MicMac `DicoAppuisFlottant` XML: ground points (m) with sigmas from `Incertitude`.

    MicMac writes `Incertitude` as weights-ish placeholders (often `1 1 1`); they are kept as sigmas
    in metres, so override them with `--gcp-sigma` when they are not real standard deviations.
    """
    path = Path(path)
    root, text = _xml(path, "DicoAppuisFlottant")
    ids, xyz, sig, lines = [], [], [], []
    pos = 0
    for el in root.findall("OneAppuisDAF"):
        line, pos = _line_of(text, "<OneAppuisDAF", pos)
        name = (el.findtext("NamePt") or "").strip()
        if not name:
            raise InputError("missing value", path, line, "NamePt")
        if name in ids:
            raise InputError(f"duplicate point id {name!r}", path, line, "NamePt")
        xyz.append(_numbers(el.find("Pt"), 3, path, line, "Pt"))
        inc = el.find("Incertitude")
        s = _numbers(inc, 3, path, line, "Incertitude") if inc is not None else np.full(3, np.nan)
        if np.any(s <= 0):
            raise InputError("a sigma must be positive", path, line, "Incertitude")
        sig.append(s)
        ids.append(name)
        lines.append(line or 0)
    if not ids:
        raise InputError("no <OneAppuisDAF> points", path)
    return Points(np.array(ids, dtype=object), np.array(xyz), np.array(sig),
                  np.array(["control"] * len(ids), dtype=object), np.array(lines), path)


def read_micmac_measurements(path: str | Path) -> Measurements:
    """Read a MicMac `SetOfMesureAppuisFlottants` XML: image measurements (px, top-left pixel centre = 0,0)."""
    path = Path(path)
    root, text = _xml(path, "SetOfMesureAppuisFlottants")
    img, pid, xy, lines = [], [], [], []
    pos = 0
    for im in root.findall("MesureAppuiFlottant1Im"):
        name = (im.findtext("NameIm") or "").strip()
        _, pos = _line_of(text, "<MesureAppuiFlottant1Im", pos)
        if not name:
            raise InputError("missing value", path, text.count("\n", 0, pos) + 1, "NameIm")
        for m in im.findall("OneMesureAF1I"):
            line, pos = _line_of(text, "<OneMesureAF1I", pos)
            p = (m.findtext("NamePt") or "").strip()
            if not p:
                raise InputError("missing value", path, line, "NamePt")
            xy.append(_numbers(m.find("PtIm"), 2, path, line, "PtIm", validate.MAX_PIXEL))
            img.append(name)
            pid.append(p)
            lines.append(line or 0)
    if not img:
        raise InputError("no <OneMesureAF1I> measurements", path)
    meas = Measurements(np.array(img, dtype=object), np.array(pid, dtype=object), np.array(xy),
                        np.full((len(img), 2), np.nan), np.array(lines), path)
    _no_duplicate_measurements(meas)
    return meas


def _head(p: Path, size: int = 2000) -> str:
    """The start of a file (without leading blanks) to recognise its format; '' when it cannot be read (the
    reader chosen then says why)."""
    try:
        with open(p, "rb") as fh:
            return fh.read(size).decode("utf-8", errors="replace").lstrip("\ufeff").lstrip()
    except OSError:
        return ""


def read_any_points(path: str | Path) -> tuple[Points, str | None]:
    """Ground points from a dgcal CSV, a MicMac XML, a Metashape markers XML (its chunk CRS), an ODM gcp_list.txt
    or a Pix4D GCP file; with the CRS when the file names one (else None). The format is recognised by content."""
    p = Path(path)
    if _head(p).startswith("<"):
        if is_metashape_markers(p):
            pts, _, crs = read_metashape_markers(p)
            if pts is None:
                raise InputError("no marker of the Metashape file has reference coordinates", p, field="reference")
            return pts, crs
        return read_micmac_points(p), None
    if is_odm_gcp_list(p):
        crs, pts, _ = read_odm_gcp_list(p)
        return pts, crs
    if is_pix4d_gcps(p):
        return read_pix4d_gcps(p), None
    return read_points(p), None


def read_any_measurements(path: str | Path, image_size: tuple[int, int] | None = None,
                          pixel_size_mm: float | None = None,
                          image_names: Mapping[str, str] | Sequence[str] | None = None,
                          ) -> tuple[Measurements, str | None, Points | None]:
    """Image measurements (px, OpenCV convention) with the file's CRS and ground points when it has them, from
    (recognised by content) a dgcal CSV, an ODM gcp_list.txt, a MicMac XML, a Metashape markers XML, a Pix4D
    marks file, a Pix4D / BINGO `_bingo.txt` (sensor mm: needs `image_size` (w, h) px and `pixel_size_mm`) or a
    COLMAP model folder
    (its tracks as tie points). `image_names` (the images' file names, or a {label: name} map) turns the labels of
    Pix4D and Metashape, which drop the extension, into file names."""
    p = Path(path)
    if p.is_dir() or colmap_model_files(p) is not None:
        return read_colmap_tracks(p), None, None
    if _head(p).startswith("<"):
        if is_metashape_markers(p):
            pts, meas, crs = read_metashape_markers(p, image_names=image_names)
            return meas, crs, pts
        return read_micmac_measurements(p), None, None
    if is_odm_gcp_list(p):
        crs, pts, meas = read_odm_gcp_list(p)
        return meas, crs, pts
    if is_bingo(p):
        if image_size is None or pixel_size_mm is None:
            # an option is missing, not a value of the file: the error names the option (the CLI's flag)
            raise InputError(f"{p} is a BINGO file, which holds sensor millimetres: give the camera's image size "
                             "and its pixel size in mm to turn them into pixels", field="pixel_size_mm")
        return read_bingo(p, image_size, pixel_size_mm, image_names), None, None
    if is_pix4d_marks(p):
        return read_pix4d_marks(p, image_names=image_names), None, None
    return read_measurements(p), None, None


def read_micmac_orientation(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """MicMac V1 `Orientation-*.xml`: (R_cam_to_world (3,3), projection centre (3,)) in its ground frame.

    MicMac's camera frame is x right, y down, z forward (as dgcal's); `CodageMatr` rows L1..L3 form the
    camera-to-world rotation: X_world = Centre + CodageMatr X_cam.
    """
    path = Path(path)
    root, _ = _xml(path, "OrientationConique")
    ext = root.find("Externe")
    if ext is None:
        raise InputError("no <Externe>", path, field="Externe")
    C_world = _numbers(ext.find("Centre"), 3, path, None, "Centre")
    mat = ext.find("ParamRotation/CodageMatr")
    if mat is None:
        raise InputError("only <CodageMatr> rotations are supported", path, field="ParamRotation")
    R_cam_to_world = np.array([_numbers(mat.find(k), 3, path, None, k) for k in ("L1", "L2", "L3")])
    return R_cam_to_world, C_world
