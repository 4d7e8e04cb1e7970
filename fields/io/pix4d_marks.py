"""Pix4D's companion text files of a BINGO export: the GCP file and the GCP/MTP marks file (no header rows).

- GCP file (Pix4D "Tie points (GCPs, CPs) import format", support.pix4d.com article 360038397752): one point per
  line, comma separated, `label,X,Y,Z` or `label,X,Y,Z,accuracy_horizontal,accuracy_vertical` (m); the
  coordinates in the axis order of the project's CRS (Pix4D's note: a CRS whose first axis is northing or latitude
  puts that first — convert such a file before giving it to dgcal, whose x is east). The accuracies become sigmas
  (sx = sy = horizontal, sz = vertical).
- Marks file (Pix4D "How to import and export Tie Points marks", article 360035474951): `image,label,x,y[,extra]`,
  comma separated, pixels with "the origin [at] the upper left part of the image", x right, y down. The article
  does not say whether a pixel's centre is at an integer or at half a pixel; dgcal reads the origin as the image's
  corner (the top-left pixel's centre at (0.5, 0.5), as in COLMAP and Metashape) and subtracts `pixel_shift` = 0.5 px
  (pass 0 if your files count from the top-left pixel's centre). The optional fifth column is the mark's accuracy
  in pixels (PIX4Dmatic) or Pix4Dmapper's zoom level: it is ignored unless `fifth="sigma"`.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.formats import Measurements, Points
from dgcal.fields.io.image_names import image_namer
from dgcal.fields.io.text_files import read_text

PIXEL_SHIFT = 0.5
_NUMBER = re.compile(r"^\s*[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?\s*$")


def _first_row(path: str | Path) -> list[str]:
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096).decode("utf-8", "replace").lstrip("\ufeff")
    except OSError:
        return []
    row = next((ln for ln in head.splitlines() if ln.strip() and not ln.lstrip().startswith("#")), "")
    return row.split(",")


def is_pix4d_gcps(path: str | Path) -> bool:
    """True when the first row is `label,X,Y,Z[,acc_h,acc_v]` with numbers (no header row)."""
    f = _first_row(path)
    return len(f) in (4, 6) and all(_NUMBER.match(v) for v in f[1:])


def is_pix4d_marks(path: str | Path) -> bool:
    """True when the first row is `image,label,x,y[,extra]` with numeric x, y (no header row)."""
    f = _first_row(path)
    return len(f) in (4, 5) and not _NUMBER.match(f[0]) and all(_NUMBER.match(v) for v in f[2:])


def _rows(path: Path, sizes: tuple[int, ...], layout: str):
    for no, raw in enumerate(read_text(path).splitlines(), start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        f = [v.strip() for v in s.split(",")]
        if len(f) not in sizes:
            raise InputError(f"expected '{layout}', got {len(f)} fields", path, no)
        yield no, f


def read_pix4d_gcps(path: str | Path) -> Points:
    """Read a Pix4D GCP file `label,X,Y,Z[,acc_h,acc_v]` (m): control points with sigmas from the accuracies."""
    path = Path(path)
    ids, xyz, sig, lines = [], [], [], []
    for no, f in _rows(path, (4, 6), "label,X,Y,Z[,accuracy_h,accuracy_v]"):
        if not f[0]:
            raise InputError("missing value", path, no, "label")
        if f[0] in ids:
            raise InputError(f"duplicate point label {f[0]!r}", path, no, "label")
        lim = validate.MAX_COORDINATE_M
        xyz.append([validate.in_range(v, -lim, lim, path, no, k, "m") for v, k in zip(f[1:4], "XYZ")])
        if len(f) == 6:
            h, v = (validate.positive(x, path, no, k, lim) for x, k in zip(f[4:], ("accuracy_h", "accuracy_v")))
            sig.append([h, h, v])
        else:
            sig.append([np.nan] * 3)
        ids.append(f[0])
        lines.append(no)
    if not ids:
        raise InputError("no 'label,X,Y,Z' rows", path)
    return Points(np.array(ids, dtype=object), np.array(xyz), np.array(sig), np.array(["control"] * len(ids),
                  dtype=object), np.array(lines), path)


def read_pix4d_marks(path: str | Path, pixel_shift: float = PIXEL_SHIFT, fifth: str = "ignore",
                     image_names: Mapping[str, str] | Sequence[str] | None = None) -> Measurements:
    """Read a Pix4D marks file `image,label,x,y[,extra]` (px from the image's upper-left corner) into dgcal's pixel
    convention (minus `pixel_shift`); `fifth="sigma"` takes the fifth column as the mark's sigma in px. An image
    given with its folder keeps only its file name; `image_names` maps names as `image_names.image_namer` does."""
    path = Path(path)
    namer = image_namer(image_names, path)
    if fifth not in ("ignore", "sigma"):
        raise InputError(f"fifth must be 'ignore' or 'sigma', not {fifth!r}", path, field="fifth")
    img, pid, xy, sig, lines = [], [], [], [], []
    seen: set[tuple[str, str]] = set()
    for no, f in _rows(path, (4, 5), "image,label,x,y[,accuracy]"):
        for k, name in ((0, "image"), (1, "label")):
            if not f[k]:
                raise InputError("missing value", path, no, name)
        name = namer(re.split(r"[\\/]", f[0])[-1], no)
        if (name, f[1]) in seen:
            raise InputError(f"point {f[1]!r} marked twice in image {name!r}", path, no, "label")
        seen.add((name, f[1]))
        xy.append([validate.in_range(v, -validate.MAX_PIXEL, validate.MAX_PIXEL, path, no, k, "px") - pixel_shift
                   for v, k in zip(f[2:4], "xy")])
        s = np.nan
        if fifth == "sigma" and len(f) == 5:
            s = validate.positive(f[4], path, no, "accuracy", validate.MAX_PIXEL)
        sig.append([s, s])
        img.append(name)
        pid.append(f[1])
        lines.append(no)
    if not img:
        raise InputError("no 'image,label,x,y' rows", path)
    sigma = np.array(sig) if fifth == "sigma" else None
    return Measurements(np.array(img, dtype=object), np.array(pid, dtype=object), np.array(xy), sigma,
                        np.array(lines), path)
