"""CSV tables with header, typed columns and errors that name file, line and field (written atomically)."""
from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from dgcal.fields.errors import InputError
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


def read_table(path: str | Path, required: Sequence[str], optional: Sequence[str] = (),
               text: Iterable[str] = ("image", "id", "role", "name"), allow_empty: bool = False) -> Table:
    """Read a CSV with a header row; `required` columns must exist, numeric columns are parsed as float.

    Columns named in `text` stay strings; every other required/optional column must parse as a float.
    Blank lines and lines starting with '#' are skipped. Raises InputError naming file, line and field.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path)
    try:
        raw = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read: {exc}", path) from None
    rows: list[tuple[int, list[str]]] = []
    header: list[str] | None = None
    header_line = 0
    for lineno, rec in enumerate(csv.reader(io.StringIO(raw)), start=1):
        if not rec or all(not c.strip() for c in rec) or rec[0].lstrip().startswith("#"):
            continue
        rec = [c.strip() for c in rec]
        if header is None:
            header, header_line = [c.lower() for c in rec], lineno
            continue
        rows.append((lineno, rec))
    if header is None:
        raise InputError("empty file, expected a header row with columns " + ",".join(required), path)
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)} (header has {', '.join(header)})",
                         path, header_line)
    if not rows and not allow_empty:
        raise InputError("no data rows", path)
    text = set(text)
    wanted = list(required) + [c for c in optional if c in header]
    cols: dict[str, np.ndarray] = {}
    lines = np.array([ln for ln, _ in rows], dtype=int)
    for name in wanted:
        j = header.index(name)
        vals = []
        for ln, rec in rows:
            if j >= len(rec) or rec[j] == "":
                if name in required:
                    raise InputError("missing value", path, ln, name)
                vals.append("" if name in text else "nan")
            else:
                vals.append(rec[j])
        if name in text:
            cols[name] = np.array(vals, dtype=object)
        else:
            out = np.empty(len(vals))
            for i, v in enumerate(vals):
                try:
                    out[i] = float(v)
                except ValueError:
                    raise InputError(f"not a number: {v!r}", path, int(lines[i]), name) from None
            cols[name] = out
    return Table(path, cols, lines)


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
