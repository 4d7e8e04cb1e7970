"""IMU data (angle and velocity increments, body FRD) and its text readers/writers.

`ImuData.t[i]` is the continuous GPS time (week*604800 + sow, s) at the END of interval i;
`dtheta[i]` (rad) and `dvel[i]` (m/s) are the increments accumulated over (t[i-1], t[i]].
Formats:
- KF-GINS / OB_GINS text (i2Nav-WHU): whitespace separated `sow dθx dθy dθz dvx dvy dvz`, rad and m/s,
  axes front-right-down; extra columns are ignored.
- Generic text / CSV: any columns (by header name or 0-based index), rates or increments, units
  configurable, optional fixed sensor-to-body rotation.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from dgcal.fields.constants import G0, SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.io.text_files import read_text
from dgcal.fields.io.validate import gps_seconds_values

# factors to rad (increments) / rad/s (rates), m/s (increments) / m/s^2 (rates)
GYRO_UNITS = {"rad": 1.0, "deg": np.pi / 180.0, "rad/s": 1.0, "deg/s": np.pi / 180.0,
              "deg/h": np.pi / 180.0 / 3600.0}
ACC_UNITS = {"m/s": 1.0, "m/s2": 1.0, "m/s^2": 1.0, "g": G0, "mg": G0 * 1e-3}
_GYRO_UNITS, _ACC_UNITS = GYRO_UNITS, ACC_UNITS


@dataclass
class ImuData:
    """IMU increments in body FRD: `t` (N,) GPS s at interval end, `dtheta` (N,3) rad, `dvel` (N,3) m/s.

    `bridges`: spans whose samples were interpolated (gaps, spikes) by `dgcal.pos.ins.integrity.check_imu`, with
    the extra white noise the smoother carries over them (`dgcal.pos.ins.integrity.Bridge`)."""

    t: np.ndarray
    dtheta: np.ndarray
    dvel: np.ndarray
    rate_hz: float
    path: Path | None = None
    lines: np.ndarray | None = field(default=None, repr=False)
    bridges: list = field(default_factory=list, repr=False)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def dt(self) -> np.ndarray:
        """Interval lengths (s); the first sample's interval is taken as 1/rate_hz."""
        d = np.empty(len(self.t))
        d[0] = 1.0 / self.rate_hz
        d[1:] = np.diff(self.t)
        return d

    @property
    def gyro_rad_s(self) -> np.ndarray:
        """Mean angular rate over each interval, rad/s, body FRD (N,3)."""
        return self.dtheta / self.dt[:, None]

    @property
    def accel_m_s2(self) -> np.ndarray:
        """Mean specific force over each interval, m/s^2, body FRD (N,3)."""
        return self.dvel / self.dt[:, None]

    @classmethod
    def from_rates(cls, t: np.ndarray, gyro_rad_s: np.ndarray, accel_m_s2: np.ndarray,
                   rate_hz: float | None = None) -> "ImuData":
        """ImuData from mean rates (rad/s, m/s^2, body FRD) over the intervals ending at `t` (GPS s)."""
        t = np.asarray(t, float)
        rate = float(rate_hz) if rate_hz else estimate_rate_hz(t)
        d = np.empty(len(t))
        d[0] = 1.0 / rate
        d[1:] = np.diff(t)
        return cls(t, np.asarray(gyro_rad_s, float) * d[:, None], np.asarray(accel_m_s2, float) * d[:, None],
                   rate)

    def gaps(self, factor: float = 1.5) -> np.ndarray:
        """Indices i whose interval (t[i-1], t[i]] is longer than `factor` nominal steps (missing samples)."""
        return np.flatnonzero(np.diff(self.t) > factor / self.rate_hz) + 1

    def between(self, t0: float, t1: float) -> "ImuData":
        """The samples with t0 <= t <= t1 (GPS s)."""
        i0, i1 = np.searchsorted(self.t, t0, side="left"), np.searchsorted(self.t, t1, side="right")
        sl = slice(i0, i1)
        return ImuData(self.t[sl], self.dtheta[sl], self.dvel[sl], self.rate_hz, self.path,
                       None if self.lines is None else self.lines[sl],
                       [b for b in self.bridges if b.t1 > t0 and b.t0 < t1])

    def rotated(self, R_sensor_to_body: np.ndarray) -> "ImuData":
        """The same data with the axes rotated by a fixed sensor-to-body rotation."""
        R = np.asarray(R_sensor_to_body, float)
        return ImuData(self.t, self.dtheta @ R.T, self.dvel @ R.T, self.rate_hz, self.path, self.lines,
                       [b.rotated(R) for b in self.bridges])


def estimate_rate_hz(t: np.ndarray, path: Path | None = None) -> float:
    """Nominal sampling rate (Hz) from the median time step; `path` names the file in the error."""
    if len(t) < 2:
        raise InputError("need at least two IMU samples to know the sampling rate", path)
    rate = float(1.0 / np.median(np.diff(t)))
    # continuous GPS seconds (~1.4e9) carry ~0.2 us rounding; snap to the nominal integer rate
    return float(round(rate)) if round(rate) > 0 and abs(rate - round(rate)) < 1e-3 * rate else rate


def data_lines(path: Path, header: str | bool = "auto", delimiter: str | None = None
               ) -> tuple[list[str], np.ndarray, str | None, int]:
    """Non-blank, non-comment (`#`, `%`) lines, their 1-based line numbers and the header line (or None).

    `header` "auto": the first line is a header when its first field is not a number; True/False force it."""
    all_lines = read_text(path).splitlines()
    keep = [i for i, s in enumerate(all_lines) if s.strip() and not s.lstrip().startswith(("#", "%"))]
    header_text, header_line = None, 0
    if keep:
        first_line = all_lines[keep[0]]
        if header == "auto":
            sep = delimiter if delimiter not in (None, "ws") else ","
            first = first_line.replace(sep, " ").replace(",", " ").split()
            try:
                float(first[0])
                is_header = False
            except (ValueError, IndexError):
                is_header = True
        else:
            is_header = bool(header)
        if is_header:
            header_text, header_line = first_line, keep[0] + 1
            keep = keep[1:]
    if not keep:
        raise InputError("no IMU data rows", path)
    return [all_lines[i] for i in keep], np.asarray(keep) + 1, header_text, header_line


def parse_numeric(path: Path, rows: list[str], lines: np.ndarray, ncols_needed: int, delim: str | None,
                  usecols: list[int] | None = None) -> np.ndarray:
    """The rows' columns (all, or `usecols`) as floats (vectorised np.loadtxt); on failure the first bad
    line and column is reported (InputError)."""
    sep = None if delim == "ws" else delim
    arr = None
    try:
        with np.errstate(all="ignore"):
            arr = np.loadtxt(rows, delimiter=sep, ndmin=2, dtype=float, usecols=usecols)
        ncols = arr.shape[1] if usecols is None else max(usecols) + 1
        if ncols >= ncols_needed and np.isfinite(arr).all():
            return arr
    except (ValueError, IndexError):
        arr = None
    check = None if usecols is None else set(usecols)
    for k, s in enumerate(rows):
        toks = [c.strip() for c in (s.split(sep) if sep else s.split())]
        if len(toks) < ncols_needed:
            raise InputError(f"expected at least {ncols_needed} columns, found {len(toks)}", path, int(lines[k]))
        for j, tok in enumerate(toks):
            if check is not None and j not in check:
                continue
            try:
                v = float(tok)
            except ValueError:
                raise InputError(f"not a number: {tok[:40]!r}", path, int(lines[k]), f"column {j + 1}") from None
            if not np.isfinite(v):
                raise InputError(f"not a finite number: {tok[:40]!r}", path, int(lines[k]), f"column {j + 1}")
    if arr is None:  # ragged rows that each have enough columns
        raise InputError("rows have different numbers of columns", path)
    return arr


_data_lines, _parse_numeric = data_lines, parse_numeric


def _to_gps_time(path: Path, lines: np.ndarray, time: np.ndarray, gps_week: int | None, time_kind: str
                 ) -> np.ndarray:
    """Continuous GPS seconds from a time column ('sow' with a week, or already continuous 'gps')."""
    if time_kind == "gps":
        return time
    if time_kind != "sow":
        raise InputError(f"unknown time kind {time_kind!r} (use 'sow' or 'gps')", path)
    bad = np.flatnonzero((time < 0) | (time >= SECONDS_PER_WEEK))
    if bad.size:
        raise InputError(f"seconds of week out of range: {time[bad[0]]}", path, int(lines[bad[0]]), "sow")
    # a week rollover inside the file shows as a drop of about one week
    roll = np.concatenate([[0.0], np.cumsum(np.diff(time) < -SECONDS_PER_WEEK / 2)]) * SECONDS_PER_WEEK
    return time + roll + (0.0 if gps_week is None else gps_week * SECONDS_PER_WEEK)


def _check_time(path: Path, lines: np.ndarray, t: np.ndarray) -> None:
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        k = bad[0] + 1
        raise InputError(f"time does not increase ({t[k]!r} after {t[k - 1]!r})", path, int(lines[k]), "time")


def finish_imu(path: Path, lines: np.ndarray, t: np.ndarray, g: np.ndarray, a: np.ndarray, kind: str,
               rate_hz: float | None, R_sensor_to_body: np.ndarray | None) -> ImuData:
    """ImuData (body FRD increments) from parsed times (GPS s), gyro and accel columns (SI) of `kind`."""
    gps_seconds_values(t, path, "time", lines)    # a week or time of 1e20 is a corrupt value, not a date
    _check_time(path, lines, t)
    rate = float(rate_hz) if rate_hz else estimate_rate_hz(t, path)
    if kind == "increments":
        imu = ImuData(t, g, a, rate, path, lines)
    elif kind == "rates":
        imu = ImuData.from_rates(t, g, a, rate)
        imu.path, imu.lines = path, lines
    else:
        raise InputError(f"unknown IMU data kind {kind!r} (use 'increments' or 'rates')", path)
    _check_ranges(imu, path, lines)
    return imu.rotated(R_sensor_to_body) if R_sensor_to_body is not None else imu


MAX_GYRO_RAD_S = 100.0          # 5700 deg/s: beyond any IMU's range (a sample beyond is a corrupt value)
MAX_ACCEL_M_S2 = 2000.0         # 200 g: beyond any navigation IMU's accelerometer range


def _check_ranges(imu: ImuData, path: Path, lines: np.ndarray) -> None:
    """Every sample's rate and specific force within what an IMU can measure (1e20 in a column is a corrupt file,
    not a manoeuvre); InputError naming the line and column."""
    dt = imu.dt
    for name, inc, lim, cols in (("gyro", imu.dtheta, MAX_GYRO_RAD_S, ("gx", "gy", "gz")),
                                 ("accel", imu.dvel, MAX_ACCEL_M_S2, ("ax", "ay", "az"))):
        with np.errstate(invalid="ignore", divide="ignore"):
            v = np.abs(inc / dt[:, None])
        bad = ~(v <= lim)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            unit = "rad/s" if name == "gyro" else "m/s^2"
            raise InputError(f"{name} {v[i, j]:.4g} {unit} is beyond any IMU's range ({lim:g} {unit}): a corrupt "
                             "value or a unit mistake", path, int(lines[i]) if lines is not None else None, cols[j])


def read_kf_gins(path: str | Path, gps_week: int | None = None, rate_hz: float | None = None) -> ImuData:
    """Read a KF-GINS/OB_GINS IMU text file (`sow dθxyz[rad] dvxyz[m/s]`, FRD); t = week*604800 + sow."""
    path = Path(path)
    rows, lines, _, _ = _data_lines(path)
    arr = _parse_numeric(path, rows, lines, 7, None)
    t = _to_gps_time(path, lines, arr[:, 0], gps_week, "sow")
    return finish_imu(path, lines, t, arr[:, 1:4].copy(), arr[:, 4:7].copy(), "increments", rate_hz, None)


def read_imu_text(path: str | Path, columns: Sequence[str | int] | None = None, kind: str = "increments",
                  gyro_unit: str | None = None, accel_unit: str | None = None, time_kind: str = "sow",
                  gps_week: int | None = None, rate_hz: float | None = None,
                  R_sensor_to_body: np.ndarray | None = None) -> ImuData:
    """Read IMU samples from text/CSV: `columns` = [time, gx, gy, gz, ax, ay, az] by header name or index.

    kind 'increments' (gyro 'rad'|'deg', accel 'm/s') or 'rates' (gyro 'rad/s'|'deg/s'|'deg/h',
    accel 'm/s2'|'g'|'mg'); time_kind 'sow' (with `gps_week`) or 'gps' (continuous GPS seconds).
    Without `columns`, the first seven columns are used in that order. Result is body FRD after
    `R_sensor_to_body`.
    """
    path = Path(path)
    gyro_unit = gyro_unit or ("rad" if kind == "increments" else "rad/s")
    accel_unit = accel_unit or ("m/s" if kind == "increments" else "m/s2")
    if gyro_unit not in _GYRO_UNITS:
        raise InputError(f"unknown gyro unit {gyro_unit!r} (one of {', '.join(_GYRO_UNITS)})", path)
    if accel_unit not in _ACC_UNITS:
        raise InputError(f"unknown accelerometer unit {accel_unit!r} (one of {', '.join(_ACC_UNITS)})", path)
    rows, lines, header, header_line = _data_lines(path)
    delim = "," if "," in rows[0] else None
    names = None
    if header is not None:
        names = [c.strip().lower() for c in (header.split(",") if delim else header.split())]
    cols = list(columns) if columns is not None else list(range(7))
    if len(cols) != 7:
        raise InputError(f"need 7 columns (time, 3 gyro, 3 accel), got {len(cols)}", path)
    idx = []
    for c in cols:
        if isinstance(c, (int, np.integer)):
            idx.append(int(c))
        else:
            if names is None or c.lower() not in names:
                raise InputError(f"column {c!r} not in header ({', '.join(names or [])})", path, header_line or None)
            idx.append(names.index(c.lower()))
    arr = _parse_numeric(path, rows, lines, max(idx) + 1, delim)
    t = _to_gps_time(path, lines, arr[:, idx[0]], gps_week, time_kind)
    g = arr[:, idx[1:4]] * _GYRO_UNITS[gyro_unit]
    a = arr[:, idx[4:7]] * _ACC_UNITS[accel_unit]
    return finish_imu(path, lines, t, g, a, kind, rate_hz, R_sensor_to_body)


def write_kf_gins(path: str | Path, imu: ImuData) -> None:
    """Write KF-GINS/OB_GINS IMU text (`sow dθxyz dvxyz`, rad and m/s, FRD), atomically."""
    sow = np.mod(imu.t, SECONDS_PER_WEEK)
    arr = np.column_stack([sow, imu.dtheta, imu.dvel])
    with atomic_write(path) as fh:
        np.savetxt(fh, arr, fmt=["%.6f"] + ["%.12e"] * 6)  # us: the float64 GPS time holds 0.24 us


def write_imu_csv(path: str | Path, imu: ImuData, kind: str = "increments") -> None:
    """Write a CSV with header `gps_week,gps_sow,gx,gy,gz,ax,ay,az` (increments rad, m/s or rates rad/s, m/s^2)."""
    week = np.floor(imu.t / SECONDS_PER_WEEK)
    sow = imu.t - week * SECONDS_PER_WEEK
    if kind == "increments":
        g, a = imu.dtheta, imu.dvel
    elif kind == "rates":
        g, a = imu.gyro_rad_s, imu.accel_m_s2
    else:
        raise ValueError(f"unknown kind {kind!r}")
    arr = np.column_stack([week, sow, g, a])
    with atomic_write(path) as fh:
        fh.write("gps_week,gps_sow,gx,gy,gz,ax,ay,az\n")
        np.savetxt(fh, arr, fmt=["%d", "%.6f"] + ["%.12e"] * 6, delimiter=",")


def read_imu_csv(path: str | Path, kind: str = "increments", rate_hz: float | None = None) -> ImuData:
    """Read the CSV written by `write_imu_csv` (`gps_week,gps_sow,gx..az`)."""
    path = Path(path)
    rows, lines, header, header_line = _data_lines(path)
    names = [c.strip().lower() for c in (header or "").split(",")]
    need = ["gps_week", "gps_sow", "gx", "gy", "gz", "ax", "ay", "az"]
    missing = [c for c in need if c not in names]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)}", path, header_line or None)
    idx = [names.index(c) for c in need]
    arr = _parse_numeric(path, rows, lines, max(idx) + 1, ",")
    t = arr[:, idx[0]] * SECONDS_PER_WEEK + arr[:, idx[1]]
    return finish_imu(path, lines, t, arr[:, idx[2:5]], arr[:, idx[5:8]], kind, rate_hz, None)
