"""Metashape markers XML (File > Export > Export Markers): ground points and their image measurements.

The structure (Agisoft Metashape's project/markers XML, `<document version="1.x">`):
  <document><chunk>
    <cameras><camera id="0" sensor_id="0" label="DJI_0001"/>...</cameras>      (possibly inside <group>)
    <markers><marker id="0" label="GCP1"><reference x=".." y=".." z=".." [sx sy sz | sxyz] enabled="true"/>
    </marker>...</markers>
    <frames><frame id="0"><markers><marker marker_id="0">
        <location camera_id="0" pinned="true" x="4278" y="2187.5"/>...
    </marker></markers></frame></frames>
    <reference>WKT of the chunk's CRS</reference>
  </chunk></document>
A marker's `reference` holds its surveyed coordinates in the chunk's CRS (geographic: x = longitude, y = latitude,
z = height), `enabled="true"` when Metashape uses it as control, `false` for a check point (dgcal: role `check`);
a marker without `reference` is a tie marker (measured, no coordinates). A `location` is a projection of the marker
in a camera: `pinned="true"` when the user placed it, `pinned="false"` when Metashape only projected it (read with
`include_unpinned=True`). Location pixels are measured from the top-left corner of the image (the top-left
pixel's centre is (0.5, 0.5), as in Metashape's calibration where the image centre is w/2: dgcal's
`calib.camera.conversions.METASHAPE_PIXEL_SHIFT`), so dgcal subtracts 0.5 px.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Mapping, Sequence
from xml.parsers import expat

import numpy as np

from dgcal.fields.crs import MapGrid, parse_crs
from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.formats import Measurements, Points
from dgcal.fields.io.image_names import image_namer
from dgcal.fields.io.text_files import read_text

PIXEL_SHIFT = 0.5       # Metashape pixel origin: the top-left corner of the image
_LINE = "__line"        # attribute holding an element's file line (set by the line-keeping parser)


def parse_xml_with_lines(text: str, path: Path | None) -> ET.Element:
    """An ElementTree of `text` whose elements carry their file line in the attribute `__line`."""
    root: list[ET.Element] = []
    stack: list[ET.Element] = []
    p = expat.ParserCreate()

    def start(tag, attrs):
        el = ET.Element(tag, attrs)
        el.set(_LINE, str(p.CurrentLineNumber))
        if stack:
            stack[-1].append(el)
        else:
            root.append(el)
        stack.append(el)

    def end(tag):
        stack.pop()

    def chars(data):
        if stack:
            stack[-1].text = (stack[-1].text or "") + data
    p.StartElementHandler, p.EndElementHandler, p.CharacterDataHandler = start, end, chars
    try:
        p.Parse(text, True)
    except expat.ExpatError as exc:
        raise InputError(f"invalid XML ({expat.errors.messages[exc.code]})", path, exc.lineno) from None
    if not root:
        raise InputError("empty XML", path)
    return root[0]


def _line(el: ET.Element) -> int | None:
    v = el.get(_LINE)
    return int(v) if v else None


def is_metashape_markers(path: str | Path) -> bool:
    """True when a file is a Metashape document XML with markers (`<document>` ... `<chunk>` ... `<markers>`)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(65536).decode("utf-8", "replace")
    except OSError:
        return False
    return "<document" in head and "<chunk" in head and "<marker" in head


def read_metashape_markers(path: str | Path, include_unpinned: bool = False,
                           image_names: Mapping[str, str] | Sequence[str] | None = None,
                           chunk: int = 0, to_crs: str | None = None) -> tuple[Points | None, Measurements, str | None]:
    """Read a Metashape markers XML: (ground points or None, measurements in px (OpenCV), chunk CRS WKT or None).

    Control = markers whose reference is enabled, check = disabled; sigmas from `sx/sy/sz` (or `sxyz`), NaN when
    absent. `image_names` maps camera labels to file names (a dict, or the folder's names matched by stem).
    `to_crs` converts the points from the chunk's CRS (geographic: x = longitude, y = latitude, ellipsoidal z) into
    that CRS (pyproj through ECEF; sigmas kept, m) and returns it as the CRS."""
    path = Path(path)
    root = parse_xml_with_lines(read_text(path), path)
    chunks = [root] if root.tag == "chunk" else root.findall("chunk")
    if root.tag not in ("document", "chunk") or not chunks:
        raise InputError(f"expected a Metashape <document> with a <chunk>, found <{root.tag}>", path, _line(root),
                         "chunk")
    if chunk >= len(chunks):
        raise InputError(f"chunk {chunk} requested, the file has {len(chunks)}", path, field="chunk")
    ch = chunks[chunk]
    namer = image_namer(image_names, path, "label")
    cams: dict[str, str] = {}
    for cam in ch.iter("camera"):
        cid, label = cam.get("id"), cam.get("label")
        if cid is None or not label:
            raise InputError("a <camera> needs an id and a label", path, _line(cam), "label" if cid else "id")
        if cid in cams:
            raise InputError(f"camera id {cid} appears twice", path, _line(cam), "id")
        cams[cid] = namer(label, _line(cam))
    markers_el = ch.find("markers")
    labels: dict[str, str] = {}
    ids, xyz, sig, role, plines = [], [], [], [], []
    for m in ([] if markers_el is None else markers_el.iter("marker")):
        mid, label = m.get("id"), m.get("label")
        if mid is None:
            raise InputError("a <marker> needs an id", path, _line(m), "id")
        label = label or f"marker_{mid}"
        if mid in labels:
            raise InputError(f"marker id {mid} appears twice", path, _line(m), "id")
        if label in labels.values():
            raise InputError(f"marker label {label!r} appears twice", path, _line(m), "label")
        labels[mid] = label
        ref = m.find("reference")
        if ref is None or ref.get("x") is None:
            continue
        ln = _line(ref)
        xyz.append([validate.in_range(ref.get(k), -validate.MAX_COORDINATE_M, validate.MAX_COORDINATE_M, path, ln, k)
                    for k in ("x", "y", "z")])
        s = [ref.get(k, ref.get("sxyz")) for k in ("sx", "sy", "sz")]
        sig.append([np.nan if v is None else validate.positive(v, path, ln, k, validate.MAX_COORDINATE_M)
                    for v, k in zip(s, ("sx", "sy", "sz"))])
        enabled = (ref.get("enabled") or "true").strip().lower()
        if enabled not in ("true", "false", "1", "0"):
            raise InputError(f"enabled must be true or false, got {enabled!r}", path, ln, "enabled")
        role.append("control" if enabled in ("true", "1") else "check")
        ids.append(label)
        plines.append(ln or 0)
    img, pid, xy, mlines = [], [], [], []
    frames = ch.find("frames")
    for fm in ([] if frames is None else frames.iter("marker")):
        mid = fm.get("marker_id")
        if mid is None:
            continue
        if mid not in labels:
            raise InputError(f"marker_id {mid} is not among the chunk's <markers>", path, _line(fm), "marker_id")
        for loc in fm.findall("location"):
            ln = _line(loc)
            pinned = (loc.get("pinned") or "false").strip().lower() in ("true", "1")
            if (not pinned and not include_unpinned) or (loc.get("valid") or "true").lower() == "false":
                continue
            cid = loc.get("camera_id")
            if cid not in cams:
                raise InputError(f"camera_id {cid} is not among the chunk's <cameras>", path, ln, "camera_id")
            xy.append([validate.in_range(loc.get(k), -validate.MAX_PIXEL, validate.MAX_PIXEL, path, ln, k, "px")
                       - PIXEL_SHIFT for k in ("x", "y")])
            img.append(cams[cid])
            pid.append(labels[mid])
            mlines.append(ln or 0)
    if not img:
        raise InputError("no pinned marker locations (<frames><frame><markers><marker><location pinned=\"true\">)",
                         path, field="location")
    meas = Measurements(np.array(img, dtype=object), np.array(pid, dtype=object), np.array(xy, float), None,
                        np.array(mlines), path)
    seen: set[tuple[str, str]] = set()
    for i, key in enumerate(zip(img, pid)):
        if key in seen:
            raise InputError(f"marker {key[1]!r} located twice in camera {key[0]!r}", path, mlines[i], "camera_id")
        seen.add(key)
    points = None
    if ids:
        points = Points(np.array(ids, dtype=object), np.array(xyz, float), np.array(sig, float),
                        np.array(role, dtype=object), np.array(plines), path)
    crs_el = ch.find("reference")
    crs = crs_el.text.strip() if crs_el is not None and crs_el.text and crs_el.text.strip() else None
    if to_crs is not None and points is not None:
        if crs is None:
            raise InputError("the chunk names no CRS (<reference>) to convert the markers from", path, field="crs")
        src, dst = parse_crs(crs, "reference"), parse_crs(to_crs)
        if src != dst:
            points.xyz = MapGrid(dst).from_ecef(MapGrid(src).to_ecef(points.xyz))
        crs = to_crs
    return points, meas, crs
