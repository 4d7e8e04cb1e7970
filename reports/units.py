"""Numbers of the reports formatted by unit in one place: metres to the millimetre, degrees to a resolution suited to
their size, px to 0.01, ms, ppm; coordinates in full fixed notation; GPS times as week + seconds of week; lists as
comma-separated numbers. Nothing here writes e+ or e- notation: a number too small for its unit's resolution is
shown with more decimals (up to a limit), a huge one in full."""
from __future__ import annotations

import datetime
import math
import re
from collections.abc import Mapping

import numpy as np

# decimals per unit: the resolution a surveyor reads (m: mm; px: 0.01 px; deg: 0.0001° ≈ 0.4")
DECIMALS = {"m": 3, "cm": 1, "mm": 1, "km": 3, "deg": 4, "°": 4, "rad": 6, "arcsec": 1, "″": 1, "px": 2, "s": 3,
            "ms": 2, "µs": 1, "ns": 1, "ppm": 2, "%": 1, "m/s": 3, "m/s²": 4, "°/h": 2, "deg/h": 2, "°/s": 3,
            "deg/s": 3, "°/√h": 3, "m/s/√h": 4, "mg": 2, "µg": 1, "Hz": 1, "dB-Hz": 1, "dB": 1, "K": 1, "°C": 1}
COORDINATE_DECIMALS = {"m": 3, "deg": 8, "°": 8}   # map/ECEF coordinates and latitudes/longitudes
MAX_DECIMALS = 8           # a tiny value gets more decimals than its unit's, up to this many
SIGNIFICANT = 4            # unitless numbers: about this many significant digits
GPS_EPOCH = datetime.datetime(1980, 1, 6)
GPS_SECONDS_MIN = 1e8      # a "GPS time" below this is a span (s since a start), not an absolute time
WEEK_S = 604800.0

_UNIT_IN_PARENS = re.compile(r"\(([^()]*)\)\s*$")


def _decimals_for(v: float, base: int) -> int:
    """`base` decimals (the unit's resolution), more when |v| is below that resolution (two significant digits then,
    at most MAX_DECIMALS; a value below even that: `base`, it reads as 0)."""
    a = abs(v)
    if a == 0 or a >= 10 ** -base or a < 10 ** -MAX_DECIMALS:
        return base
    return min(MAX_DECIMALS, max(base, 1 - int(math.floor(math.log10(a)))))


def _sigma_decimals(s: float, base: int | None) -> int:
    """Decimals that show a sigma with two significant digits, at least `base` (the unit's resolution)."""
    return min(MAX_DECIMALS, max(base or 0, 1 - int(math.floor(math.log10(s)))))


def column_decimals(values, unit: str | None) -> int | None:
    """One number of decimals for a table column in `unit` (the most any of its numbers needs, `_decimals_for`),
    so a column reads aligned (0.0011 beside 0.0009, not 0.00107 beside 0.000909); None for a unitless column."""
    u = canonical_unit(unit)
    if u not in DECIMALS:
        return None
    nums = [float(v) for v in values if isinstance(v, (float, np.floating)) and math.isfinite(float(v))]
    return max((_decimals_for(v, DECIMALS[u]) for v in nums), default=None)


def plain(v: float, significant: int = SIGNIFICANT) -> str:
    """A unitless number with about `significant` digits, in fixed notation (never e±)."""
    a = abs(v)
    if a == 0:
        return "0"
    if a >= 10 ** (significant - 1):
        return f"{v:.0f}"
    d = significant - 1 - int(math.floor(math.log10(a)))
    text = f"{v:.{min(max(d, 0), MAX_DECIMALS)}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def canonical_unit(unit: str | None) -> str:
    """The unit as the tables write it ('deg' → '°', 'deg/h' → '°/h'; '' for none)."""
    u = (unit or "").strip()
    return {"deg": "°", "degrees": "°", "deg/h": "°/h", "deg/s": "°/s", "mps": "m/s", "m s-1": "m/s",
            "pct": "%", "percent": "%", "arcsec": "″", "sec": "s"}.get(u, u)


def fmt_number(v, unit: str | None = None, coordinate: bool = False, decimals: int | None = None) -> str:
    """One number in `unit` at that unit's resolution (`coordinate`: map, ECEF or lat/lon resolution; `decimals`:
    this many instead); '–' for missing values, never e± notation. The unit itself is not appended."""
    if v is None:
        return "–"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    if not math.isfinite(f):
        return "–"
    u = canonical_unit(unit)
    if decimals is None:
        if coordinate and u in COORDINATE_DECIMALS:
            decimals = COORDINATE_DECIMALS[u]
        elif coordinate and not u:     # a mixed list such as lat, lon (°), h (m): angles to 1e-8 °, the rest mm
            decimals = 8 if abs(f) <= 180 else 3
        elif u in DECIMALS:
            decimals = _decimals_for(f, DECIMALS[u])
        else:
            return plain(f)
    text = f"{f:.{decimals}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def fmt_value(v, unit: str | None = None, coordinate: bool = False, decimals: int | None = None) -> str:
    """Any summary value as text: a number in `unit` (`fmt_number`), a list as comma-separated numbers, a nested
    list (a matrix) as rows separated by '; ', a mapping as 'label: value' pairs, True/False as yes/no, None '–'."""
    if isinstance(v, Mapping):
        from dgcal.reports.glossary import label   # why: glossary imports this module
        return "; ".join(f"{label(k)}: {fmt_value(x, _unit_of_key(k) or unit, coordinate)}" for k, x in v.items())
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if isinstance(v, (list, tuple)):
        if not v:
            return "none"
        sep = "; " if any(isinstance(x, (list, tuple, Mapping)) for x in v) else ", "
        if decimals is None and not coordinate:
            decimals = column_decimals(v, unit)
        return sep.join(fmt_value(x, unit, coordinate, decimals) for x in v)
    if isinstance(v, str):
        return v
    return fmt_number(v, unit, coordinate, decimals)


def with_unit(v, unit: str | None, coordinate: bool = False) -> str:
    """`fmt_value` followed by the unit ('1.234 m', '0.0120 °', '12 %')."""
    u = canonical_unit(unit)
    text = fmt_value(v, u, coordinate)
    if not u or text == "–":
        return text
    return f"{text}{'' if u in ('°', '%', '″') else ' '}{u}"


def value_sigma(v, sigma, unit: str | None = None, signed: bool = False) -> tuple[str, str]:
    """A value and its sigma as text with the same decimals: the sigma's two significant digits (at least the
    unit's resolution); a missing or zero sigma: the value at its unit's resolution and '–'."""
    u = canonical_unit(unit)
    try:
        fs = float(sigma)
    except (TypeError, ValueError):
        fs = float("nan")
    sign = "+" if signed and _positive(v) else ""
    if not math.isfinite(fs) or fs <= 0:
        return sign + fmt_number(v, u), "–"
    d = _sigma_decimals(fs, DECIMALS.get(u))
    return sign + fmt_number(v, u, decimals=d), fmt_number(fs, u, decimals=d)


def pm(v, sigma, unit: str | None = None, signed: bool = True) -> str:
    """'value ± sigma' with the same decimals (`value_sigma`; no unit appended); without a sigma the value alone."""
    a, b = value_sigma(v, sigma, unit, signed)
    return a if b == "–" else f"{a} ± {b}"


def _positive(v) -> bool:
    try:
        return float(v) >= 0
    except (TypeError, ValueError):
        return False


def gps_time(t_gps) -> str:
    """A continuous GPS time (s since 1980-01-06) as 'week W, SOW s (YYYY-MM-DD hh:mm:ss GPST)'; a value below
    GPS_SECONDS_MIN (a span or relative time) as seconds."""
    try:
        t = float(t_gps)
    except (TypeError, ValueError):
        return "–" if t_gps is None else str(t_gps)
    if not math.isfinite(t):
        return "–"
    if t < GPS_SECONDS_MIN:
        return f"{t:.3f} s"
    week = int(t // WEEK_S)
    sow = t - week * WEEK_S
    when = GPS_EPOCH + datetime.timedelta(seconds=t)
    return f"week {week}, {sow:.3f} s of week ({when:%Y-%m-%d %H:%M:%S} GPST)"


def unit_of_label(text: str) -> str:
    """The unit in a label's trailing parentheses ('RMS E (m)' → 'm'); '' when there is none or it is not a unit."""
    m = _UNIT_IN_PARENS.search(str(text))
    if not m:
        return ""
    inner = m.group(1).strip()
    # 'x / y / z (m)' or '(m, body FRD)': the first word that is a unit
    for part in re.split(r"[,;]\s*", inner):
        u = canonical_unit(part.strip())
        if u in DECIMALS or u in ("°", "″", "%"):
            return u
    return ""


def _unit_of_key(key) -> str:
    """The unit of a snake_case summary key from its suffix (`sigma_m` → 'm'; `bias_deg_h_mean` → '°/h')."""
    from dgcal.reports.glossary import split_key   # why: glossary imports this module
    return split_key(str(key))[2]


def is_coordinate_label(text: str) -> bool:
    """Whether a label names coordinates (full resolution: map/ECEF metres, lat/lon to 1e-8 °)."""
    t = str(text).lower()
    return any(w in t for w in ("ecef", "coordinate", "lat", "lon", "origin", "position (", "easting", "northing",
                                "base position"))
