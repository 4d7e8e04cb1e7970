"""A COLMAP sparse model as tie points: every observation of a 3-D point -> an image measurement (px, OpenCV).

COLMAP's model folder (colmap.github.io/format.html) holds `cameras`, `images` and `points3D` as `.txt` or `.bin`.
`images.txt`: per image a line `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, then a line of `X Y POINT3D_ID`
triples (POINT3D_ID -1: the feature belongs to no 3-D point). The text files are parsed here (errors name the
line); the binary ones are read with pycolmap (`pycolmap.Reconstruction`), which is imported only then.

Pixel convention: COLMAP's image origin is the top-left corner of the image, the centre of the top-left pixel is
(0.5, 0.5) (a COLMAP camera's default principal point is (w/2, h/2); dgcal's
`calib.camera.conversions.COLMAP_PIXEL_SHIFT`); dgcal's origin is that pixel's centre, so 0.5 px is subtracted.
Tie point ids are `<prefix><POINT3D_ID>` (default `colmap_`) so they cannot collide with ground point ids.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.formats import Measurements
from dgcal.fields.io.text_files import read_text

PIXEL_SHIFT = 0.5
ID_PREFIX = "colmap_"


def colmap_model_files(path: str | Path) -> tuple[Path, str] | None:
    """(model folder, 'txt' or 'bin') when `path` is a COLMAP model folder or one of its images/points3D files."""
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    if p.is_file() and p.stem not in ("images", "points3D", "cameras"):
        return None
    for ext in ("txt", "bin"):
        if (folder / f"images.{ext}").is_file() and (folder / f"points3D.{ext}").is_file():
            if p.is_file() and p.suffix != f".{ext}":
                continue
            return folder, ext
    return None


def read_colmap_tracks(path: str | Path, min_track_length: int = 2, id_prefix: str = ID_PREFIX) -> Measurements:
    """Tie-point measurements (px, OpenCV convention) of a COLMAP model folder (text or binary).

    Only features of 3-D points seen in at least `min_track_length` images are kept."""
    found = colmap_model_files(path)
    if found is None:
        raise InputError("not a COLMAP model (a folder with images.txt and points3D.txt, or .bin)", path,
                         field="measurements")
    folder, ext = found
    img, pid, xy, lines = _read_text(folder / "images.txt") if ext == "txt" else _read_binary(folder)
    img, pid, xy = np.asarray(img, dtype=object), np.asarray(pid, np.int64), np.asarray(xy, float).reshape(-1, 2)
    lines = np.asarray(lines, np.int64)
    if len(pid):
        _, inv, counts = np.unique(pid, return_inverse=True, return_counts=True)
        keep = counts[inv] >= min_track_length
        img, pid, xy, lines = img[keep], pid[keep], xy[keep], lines[keep]
    if not len(pid):
        raise InputError(f"no 3-D point is observed in {min_track_length} or more images", folder / f"images.{ext}",
                         field="POINT3D_ID")
    ids = np.array([f"{id_prefix}{k}" for k in pid.tolist()], dtype=object)
    meas = Measurements(img, ids, xy - PIXEL_SHIFT, None, lines, folder / f"images.{ext}")
    key = pid * (1 << 20) + np.unique(img.astype(str), return_inverse=True)[1]
    order = np.argsort(key, kind="stable")
    dup = order[1:][key[order][1:] == key[order][:-1]]
    if dup.size:
        rep = int(dup.min())
        raise InputError(f"3-D point {pid[rep]} observed twice in image {img[rep]!r}", meas.path,
                         int(lines[rep]) or None, "POINT3D_ID")
    return meas


def _read_text(path: Path) -> tuple[list, list, list, list]:
    """Observations of 3-D points in images.txt: (image names, point ids, xy (COLMAP px), file lines)."""
    img, pid, xy, lines = [], [], [], []
    rows = [(no, s) for no, s in enumerate(read_text(path).splitlines(), start=1) if not s.lstrip().startswith("#")]
    k = 0
    while k < len(rows):
        no, head = rows[k]
        if not head.strip():
            k += 1
            continue
        f = head.split()
        if len(f) < 10:
            raise InputError(f"expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', got {len(f)} fields", path, no,
                             "NAME")
        name = " ".join(f[9:])
        if k + 1 >= len(rows):
            raise InputError(f"image {name!r} has no POINTS2D line after it", path, no, "POINTS2D")
        no2, obs = rows[k + 1]
        vals = obs.split()
        if len(vals) % 3:
            raise InputError(f"POINTS2D must be (X, Y, POINT3D_ID) triples, got {len(vals)} numbers", path, no2,
                             "POINTS2D")
        if vals:
            try:
                a = np.array(vals, float).reshape(-1, 3)
            except ValueError:
                bad = next(v for v in vals if not _is_float(v))
                raise InputError(f"not a number: {bad[:40]!r}", path, no2, "POINTS2D") from None
            validate.values_in_range(a[:, :2], -validate.MAX_PIXEL, validate.MAX_PIXEL, path, "POINTS2D",
                                     np.full(len(a), no2), unit="px")
            validate.whole_values(a[:, 2], -1, 2 ** 63 - 1, path, "POINT3D_ID", np.full(len(a), no2))
            has = a[:, 2] >= 0
            img += [name] * int(has.sum())
            pid += a[has, 2].astype(np.int64).tolist()
            xy += a[has, :2].tolist()
            lines += [no2] * int(has.sum())
        k += 2
    return img, pid, xy, lines


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _read_binary(folder: Path) -> tuple[list, list, list, list]:
    """Observations of 3-D points in a binary model, read with pycolmap."""
    import pycolmap          # heavy, and only for binary models
    try:
        rec = pycolmap.Reconstruction(str(folder))
    except Exception as exc:  # pycolmap raises its own C++ exceptions for damaged files
        raise InputError(f"COLMAP cannot read the model ({str(exc).splitlines()[0][:120]})", folder,
                         field="measurements") from None
    img, pid, xy = [], [], []
    for image in rec.images.values():
        for p in image.points2D:
            if p.has_point3D():
                img.append(image.name)
                pid.append(int(p.point3D_id))
                xy.append(np.asarray(p.xy, float))
    if xy:
        validate.values_in_range(np.array(xy), -validate.MAX_PIXEL, validate.MAX_PIXEL, folder / "images.bin",
                                 "xy", unit="px")
    return img, pid, xy, [0] * len(img)
