"""Checks of the values read from users' files: numbers, finite, positive, in a range, whole, image sizes.

Every reader of dgcal checks what it read here, once, at the edge: a value that fails raises one InputError
naming the file, line and field, so nothing non-finite or physically absurd (a NaN lever arm, a 1e308 GPS
week, a negative focal length) reaches the adjustments, where it would surface as an OverflowError, a
LinAlgError, a native abort or, worst, a plausible-looking wrong result. The scalar checks return the value
(as float or int); the array checks take the file lines of the rows (`lines`) to name the first bad one.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.errors import InputError

# physical limits of what dgcal reads (generous: they catch nonsense, not unusual data)
MAX_IMAGE_SIDE = 100_000          # px, a side of an image (the largest aerial sensors are ~ 20 000 px)
MAX_PIXEL = 1_000_000.0           # px, |image coordinate| (measurements may lie a little outside the frame)
MAX_COORDINATE_M = 1e9            # m, |map, ECEF or local coordinate|
MAX_HEIGHT_M = 1e6                # m, |ellipsoidal height| of a trajectory or a ground point
MAX_SPEED_M_S = 1e4               # m/s, |velocity component|
MAX_ANGLE_DEG = 1e5               # deg, |attitude angle| (unwrapped headings included)
MAX_LEVER_ARM_M = 1000.0          # m, |lever-arm component|
MAX_DELAY_S = 3600.0              # s, |exposure delay|
GPS_WEEK_MAX = 5000               # GPS weeks (week 5000 is the year 2075)


def _fmt(v) -> str:
    if isinstance(v, (int, np.integer)) and not isinstance(v, bool) and abs(int(v)) > 10 ** 15:
        v = float(v)
    s = f"{v:.6g}" if isinstance(v, float) else repr(v)
    return s if len(s) <= 40 else s[:37] + "..."


_YAML_SPECIALS = {".nan": math.nan, ".inf": math.inf, "+.inf": math.inf, "-.inf": -math.inf}


def number(value, path: str | Path | None = None, line: int | None = None, field: str | None = None) -> float:
    """`value` as a float: a Python/NumPy number or numeric text in ASCII digits (booleans, lists, None and
    '１２' are not numbers). The result may be NaN or inf; `finite` rejects those."""
    if isinstance(value, (bool, np.bool_)) or value is None:
        raise InputError(f"must be a number, not {_fmt(value)}", path, line, field)
    if isinstance(value, (int, float, np.integer, np.floating)):
        try:
            return float(value)
        except OverflowError:
            raise InputError(f"number out of range: {_fmt(value)}", path, line, field) from None
    if isinstance(value, str):
        s = value.strip()
        if not s.isascii():
            raise InputError(f"not a number (non-ASCII characters): {_fmt(value)}", path, line, field)
        if s.lower() in _YAML_SPECIALS:   # OpenCV's YAML writes .Nan, .Inf
            return _YAML_SPECIALS[s.lower()]
        try:
            return float(s)
        except ValueError:
            raise InputError(f"not a number: {_fmt(value)}", path, line, field) from None
    raise InputError(f"must be a number, not {type(value).__name__}", path, line, field)


def finite(value, path=None, line=None, field=None) -> float:
    """A finite number (not NaN, not +-inf, not an overflowing literal such as 1e400)."""
    v = number(value, path, line, field)
    if not math.isfinite(v):
        raise InputError(f"not a finite number: {_fmt(value)}", path, line, field)
    return v


def in_range(value, lo: float, hi: float, path=None, line=None, field=None, unit: str = "") -> float:
    """A finite number within [lo, hi]."""
    v = finite(value, path, line, field)
    if not lo <= v <= hi:
        u = f" {unit}" if unit else ""
        raise InputError(f"{_fmt(v)}{u} is outside the plausible range [{lo:g}, {hi:g}]{u}", path, line, field)
    return v


def positive(value, path=None, line=None, field=None, hi: float = math.inf) -> float:
    """A finite number > 0 (and <= hi)."""
    v = finite(value, path, line, field)
    if not v > 0:
        raise InputError(f"must be positive, got {_fmt(v)}", path, line, field)
    if v > hi:
        raise InputError(f"{_fmt(v)} is implausibly large (more than {hi:g})", path, line, field)
    return v


def non_negative(value, path=None, line=None, field=None, hi: float = math.inf) -> float:
    """A finite number >= 0 (and <= hi): a sigma, a count, a duration."""
    v = finite(value, path, line, field)
    if not v >= 0:
        raise InputError(f"must not be negative, got {_fmt(v)}", path, line, field)
    if v > hi:
        raise InputError(f"{_fmt(v)} is implausibly large (more than {hi:g})", path, line, field)
    return v


def integer(value, lo: int | None = None, hi: int | None = None, path=None, line=None, field=None) -> int:
    """A whole number (an int, or a float or text with an integral value such as '12' or 12.0) within
    [lo, hi] when given; booleans are not numbers."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        v = int(value)
    else:
        f = finite(value, path, line, field)
        if f != math.floor(f):
            raise InputError(f"must be a whole number, got {_fmt(value)}", path, line, field)
        v = int(f)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        rng = f"[{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"
        raise InputError(f"{_fmt(v)} is outside the plausible range {rng}", path, line, field)
    return v


def image_side(value, path=None, line=None, field=None) -> int:
    """A side of an image: a whole number of pixels in 1..MAX_IMAGE_SIDE (5000, 5000.0 and '5000' are)."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        n = int(value)
    else:
        f = finite(value, path, line, field)
        if f != math.floor(f):
            raise InputError(f"an image size must be a whole number of pixels, got {_fmt(value)}", path, line, field)
        n = int(f)
    if not 1 <= n <= MAX_IMAGE_SIDE:
        raise InputError(f"implausible image size {_fmt(n)} px (1 to {MAX_IMAGE_SIDE})", path, line, field)
    return n


def image_size(width, height, path=None, line=None, field: str | None = "image_size") -> tuple[int, int]:
    """(width, height) of an image (`image_side` each; the fields are named `field[0]`, `field[1]`)."""
    return (image_side(width, path, line, None if field is None else f"{field}[0]"),
            image_side(height, path, line, None if field is None else f"{field}[1]"))


def vector(values, n: int | Sequence[int], path=None, line=None, field=None, lo: float = -math.inf,
           hi: float = math.inf) -> np.ndarray:
    """A list of `n` (or one of the sizes `n`) finite numbers within [lo, hi], as a float array."""
    sizes = (n,) if isinstance(n, int) else tuple(n)
    if isinstance(values, (str, bytes, dict)) or not hasattr(values, "__len__"):
        raise InputError(f"must be a list of {' or '.join(map(str, sizes))} numbers, not {_fmt(values)}", path,
                         line, field)
    if len(values) not in sizes:
        raise InputError(f"must hold {' or '.join(map(str, sizes))} numbers, got {len(values)}", path, line, field)
    return np.array([in_range(v, lo, hi, path, line, field) for v in values], float)


def matrix(values, shape: tuple[int, int], path=None, line=None, field=None) -> np.ndarray:
    """A nested list (or flat list) of finite numbers of `shape`, as a float array."""
    rows = values
    if isinstance(rows, (list, tuple)) and rows and all(isinstance(r, (list, tuple)) for r in rows):
        if len(rows) != shape[0] or any(len(r) != shape[1] for r in rows):
            raise InputError(f"must be a {shape[0]} x {shape[1]} matrix", path, line, field)
        flat = [v for r in rows for v in r]
    else:
        flat = rows
    return vector(flat, shape[0] * shape[1], path, line, field).reshape(shape)


# ---------------------------------------------------------------------------------------------
# arrays (columns of a table): the first bad row is named by its file line
# ---------------------------------------------------------------------------------------------
def _line(lines, i: int) -> int | None:
    return None if lines is None else int(np.asarray(lines)[i])


def finite_values(a, path=None, field=None, lines=None, allow_nan: bool = False) -> np.ndarray:
    """Every value finite (NaN allowed when `allow_nan`: an optional value not given)."""
    a = np.asarray(a, float)
    bad = ~np.isfinite(a) & ~(np.isnan(a) if allow_nan else False)
    if bad.any():
        i = int(np.argmax(bad.reshape(len(a), -1).any(axis=1))) if a.ndim > 1 else int(np.argmax(bad))
        raise InputError("not a finite number", path, _line(lines, i), field)
    return a


def values_in_range(a, lo: float, hi: float, path=None, field=None, lines=None, allow_nan: bool = False,
                    unit: str = "") -> np.ndarray:
    """Every value finite and within [lo, hi] (NaN allowed when `allow_nan`)."""
    a = finite_values(a, path, field, lines, allow_nan)
    with np.errstate(invalid="ignore"):
        bad = (a < lo) | (a > hi)
    if bad.any():
        i = int(np.argmax(bad.reshape(len(a), -1).any(axis=1))) if a.ndim > 1 else int(np.argmax(bad))
        v = a.reshape(len(a), -1)[i][bad.reshape(len(a), -1)[i]][0] if a.ndim > 1 else a[i]
        u = f" {unit}" if unit else ""
        raise InputError(f"{_fmt(float(v))}{u} is outside the plausible range [{lo:g}, {hi:g}]{u}", path,
                         _line(lines, i), field)
    return a


# ECEF positions of receivers, vehicles and aircraft: the WGS84 polar radius minus 1 km to the equatorial plus 50 km
ECEF_NORM_RANGE_M = (6356752.3 - 1.0e3, 6378137.0 + 5.0e4)


def ecef_near_surface(p_ecef, path=None, lines=None, field: str = "x,y,z") -> np.ndarray:
    """ECEF positions (N,3) m that lie near the Earth's surface (within `ECEF_NORM_RANGE_M` of its centre); else an
    InputError naming the row and the likely cause (kilometres, not metres; a missing coordinate; not ECEF)."""
    p = np.asarray(p_ecef, float).reshape(-1, 3)
    r = np.linalg.norm(p, axis=1)
    lo, hi = ECEF_NORM_RANGE_M
    bad = ~((r >= lo) & (r <= hi))
    if bad.any():
        i = int(np.argmax(bad))
        why = ("kilometres, not metres?" if 6.3e3 < r[i] < 6.5e3 else
               "a coordinate missing or zero?" if np.any(p[i] == 0) else
               "not ECEF metres (geodetic or map coordinates?)")
        raise InputError(f"ECEF position {np.round(p[i], 3).tolist()} is {r[i] / 1e3:.3f} km from the Earth's "
                         f"centre, not near its surface ({lo / 1e3:.0f}-{hi / 1e3:.0f} km): {why}", path,
                         _line(lines, i), field)
    return p


def positive_values(a, path=None, field=None, lines=None, allow_nan: bool = False, hi: float = math.inf,
                    strict: bool = True, what: str = "value") -> np.ndarray:
    """Every value finite and > 0 (>= 0 unless `strict`) and <= hi; NaN allowed when `allow_nan`."""
    a = finite_values(a, path, field, lines, allow_nan)
    with np.errstate(invalid="ignore"):
        low = (a <= 0) if strict else (a < 0)
        high = a > hi
    for bad, msg in ((low, f"{what} must be {'positive' if strict else 'zero or positive'}"),
                     (high, f"{what} is implausibly large (more than {hi:g})")):
        if bad.any():
            i = int(np.argmax(bad.reshape(len(a), -1).any(axis=1))) if a.ndim > 1 else int(np.argmax(bad))
            raise InputError(msg, path, _line(lines, i), field)
    return a


def whole_values(a, lo: int, hi: int, path=None, field=None, lines=None) -> np.ndarray:
    """Every value a whole number within [lo, hi] (a GPS week, a count)."""
    a = values_in_range(a, lo, hi, path, field, lines)
    bad = a != np.floor(a)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"must be a whole number, got {_fmt(float(a[i]))}", path, _line(lines, i), field)
    return a


def gps_week_sow(week, sow, path=None, lines=None, fields: tuple[str, str] = ("gps_week", "gps_sow")) -> None:
    """GPS weeks whole numbers in 0..GPS_WEEK_MAX and seconds of week in [0, 604800]."""
    whole_values(week, 0, GPS_WEEK_MAX, path, fields[0], lines)
    values_in_range(sow, 0.0, SECONDS_PER_WEEK, path, fields[1], lines, unit="s")


GPS_SECONDS_MAX = (GPS_WEEK_MAX + 1) * SECONDS_PER_WEEK


def gps_seconds_values(t, path=None, field=None, lines=None) -> np.ndarray:
    """Continuous GPS seconds within GPS weeks 0..GPS_WEEK_MAX."""
    return values_in_range(t, 0.0, GPS_SECONDS_MAX, path, field, lines, unit="s")


# ---------------------------------------------------------------------------------------------
# TOML files: every number bounded where it is read
# ---------------------------------------------------------------------------------------------
MAX_TOML_NUMBER = 1e12   # no setting of a dgcal TOML file is larger (ECEF m ~6.4e6, GPS s ~1.5e9)


def _toml_key_line(text: str, keys: tuple[str, ...]) -> int | None:
    """The line of `text` that sets the key path `keys` (its last key, in its table when found there)."""
    import re
    table, first, want = (), None, ".".join(keys[:-1])
    pat = re.compile(r"""^\s*(?:[\w.-]+\s*\.\s*)*["']?""" + re.escape(keys[-1]) + r"""["']?\s*=""")
    for i, line in enumerate(text.splitlines(), 1):
        head = re.match(r"^\s*\[\[?\s*([^\]]+?)\s*\]\]?", line)
        if head:
            table = tuple(k.strip().strip("\"'") for k in head.group(1).split("."))
            continue
        if pat.match(line):
            if ".".join(table) == want or (not table and not want):
                return i
            first = first or i
    return first


def toml_numbers_in_range(d: dict, path: str | Path | None = None, text: str | None = None,
                          limit: float = MAX_TOML_NUMBER) -> dict:
    """`d` (a parsed TOML file) when every number in it is finite and within ±`limit` (TOML reads 20-digit integers,
    nan and inf, which would overflow or poison what is computed from them); else InputError naming the file, the
    line (from `text`, the file's text, or the file itself) and the key (`table.key[i]`)."""
    def walk(v, keys: tuple, shown: str):
        if isinstance(v, dict):
            for k, x in v.items():
                walk(x, (*keys, str(k)), f"{shown}.{k}" if shown else str(k))
        elif isinstance(v, list):
            for i, x in enumerate(v):
                walk(x, keys, f"{shown}[{i}]")
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            bad = (not math.isfinite(v)) if isinstance(v, float) else False
            if bad or abs(v) > limit:
                src = text
                if src is None and path is not None:
                    try:
                        src = Path(path).read_text(encoding="utf-8", errors="replace")
                    except OSError:
                        src = None
                line = _toml_key_line(src, keys) if src and keys else None
                what = "not a finite number" if bad else f"{_fmt(v)} is out of range (|x| <= {limit:g})"
                raise InputError(what, path, line, shown or None)
    walk(d, (), "")
    return d
