"""Outputs that appear whole or not at all: atomic files and atomic output folders.

`atomic_write(path)` writes through a temporary file renamed into place on success.

`staged_dir(out)` yields a staging folder beside `out` (same file system); on success it becomes `out`:
- `out` does not exist: one rename;
- `out` holds only a previous output of dgcal (every entry is listed in its manifest `.dgcal-outputs.json`):
  `out` is renamed aside, the staging folder renamed into place, the old folder removed — an interrupted
  run leaves the old outputs or the new ones, never a mixture;
- `out` holds other files too (a user's folder, or `merge=True`: a campaign folder holding the steps' folders
  beside its report): the new files are moved in one by one, and the manifest, written last, is what marks
  the set complete (`read_manifest`).
`output_lock(out)` (taken by `staged_dir`, by a verb for its whole run: `verb_output_lock`, and by a campaign)
refuses a second dgcal process writing into the same folder: one-line InputError naming the folder and the
process holding it. Errors of the file system (read-only, full disk, `out` a file) are one-line InputErrors
naming the folder, not internal errors.
The manifest lists every file with its size and SHA-256 (`entries`), so a folder can be checked against it
(`manifest_problems`). A stale staging or set-aside folder of an interrupted run, and the temporary files of
an interrupted `atomic_write` in `out`, are cleaned up at the next `staged_dir(out)` (or `clean_stale(out)`):
the old outputs are put back when the new ones never arrived.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import os
import re
import shutil
import tempfile
import time
from pathlib import Path
from typing import Iterator

from dgcal.fields.errors import InputError

MANIFEST = ".dgcal-outputs.json"
# in a folder while new files are merged into it (a user's folder, a campaign's): readers of dgcal's files refuse a
# folder that holds it (an interrupted merge leaves new files beside old ones: fields.io.text_files)
INCOMPLETE = ".dgcal-incomplete"


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


# what `atomic_write` leaves when killed: .NAME.XXXXXXXX.part (mkstemp's eight random characters)
_PARTIAL = re.compile(r"^\..+\.[a-z0-9_]{8}\.part$")


def _siblings(out: Path, kind: str) -> list[Path]:
    return sorted(out.parent.glob(f".{out.name}.{kind}.*")) if out.parent.is_dir() else []


def clean_stale(out: str | Path) -> None:
    """Remove what an interrupted `staged_dir(out)` left: staging folders, and set-aside old outputs (put back
    when `out` itself is missing, i.e. the run died between its two renames)."""
    out = Path(out)
    _remove_stale_lock(out)
    for p in _siblings(out, "staging"):
        shutil.rmtree(p, ignore_errors=True)
    for p in _siblings(out, "old"):
        if not out.exists():
            with contextlib.suppress(OSError):
                os.replace(p, out)
                continue
        shutil.rmtree(p, ignore_errors=True)
    if out.is_dir():   # staging folders of the earlier layout, inside the output folder; killed atomic writes
        for p in out.glob(".staging.*"):
            shutil.rmtree(p, ignore_errors=True)
        for p in out.glob(".*.part"):
            if _PARTIAL.match(p.name) and p.is_file():
                with contextlib.suppress(OSError):
                    p.unlink()


def _remove_stale_lock(out: Path) -> None:
    """The lock file of a killed writer (no process holds it) removed; a held one is left alone."""
    key = lock_path(out)
    if not key.is_file() or str(key.resolve()) in _HELD:
        return
    try:
        fd = os.open(key, os.O_RDWR)
    except OSError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with contextlib.suppress(OSError):
            if os.fstat(fd).st_ino == os.stat(key).st_ino:
                os.unlink(key)
    except OSError:
        pass                               # held by a live writer
    finally:
        os.close(fd)


def read_manifest(out: str | Path) -> dict | None:
    """The manifest of a complete dgcal output folder (files, time), or None when there is none."""
    p = Path(out) / MANIFEST
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a file's contents."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def manifest_problems(out: str | Path, hashes: bool = False) -> list[str]:
    """What keeps `out` from being the complete output set its manifest describes: no manifest, a listed
    file missing or of another size (or, with `hashes`, other contents). Empty when the folder is whole.
    Manifests of earlier versions (no `entries`) are checked for the presence of their files only."""
    out = Path(out)
    m = read_manifest(out)
    if m is None:
        return [f"{out}: no manifest {MANIFEST} (incomplete or not written by dgcal)"]
    entries = m.get("entries") or {f: None for f in m.get("files", [])}
    problems = []
    for name, e in entries.items():
        p = out / name
        if not p.is_file():
            problems.append(f"{p}: listed in the manifest but missing")
        elif e is not None and p.stat().st_size != e.get("size"):
            problems.append(f"{p}: size {p.stat().st_size} B, the manifest says {e.get('size')} B")
        elif e is not None and hashes and file_sha256(p) != e.get("sha256"):
            problems.append(f"{p}: contents differ from the manifest's SHA-256")
    return problems


def _ours(out: Path) -> bool:
    """True when every entry of `out` is listed in its manifest (a folder dgcal wrote and nothing else)."""
    m = read_manifest(out)
    if m is None:
        return not any(out.iterdir())
    listed = set(m.get("files", [])) | {MANIFEST}
    top = {p.split("/")[0] for p in listed}
    return all(p.name in top for p in out.iterdir())


def _write_manifest(folder: Path, files: list[str], entries: dict) -> None:
    with atomic_write(folder / MANIFEST) as fh:
        json.dump({"files": files, "entries": entries, "written_unix": time.time()}, fh, indent=1)


# errors of the file system that are the user's to fix (not dgcal's bugs)
_OS_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EDQUOT, errno.EEXIST, errno.ENOTDIR,
              errno.EISDIR, errno.ENAMETOOLONG, errno.ENOENT, errno.EMLINK, errno.EFBIG}
_HELD: dict[str, int] = {}        # lock files this process (or the parent it was forked from) holds -> depth


def lock_path(out: str | Path) -> Path:
    """The lock file of an output folder: `.NAME.lock` beside it."""
    out = Path(out)
    return out.parent / f".{out.name}.lock"


@contextlib.contextmanager
def os_errors_named(out: str | Path, doing: str = "write the outputs") -> Iterator[None]:
    """Within the block, an OSError of the file system (full disk, read-only, permission, a file where a folder
    should be) becomes a one-line InputError naming `out`."""
    try:
        yield
    except OSError as exc:
        if exc.errno not in _OS_ERRNOS:
            raise
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        raise InputError(f"cannot {doing}: {exc.strerror or exc}{where}", out) from None


LOCK_WAIT_S = 3.0     # a killed run's forked children release the lock a moment after their parent died


def _flock_within(fd: int, wait_s: float) -> bool:
    """Take an exclusive lock on `fd`, retrying for up to `wait_s` seconds; False when another process holds it."""
    end = time.monotonic() + wait_s
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if time.monotonic() >= end:
                return False
            time.sleep(0.05)


@contextlib.contextmanager
def output_lock(out: str | Path) -> Iterator[None]:
    """Hold the lock of output folder `out` for the block; InputError when another process holds it (re-entrant
    within a process and the children it forks, which work for it)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError("is a file, not a folder: give a folder for the outputs", out)
    with os_errors_named(out, "create the output folder's parent"):
        out.parent.mkdir(parents=True, exist_ok=True)
    key = str(lock_path(out).resolve())
    if key in _HELD:
        _HELD[key] += 1
        try:
            yield
        finally:
            _HELD[key] -= 1
        return
    while True:
        with os_errors_named(out, "lock the output folder"):
            fd = os.open(key, os.O_RDWR | os.O_CREAT, 0o666 & ~_umask())
        if not _flock_within(fd, LOCK_WAIT_S):
            holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip() or "unknown"
            os.close(fd)
            raise InputError(f"another dgcal run (process {holder}) is writing into this folder: wait for it to end "
                             "or give another output folder", out) from None
        try:      # the holder before us may have removed the file between our open and our lock: then again
            same = os.fstat(fd).st_ino == os.stat(key).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        _HELD[key] = 1
        try:
            yield
        finally:
            _HELD.pop(key, None)
            with contextlib.suppress(OSError):
                os.unlink(key)   # before the unlock: a process that opened it meanwhile sees the inode go, retries
    finally:
        os.close(fd)


@contextlib.contextmanager
def verb_output_lock(out: str | Path | None) -> Iterator[None]:
    """The lock of a verb's `--out` folder held for the verb's whole run, so that a second run into the same folder
    is refused at its start (not after computing for minutes, nor allowed to replace the first's outputs); nothing
    when there is no `--out` or it names an existing file (a verb writing one file, such as `compare`)."""
    if out is None or Path(out).is_file():
        yield
        return
    with output_lock(out):
        yield


@contextlib.contextmanager
def staged_dir(out: str | Path, merge: bool = False) -> Iterator[Path]:
    """Yield a staging folder whose contents become `out` only if the block succeeds (see the module doc);
    `merge`: always move the new files into `out` (never swap the folder), for a folder holding more. The folder
    is locked meanwhile (`output_lock`); file-system errors are one-line InputErrors naming `out`."""
    out = Path(out)
    with output_lock(out), os_errors_named(out):
        with _staged(out, merge) as tmp:
            yield tmp


@contextlib.contextmanager
def _staged(out: Path, merge: bool) -> Iterator[Path]:
    clean_stale(out)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.staging.", dir=out.parent))
    os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700; the output folder should get the user's usual mode
    try:
        yield tmp
        files = sorted(p.relative_to(tmp).as_posix() for p in tmp.rglob("*") if p.is_file())
        entries = {f: {"size": (tmp / f).stat().st_size, "sha256": file_sha256(tmp / f)} for f in files}
        if not out.exists():
            _write_manifest(tmp, files, entries)
            os.replace(tmp, out)
        elif out.is_dir() and not merge and _ours(out):
            _write_manifest(tmp, files, entries)
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=out.parent))
            os.rmdir(old)
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            # a folder holding the user's own files: merge, the manifest last marks the set complete; the marker
            # first tells readers that an interrupted merge left a mixture
            (out / INCOMPLETE).write_text(f"dgcal process {os.getpid()} is merging new outputs into this folder\n")
            with contextlib.suppress(OSError):
                (out / MANIFEST).unlink()
            for p in sorted(tmp.rglob("*")):
                dest = out / p.relative_to(tmp)
                if p.is_dir():
                    dest.mkdir(parents=True, exist_ok=True)
                else:
                    dest.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(p, dest)
            _write_manifest(out, files, entries)
            (out / INCOMPLETE).unlink()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
