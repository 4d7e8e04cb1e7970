"""BINGO-F image measurements (Pix4D's `*_bingo.txt` export): mm on the sensor, y up, origin at the image centre.

The layout (BINGO-F's image coordinate file, the form Pix4Dmapper writes as `project_name_bingo.txt` in
`1_initial/params`, support.pix4d.com article 203590305 "What is the bingo file generated during Initial
Processing?"): per image a header line `<image> <camera>` (Pix4D writes the image name without its extension,
e.g. `P1060498 H_8.07_6.0525`; BINGO-F itself numbers images, hence the optional map `number -> image name`), then
one line `<point_id> <x_mm> <y_mm>` per measurement, and `-99` ends the image. Pix4D: "The origin of the image
coordinate system is the center of the image. The coordinates are given in millimeters" on the original
(distorted) image. The axes are BINGO's photo coordinates: x right, y up (the article does not say the y
direction; a mirrored block shows as every measurement's y flipped: `y_up=False` reads such a file).

Pixels (dgcal, OpenCV: the top-left pixel's centre is (0, 0), so the image centre is ((w-1)/2, (h-1)/2)):
`u = (w-1)/2 + x_mm / p`, `v = (h-1)/2 - y_mm / p` with `p` the pixel size in mm.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.io.formats import Measurements
from dgcal.fields.io.image_names import image_namer
from dgcal.fields.io.text_files import read_text

END = "-99"
MAX_SENSOR_MM = 1000.0          # |x|, |y| on a sensor (a 230 mm film frame is the largest)
_NUMBER = re.compile(r"^[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?$")


def mm_to_pixels(xy_mm: np.ndarray, image_size: tuple[int, int], pixel_size_mm: float,
                 y_up: bool = True) -> np.ndarray:
    """(N,2) sensor mm (origin at the image centre, y up) -> (N,2) px (OpenCV: top-left pixel centre = 0,0)."""
    w, h = image_size
    xy = np.asarray(xy_mm, float).reshape(-1, 2) / pixel_size_mm
    return np.column_stack([(w - 1) / 2.0 + xy[:, 0], (h - 1) / 2.0 + (-xy[:, 1] if y_up else xy[:, 1])])


def pixels_to_mm(xy_px: np.ndarray, image_size: tuple[int, int], pixel_size_mm: float,
                 y_up: bool = True) -> np.ndarray:
    """(N,2) px (OpenCV convention) -> (N,2) sensor mm (origin at the image centre, y up)."""
    w, h = image_size
    xy = np.asarray(xy_px, float).reshape(-1, 2)
    x = (xy[:, 0] - (w - 1) / 2.0) * pixel_size_mm
    y = (xy[:, 1] - (h - 1) / 2.0) * pixel_size_mm
    return np.column_stack([x, -y if y_up else y])


def is_bingo(path: str | Path) -> bool:
    """True when a text file looks like BINGO image measurements: a header line, `id x y` rows (numbers), `-99`
    or blank lines between images."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(8192).decode("utf-8", "replace").lstrip("\ufeff")
    except OSError:
        return False
    lines = [ln.split() for ln in head.splitlines() if ln.strip()]
    # Pix4D's article shows images separated by blank lines: `-99` is not required to recognise the layout
    if len(lines) < 2 or "," in lines[0][0]:
        return False
    first, rows = lines[0], lines[1:20]
    return len(first) in (1, 2) and first != [END] and len(rows[0]) == 3 and all(
        f == [END] or len(f) in (1, 2) or (len(f) == 3 and _NUMBER.match(f[1]) and _NUMBER.match(f[2]))
        for f in rows)


def read_image_map(path: str | Path) -> dict[str, str]:
    """A map `image number -> image name` from a text file of lines `<number> <name>` (whitespace or comma
    separated, `#` comments): what a BINGO file's numeric image headers are translated with."""
    path = Path(path)
    out: dict[str, str] = {}
    for no, raw in enumerate(read_text(path).splitlines(), start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        f = [t for t in re.split(r"[,\s;]+", s) if t]
        if len(f) < 2:
            raise InputError("expected '<image number> <image name>'", path, no, "image")
        if f[0] in out:
            raise InputError(f"image number {f[0]!r} appears twice", path, no, "image")
        out[f[0]] = " ".join(f[1:])
    if not out:
        raise InputError("no '<image number> <image name>' lines", path)
    return out


def read_bingo(path: str | Path, image_size: tuple[int, int], pixel_size_mm: float,
               image_names: Mapping[str, str] | Sequence[str] | None = None, y_up: bool = True) -> Measurements:
    """Read a BINGO / Pix4D `_bingo.txt` file as measurements in px (OpenCV convention).

    `image_size` (w, h) px and `pixel_size_mm` turn sensor mm into pixels; `image_names` maps the headers'
    image tokens to image names (a dict such as `read_image_map` returns, or the folder's file names matched
    by stem: Pix4D writes `DJI_0001` for `DJI_0001.JPG`)."""
    path = Path(path)
    w, h = validate.image_size(*image_size, path=path, field="image_size")
    p = validate.positive(pixel_size_mm, path, None, "pixel_size_mm", hi=1.0)
    namer = image_namer(image_names, path)
    img, pid, xy, ln = [], [], [], []
    current: str | None = None
    closed = True                   # after -99 or a blank line a header may follow
    for no, raw in enumerate(read_text(path).splitlines(), start=1):
        f = raw.split()
        if not f:
            closed = True
            continue
        if f == [END]:
            if current is None:
                raise InputError("'-99' without an image header before it", path, no, "image")
            current, closed = None, True
            continue
        if len(f) == 3 and current is not None:
            vals = [validate.in_range(t, -MAX_SENSOR_MM, MAX_SENSOR_MM, path, no, n, "mm")
                    for t, n in zip(f[1:], ("x_mm", "y_mm"))]
            img.append(current)
            pid.append(f[0])
            xy.append(vals)
            ln.append(no)
            closed = False
            continue
        if len(f) <= 2 and (closed or current is None):
            current, closed = namer(f[0], no), False
            continue
        what = "'<point_id> <x_mm> <y_mm>'" if current is not None else "an image header '<image> <camera>'"
        raise InputError(f"expected {what}, got {len(f)} field(s)", path, no, "x_mm" if current else "image")
    if not img:
        raise InputError("no BINGO measurements ('<image> <camera>' headers, '<id> <x_mm> <y_mm>' rows, '-99')", path)
    px = mm_to_pixels(np.array(xy), (w, h), p, y_up)
    meas = Measurements(np.array(img, dtype=object), np.array(pid, dtype=object), px,
                        None, np.array(ln), path)
    _no_repeats(meas)
    return meas


def _no_repeats(meas: Measurements) -> None:
    seen: set[tuple[str, str]] = set()
    for i, key in enumerate(zip(meas.image.tolist(), meas.id.tolist())):
        if key in seen:
            raise InputError(f"point {key[1]!r} measured twice in image {key[0]!r}", meas.path, int(meas.lines[i]),
                             "point_id")
        seen.add(key)


def write_bingo(path: str | Path, meas: Measurements, image_size: tuple[int, int], pixel_size_mm: float,
                camera: str = "camera", strip_extension: bool = True, y_up: bool = True) -> None:
    """Write measurements (px) as Pix4D writes a `_bingo.txt`: image name (without extension) and camera per
    header, `id x_mm y_mm` rows, `-99` after each image (atomic)."""
    mm = pixels_to_mm(meas.xy, image_size, pixel_size_mm, y_up)
    images = meas.image.astype(str)
    with atomic_write(path, newline="\n") as fh:
        for name in meas.images():
            head = Path(name).stem if strip_extension else name
            fh.write(f"{head} {camera}\n")
            for i in np.flatnonzero(images == name):
                fh.write(f"{meas.id[i]} {mm[i, 0]:.6f} {mm[i, 1]:.6f}\n")
            fh.write(f"{END}\n")
