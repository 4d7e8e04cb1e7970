"""The image files of a folder: one suffix list and one error for every verb that takes an image folder."""
from __future__ import annotations

from pathlib import Path

from dgcal.fields.errors import InputError

# what OpenCV decodes (detection, tie points, optic flow)
RASTER_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".pgm", ".ppm")
# camera raw files: named and time-stamped (events, time sync) but not decoded
RAW_SUFFIXES = (".dng", ".cr2", ".nef", ".arw")


def list_image_files(folder: str | Path, field: str = "images", raw: bool = False) -> list[Path]:
    """The image files of `folder` (not recursive; suffix case-insensitive; `raw` adds camera raw files), sorted by
    name. InputError naming the folder and the option's `field` (the CLI shows its flag) when `folder` is not a
    folder or holds no image."""
    folder = Path(folder)   # named in the message, not as the error's file: the CLI then names the option's flag
    suffixes = RASTER_SUFFIXES + (RAW_SUFFIXES if raw else ())
    if not folder.is_dir():
        what = "does not exist" if not folder.exists() else "is a file, not a folder"
        raise InputError(f"{folder}: the image folder {what}", field=field)
    files = sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in suffixes), key=lambda p: p.name)
    if not files:
        raise InputError(f"{folder}: no images ({', '.join(suffixes)}) in the folder", field=field)
    return files


def list_image_names(folder: str | Path, field: str = "images", raw: bool = False) -> list[str]:
    """The file names of `list_image_files(folder, field, raw)`, sorted."""
    return [p.name for p in list_image_files(folder, field, raw)]
