"""Outputs that appear whole or not at all: atomic files and atomic output folders.

`atomic_write(path)` writes through a temporary file renamed into place on success.

`staged_dir(out)` yields a staging folder beside `out` (same file system); on success it becomes `out`:
- `out` does not exist: one rename;
- `out` holds only a previous output of dgcal (every entry is listed in its manifest `.dgcal-outputs.json`):
  `out` is renamed aside, the staging folder renamed into place, the old folder removed — an interrupted
  run leaves the old outputs or the new ones, never a mixture;
- `out` holds other files too (a user's folder): the new files are moved in one by one, and the manifest,
  written last, is what marks the set complete (`read_manifest`).
A stale staging or set-aside folder of an interrupted run is cleaned up at the next `staged_dir(out)`: the
old outputs are put back when the new ones never arrived.
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Iterator

MANIFEST = ".dgcal-outputs.json"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "w", **kw) -> Iterator:
    """Open `path` for writing through a temporary file renamed into place only on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; outputs should get the user's usual mode
    try:
        with open(tmp, mode, **kw) as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _siblings(out: Path, kind: str) -> list[Path]:
    return sorted(out.parent.glob(f".{out.name}.{kind}.*")) if out.parent.is_dir() else []


def clean_stale(out: str | Path) -> None:
    """Remove what an interrupted `staged_dir(out)` left: staging folders, and set-aside old outputs (put back
    when `out` itself is missing, i.e. the run died between its two renames)."""
    out = Path(out)
    for p in _siblings(out, "staging"):
        shutil.rmtree(p, ignore_errors=True)
    for p in _siblings(out, "old"):
        if not out.exists():
            with contextlib.suppress(OSError):
                os.replace(p, out)
                continue
        shutil.rmtree(p, ignore_errors=True)
    if out.is_dir():   # staging folders of the earlier layout, inside the output folder
        for p in out.glob(".staging.*"):
            shutil.rmtree(p, ignore_errors=True)


def read_manifest(out: str | Path) -> dict | None:
    """The manifest of a complete dgcal output folder (files, time), or None when there is none."""
    p = Path(out) / MANIFEST
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _ours(out: Path) -> bool:
    """True when every entry of `out` is listed in its manifest (a folder dgcal wrote and nothing else)."""
    m = read_manifest(out)
    if m is None:
        return not any(out.iterdir())
    listed = set(m.get("files", [])) | {MANIFEST}
    top = {p.split("/")[0] for p in listed}
    return all(p.name in top for p in out.iterdir())


def _write_manifest(folder: Path, files: list[str]) -> None:
    with atomic_write(folder / MANIFEST) as fh:
        json.dump({"files": files, "written_unix": time.time()}, fh, indent=1)


@contextlib.contextmanager
def staged_dir(out: str | Path) -> Iterator[Path]:
    """Yield a staging folder whose contents become `out` only if the block succeeds (see the module doc)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    clean_stale(out)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.staging.", dir=out.parent))
    try:
        yield tmp
        files = sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file())
        if not out.exists():
            _write_manifest(tmp, files)
            os.replace(tmp, out)
        elif out.is_dir() and _ours(out):
            _write_manifest(tmp, files)
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=out.parent))
            os.rmdir(old)
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            # a folder holding the user's own files: merge, the manifest last marks the set complete
            with contextlib.suppress(OSError):
                (out / MANIFEST).unlink()
            for p in sorted(tmp.rglob("*")):
                dest = out / p.relative_to(tmp)
                if p.is_dir():
                    dest.mkdir(parents=True, exist_ok=True)
                else:
                    dest.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(p, dest)
            _write_manifest(out, files)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
