"""Time scales of other software's files -> dgcal's continuous GPS seconds (t = week*604800 + sow, s).

- GPS week + seconds of week: `t = week*604800 + sow`.
- Unix time (UTC, seconds since 1970-01-01 UTC without leap seconds, as POSIX, ROS and PX4 `time_utc_usec`
  give it): `t = unix - 315964800 + (GPS-UTC)`, GPS-UTC from dgcal.fields.constants.GPS_UTC_LEAP_SECONDS.
- "Unix-style" GPS seconds (RTKLIB's gtime_t in GPST: seconds since 1970-01-01 counted on the GPS scale,
  as in RTKLIB time-tag files): `t = value - 315964800`.
- UTC calendar text (`2025-07-08T19:34:18.499`, `2025/07/08 19:34:18.499`): parsed, then as Unix time.
"""
from __future__ import annotations

import re

import numpy as np

from dgcal.fields.constants import GPS_EPOCH_UNIX_S, GPS_UTC_LEAP_SECONDS, SECONDS_PER_WEEK

_LEAP_AT = np.array([u for u, _ in GPS_UTC_LEAP_SECONDS], float)
_LEAP_N = np.array([n for _, n in GPS_UTC_LEAP_SECONDS], float)
_CAL = re.compile(r"^\s*(\d{4})[-/](\d{1,2})[-/](\d{1,2})[T\s]+(\d{1,2}):(\d{1,2}):(\d{1,2}(?:\.\d*)?)"
                  r"\s*(?:Z|UTC)?\s*$", re.I)


def gps_minus_utc_s(unix_utc) -> np.ndarray:
    """GPS - UTC (s, whole leap seconds) at UTC instants given as Unix seconds."""
    u = np.asarray(unix_utc, float)
    i = np.searchsorted(_LEAP_AT, u, side="right") - 1
    return np.where(i >= 0, _LEAP_N[np.clip(i, 0, None)], 0.0)


def gps_from_unix_utc(unix_utc, leap_seconds: float | None = None) -> np.ndarray:
    """Continuous GPS seconds from Unix UTC seconds; `leap_seconds` = GPS-UTC (s), default from the table."""
    u = np.asarray(unix_utc, float)
    leap = gps_minus_utc_s(u) if leap_seconds is None else float(leap_seconds)
    return u - GPS_EPOCH_UNIX_S + leap


def unix_utc_from_gps(t_gps, leap_seconds: float | None = None) -> np.ndarray:
    """Unix UTC seconds from continuous GPS seconds (inverse of `gps_from_unix_utc`)."""
    t = np.asarray(t_gps, float)
    if leap_seconds is not None:
        return t + GPS_EPOCH_UNIX_S - float(leap_seconds)
    u = t + GPS_EPOCH_UNIX_S - gps_minus_utc_s(t + GPS_EPOCH_UNIX_S - 18.0)
    return t + GPS_EPOCH_UNIX_S - gps_minus_utc_s(u)


def gps_from_unix_gpst(value) -> np.ndarray:
    """Continuous GPS seconds from RTKLIB-style 'Unix' seconds counted on the GPS time scale."""
    return np.asarray(value, float) - GPS_EPOCH_UNIX_S


def unix_from_calendar(text: str) -> float:
    """Seconds since 1970-01-01 of a calendar text `YYYY-MM-DD[T ]hh:mm:ss[.fff]` in its own time scale.

    Raises ValueError when the text is not such a date-time."""
    m = _CAL.match(text)
    if m is None:
        raise ValueError(f"not a date-time (YYYY-MM-DD hh:mm:ss.sss): {text.strip()[:40]!r}")
    y, mo, d, h, mi = (int(m.group(k)) for k in range(1, 6))
    s = float(m.group(6))
    if not (1 <= mo <= 12 and 1 <= d <= 31 and h < 24 and mi < 60 and s < 61):
        raise ValueError(f"date-time out of range: {text.strip()[:40]!r}")
    days = _days_from_civil(y, mo, d)
    return days * 86400.0 + h * 3600.0 + mi * 60.0 + s


def calendar_from_unix(u: float, decimals: int = 3) -> str:
    """`YYYY/MM/DD hh:mm:ss.fff` of seconds since 1970-01-01 (inverse of `unix_from_calendar`)."""
    q = round(float(u), decimals)
    days = int(np.floor(q / 86400.0))
    sod = q - days * 86400.0
    y, mo, d = _civil_from_days(days)
    h = int(sod // 3600)
    mi = int((sod - 3600 * h) // 60)
    s = sod - 3600 * h - 60 * mi
    w = 3 + decimals if decimals else 2
    return f"{y:04d}/{mo:02d}/{d:02d} {h:02d}:{mi:02d}:{s:0{w}.{decimals}f}"


def week_sow_from_gps(t_gps) -> tuple[np.ndarray, np.ndarray]:
    """(GPS week, seconds of week) of continuous GPS seconds."""
    t = np.asarray(t_gps, float)
    week = np.floor(t / SECONDS_PER_WEEK)
    return week.astype(int), t - week * SECONDS_PER_WEEK


def _days_from_civil(y: int, m: int, d: int) -> int:
    """Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's algorithm)."""
    y -= m <= 2
    era = (y if y >= 0 else y - 399) // 400
    yoe = y - era * 400
    doy = (153 * (m + (-3 if m > 2 else 9)) + 2) // 5 + d - 1
    doe = yoe * 365 + yoe // 4 - yoe // 100 + doy
    return era * 146097 + doe - 719468


def _civil_from_days(z: int) -> tuple[int, int, int]:
    z += 719468
    era = (z if z >= 0 else z - 146096) // 146097
    doe = z - era * 146097
    yoe = (doe - doe // 1460 + doe // 36524 - doe // 146096) // 365
    y = yoe + era * 400
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    d = doy - (153 * mp + 2) // 5 + 1
    m = mp + (3 if mp < 10 else -9)
    return y + (m <= 2), m, d
