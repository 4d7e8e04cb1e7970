"""CSV tables with header, typed columns and errors that name file, line and field (written atomically)."""
from __future__ import annotations

import csv
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from dgcal.fields.errors import InputError
from dgcal.fields.io.text_files import open_text
from dgcal.fields.io.atomic import atomic_write, staged_dir  # noqa: F401  (their old home, still imported from here)


class Table:
    """Columns of a CSV file: `cols[name]` is a NumPy array (float or str), `lines[i]` the file line of row i."""

    def __init__(self, path: Path, cols: dict[str, np.ndarray], lines: np.ndarray):
        self.path, self.cols, self.lines = path, cols, lines

    def __len__(self) -> int:
        return len(self.lines)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.cols[name]

    def __contains__(self, name: str) -> bool:
        return name in self.cols

    def get(self, name: str, default=None):
        return self.cols.get(name, default)


CHUNK_ROWS = 16384      # rows parsed per NumPy conversion: memory stays near the arrays' own size


def _to_float(vals: list[str], path: Path, lines: list[int], name: str) -> np.ndarray:
    # float() and NumPy accept full-width and other Unicode digits ('１２'); a survey file holds ASCII digits only
    if not "".join(vals).isascii():
        i = next(i for i, v in enumerate(vals) if not v.isascii())
        raise InputError(f"not a number (non-ASCII characters): {vals[i]!r}", path, lines[i], name)
    try:
        return np.array(vals, dtype=float)
    except ValueError:
        for i, v in enumerate(vals):
            try:
                float(v)
            except ValueError:
                raise InputError(f"not a number: {v[:40]!r}", path, lines[i], name) from None
        raise


class _Columns:
    """Chunked column builder: numbers become float arrays per chunk, strings are shared between equal cells."""

    def __init__(self, path: Path, header: list[str], wanted: list[str], required: set[str], text: set[str]):
        self.path, self.wanted, self.required, self.text = path, wanted, required, text
        self.index = [header.index(n) for n in wanted]
        self.buf: list[list[str]] = [[] for _ in wanted]
        self.lines: list[int] = []
        self.done: dict[str, list[np.ndarray]] = {n: [] for n in wanted}
        self.done_lines: list[np.ndarray] = []
        self.shared: dict[str, str] = {}

    def add(self, lineno: int, rec: list[str]) -> None:
        n = len(rec)
        for k, j in enumerate(self.index):
            v = rec[j].strip() if j < n else ""
            if not v:
                name = self.wanted[k]
                if name in self.required:
                    raise InputError("missing value", self.path, lineno, name)
                v = "" if name in self.text else "nan"
            self.buf[k].append(v)
        self.lines.append(lineno)
        if len(self.lines) >= CHUNK_ROWS:
            self.flush()

    def flush(self) -> None:
        if not self.lines:
            return
        for k, name in enumerate(self.wanted):
            vals = self.buf[k]
            if name in self.text:
                shared = self.shared
                self.done[name].append(np.array([shared.setdefault(v, v) for v in vals], dtype=object))
            else:
                self.done[name].append(_to_float(vals, self.path, self.lines, name))
            self.buf[k] = []
        self.done_lines.append(np.array(self.lines, dtype=np.int64))
        self.lines = []

    def table(self) -> "Table":
        self.flush()
        cols = {}
        for n in list(self.done):      # one column at a time, its chunks freed: the peak is one column over
            c = self.done.pop(n)
            cols[n] = np.concatenate(c) if c else np.empty(0, dtype=object if n in self.text else float)
            del c
        lines = np.concatenate(self.done_lines) if self.done_lines else np.empty(0, dtype=np.int64)
        self.done_lines = []
        return Table(self.path, cols, lines)


def read_table(path: str | Path, required: Sequence[str], optional: Sequence[str] = (),
               text: Iterable[str] = ("image", "id", "role", "name"), allow_empty: bool = False) -> Table:
    """Read a CSV with a header row; `required` columns must exist, numeric columns are parsed as float.

    Columns named in `text` stay strings; every other required/optional column must parse as a float (ASCII
    digits). Blank lines and lines starting with '#' are skipped. The file is read as a stream, so memory stays
    near the size of the arrays. Raises InputError naming file, line and field.
    """
    path = Path(path)
    text = set(text)
    header: list[str] | None = None
    header_line = 0
    cols: _Columns | None = None
    with open_text(path) as lines:
        reader = csv.reader(lines)
        while True:
            try:
                rec = next(reader)
            except StopIteration:
                break
            except csv.Error as exc:
                raise InputError(f"not a CSV row: {exc}", path, reader.line_num) from None
            if not rec or rec[0].lstrip().startswith("#") or all(not c.strip() for c in rec):
                continue
            if cols is None:
                header, header_line = [c.strip().lower() for c in rec], reader.line_num
                missing = [c for c in required if c not in header]
                if missing:
                    raise InputError(f"missing column(s) {', '.join(missing)} (header has "
                                     f"{', '.join(h[:40] for h in header[:30])})", path, header_line)
                wanted = list(dict.fromkeys(list(required) + [c for c in optional if c in header]))
                cols = _Columns(path, header, wanted, set(required), text)
                continue
            cols.add(reader.line_num, rec)
    if cols is None:
        raise InputError("empty file, expected a header row with columns " + ",".join(required), path)
    tab = cols.table()
    if not len(tab) and not allow_empty:
        raise InputError("no data rows", path)
    return tab


def write_table(path: str | Path, header: Sequence[str], rows: Iterable[Sequence], fmt: str = "%.10g") -> None:
    """Write a CSV atomically; floats are formatted with `fmt`, everything else with str()."""
    def cell(v):
        if isinstance(v, (float, np.floating)):
            return fmt % v
        return str(v)
    with atomic_write(path, newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        for r in rows:
            w.writerow([cell(v) for v in r])
