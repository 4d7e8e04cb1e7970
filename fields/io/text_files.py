"""Opening users' text files: decoding, permission and size problems become one InputError naming the file."""
from __future__ import annotations

import contextlib
from pathlib import Path
from typing import IO, Iterator

from dgcal.fields.errors import InputError
from dgcal.fields.io.atomic import INCOMPLETE


def _check_file(path: Path) -> None:
    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError("is a folder, expected a file", path)
    if (path.parent / INCOMPLETE).exists():
        raise InputError("the dgcal run writing this folder was interrupted (or is still running): its files may mix "
                         "two runs; run that step again", path)


def read_text(path: str | Path, encoding: str = "utf-8-sig") -> str:
    """The whole text of a file; undecodable bytes, permissions and missing files raise InputError (line named)."""
    path = Path(path)
    _check_file(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path) from None
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise InputError(f"not {encoding.replace('-sig', '')} text (byte 0x{data[exc.start]:02x})", path,
                         line) from None


def count_lines(path: str | Path, block: int = 1 << 20) -> int:
    """Lines in a file (its newlines + 1): an upper bound of its rows, counted on the bytes."""
    path = Path(path)
    _check_file(path)
    n = 1
    try:
        with open(path, "rb") as fh:
            for chunk in iter(lambda: fh.read(block), b""):
                n += chunk.count(b"\n")
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path) from None
    return n


class _LineCounter:
    """Wraps a text stream to remember how many lines were read, so decode errors can name their line."""

    def __init__(self, fh: IO[str]):
        self.fh, self.line = fh, 0

    def __iter__(self):
        return self

    def __next__(self) -> str:
        s = next(self.fh)
        self.line += 1
        return s


def _bad_line(path: Path, encoding: str) -> int | None:
    # the decoder works ahead of the line being read, so the line at fault is found again from the bytes
    with open(path, "rb") as fh:
        for no, raw in enumerate(fh, start=1):
            try:
                raw.decode(encoding if no == 1 else encoding.replace("-sig", ""))
            except UnicodeDecodeError:
                return no
    return None


@contextlib.contextmanager
def open_text(path: str | Path, encoding: str = "utf-8-sig") -> Iterator[_LineCounter]:
    """Iterate a text file's lines in a stream; decoding and OS errors inside become InputError with the line."""
    path = Path(path)
    _check_file(path)
    try:
        fh = open(path, encoding=encoding, newline="")
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path) from None
    lines = _LineCounter(fh)
    try:
        with fh:
            yield lines
    except UnicodeDecodeError:
        raise InputError(f"not {encoding.replace('-sig', '')} text", path, _bad_line(path, encoding)) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path, lines.line + 1) from None
