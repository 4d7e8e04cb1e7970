"""CSV tables with header, typed columns and errors that name file, line and field (written atomically)."""
from __future__ import annotations

import csv
from operator import itemgetter
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from dgcal.fields.errors import InputError
from dgcal.fields.io.labels import Labels
from dgcal.fields.io.text_files import count_lines, open_text
from dgcal.fields.io.atomic import atomic_write, staged_dir  # noqa: F401  (their old home, still imported from here)


class Table:
    """Columns of a CSV file: `cols[name]` is a NumPy array (float or str) or `Labels` (coded text columns),
    `lines[i]` the file line of row i."""

    def __init__(self, path: Path, cols: dict[str, np.ndarray], lines: np.ndarray):
        self.path, self.cols, self.lines = path, cols, lines
        self.groups: dict[str, np.ndarray] = {}

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
    """Column builder over a stream of rows, parsed CHUNK_ROWS at a time straight into arrays sized once for the
    file's line count (no lists of chunks joined at the end: the memory is the arrays' own). Numbers become
    floats, strings are shared between equal cells, `coded` text columns become int32 codes into their distinct
    strings (`Labels`), and the numeric columns of a group share one (n, k) array (x and y as one xy)."""

    def __init__(self, path: Path, header: list[str], wanted: list[str], required: set[str], text: set[str],
                 coded: set[str], groups: dict[str, tuple[str, ...]], capacity: int):
        self.path, self.wanted, self.required, self.text = path, wanted, required, text
        self.index = [header.index(n) for n in wanted]
        self.width = max(self.index) + 1
        self.codes: dict[str, dict[str, int]] = {n: {} for n in wanted if n in coded}
        self.shared: dict[str, str] = {}
        self.rows: list[list[str]] = []
        self.row_lines: list[int] = []
        self.n = 0
        self.groups = {g: list(cols) for g, cols in groups.items() if any(c in wanted for c in cols)}
        self._allocate(max(capacity, 1))

    def _allocate(self, cap: int) -> None:
        """Arrays for `cap` rows (np.empty: pages a file never fills are never touched), the rows so far kept."""
        old = getattr(self, "store", None)
        store: dict[str, np.ndarray] = {}
        grouped = {}
        for g, cols in self.groups.items():
            # a column of the group that the file lacks stays NaN
            complete = all(c in self.wanted for c in cols)
            arr = np.empty((cap, len(cols))) if complete else np.full((cap, len(cols)), np.nan)
            if old is not None:
                arr[:self.n] = self.group_store[g][:self.n]
            grouped[g] = arr
            for j, c in enumerate(cols):
                if c in self.wanted:
                    store[c] = arr[:, j]
        for name in self.wanted:
            if name in store:
                continue
            dtype = np.int32 if name in self.codes else object if name in self.text else float
            store[name] = np.empty(cap, dtype)
            if old is not None:
                store[name][:self.n] = old[name][:self.n]
        lines = np.empty(cap, np.int32 if cap < 2**31 else np.int64)
        if old is not None:
            lines[:self.n] = self.lines[:self.n]
        self.store, self.group_store, self.lines, self.cap = store, grouped, lines, cap

    def _column(self, k: int) -> list[str]:
        """The stripped cells of wanted column k of the buffered rows; a missing required value is an error."""
        name = self.wanted[k]
        vals = list(map(str.strip, map(itemgetter(self.index[k]), self.rows)))
        if "" in vals:
            i = vals.index("")
            if name in self.required:
                raise InputError("missing value", self.path, self.row_lines[i], name)
            fill = "" if name in self.text else "nan"
            vals = [v or fill for v in vals]
        return vals

    def flush(self) -> None:
        if not self.rows:
            return
        if min(map(len, self.rows)) < self.width:      # short rows: their missing cells are empty
            self.rows[:] = [r + [""] * (self.width - len(r)) if len(r) < self.width else r for r in self.rows]
        k_rows = len(self.rows)
        if self.n + k_rows > self.cap:                 # more rows than lines counted (the file grew): grow
            self._allocate(2 * (self.n + k_rows))
        s = slice(self.n, self.n + k_rows)
        for k, name in enumerate(self.wanted):
            vals = self._column(k)
            if name in self.codes:
                index = self.codes[name]
                put = index.setdefault
                self.store[name][s] = np.fromiter((put(v, len(index)) for v in vals), np.int32, k_rows)
            elif name in self.text:
                shared = self.shared
                self.store[name][s] = [shared.setdefault(v, v) for v in vals]
            else:
                self.store[name][s] = _to_float(vals, self.path, self.row_lines, name)
        self.lines[s] = self.row_lines
        self.n += k_rows
        self.rows.clear()          # in place: the reading loop appends to these very lists
        self.row_lines.clear()

    def table(self) -> "Table":
        self.flush()
        n = self.n

        def trim(a: np.ndarray) -> np.ndarray:
            # a view keeps the untouched tail unresident; copy only when the file had many non-data lines
            return a[:n] if n >= 0.75 * self.cap else a[:n].copy()
        cols = {}
        groups = {g: trim(arr) for g, arr in self.group_store.items()}
        for name in self.wanted:
            g = next((g for g, c in self.groups.items() if name in c), None)
            if g is not None:
                cols[name] = groups[g][:, self.groups[g].index(name)]
            elif name in self.codes:
                names = np.empty(len(self.codes[name]), dtype=object)
                names[:] = list(self.codes[name])
                cols[name] = Labels(trim(self.store[name]), names)
            else:
                cols[name] = trim(self.store[name])
        tab = Table(self.path, cols, trim(self.lines))
        tab.groups = groups
        return tab


def read_table(path: str | Path, required: Sequence[str], optional: Sequence[str] = (),
               text: Iterable[str] = ("image", "id", "role", "name"), allow_empty: bool = False,
               coded: Iterable[str] = (), groups: dict[str, tuple[str, ...]] | None = None) -> Table:
    """Read a CSV with a header row; `required` columns must exist, numeric columns are parsed as float.

    Columns named in `text` stay strings (those also in `coded` come back as `Labels`: int32 codes into their
    distinct strings); every other required/optional column must parse as a float (ASCII digits). `groups`
    names numeric columns stored together, e.g. {"xy": ("x", "y")}: `tab.groups["xy"]` is one (n,2) array (NaN for
    a column the file lacks) and `tab["x"]` a view of it. Blank lines and lines starting with '#' are skipped. The
    file is read as a stream into arrays sized by its line count, so memory stays near the size of the arrays.
    Raises InputError naming file, line and field.
    """
    path = Path(path)
    text = set(text)
    header: list[str] | None = None
    header_line = 0
    cols: _Columns | None = None
    capacity = count_lines(path)
    with open_text(path) as lines:
        reader = csv.reader(lines)
        try:
            for rec in reader:
                if not rec or not "".join(rec).strip() or rec[0].lstrip().startswith("#"):
                    continue
                if cols is None:
                    header, header_line = [c.strip().lower() for c in rec], reader.line_num
                    missing = [c for c in required if c not in header]
                    if missing:
                        raise InputError(f"missing column(s) {', '.join(missing)} (header has "
                                         f"{', '.join(h[:40] for h in header[:30])})", path, header_line)
                    wanted = list(dict.fromkeys(list(required) + [c for c in optional if c in header]))
                    cols = _Columns(path, header, wanted, set(required), text, set(coded) & text, groups or {},
                                    capacity)
                    rows, row_lines = cols.rows, cols.row_lines
                    continue
                rows.append(rec)
                row_lines.append(reader.line_num)
                if len(rows) >= CHUNK_ROWS:
                    cols.flush()
        except csv.Error as exc:
            raise InputError(f"not a CSV row: {exc}", path, reader.line_num) from None
    if cols is None:
        raise InputError("empty file, expected a header row with columns " + ",".join(required), path)
    tab = cols.table()
    if not len(tab) and not allow_empty:
        raise InputError("no data rows", path)
    return tab


def write_table(path: str | Path, header: Sequence[str], rows: Iterable[Sequence], fmt: str = "%.10g") -> None:
    """Write a CSV atomically; floats are formatted with `fmt`, everything else with str()."""
    floats = (float, np.floating)
    with atomic_write(path, newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        w.writerows([fmt % v if isinstance(v, floats) else str(v) for v in r] for r in rows)


def formatted(values, fmt: str) -> list[str]:
    """The cells of a numeric column: each value of `values` (array-like) formatted with `fmt` (e.g. "%.4f")."""
    return [fmt % v for v in np.asarray(values).tolist()]


def write_columns(path: str | Path, header: Sequence[str], columns: Sequence[Sequence]) -> None:
    """Write a CSV atomically from columns of cells (strings, e.g. `formatted`, or values written with str()),
    one per header name: the rows are assembled in C (csv's writerows), not cell by cell in Python."""
    if len(columns) != len(header):
        raise ValueError(f"{len(columns)} columns for {len(header)} header names")
    with atomic_write(path, newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        w.writerows(zip(*columns))
