"""How a logger's and a GNSS receiver's packet logs are laid out: a small declarative description (TOML or flags).

A description names, for each role, the column holding it (by header name, or 0-based index when the file
has no header), the delimiter, units and signal conventions. dgcal's own layout is the default:

    # logger.toml (dgcal sync --logger-format logger.toml)
    rate_hz = 50.0            # logger sample rate (Hz)
    counter_bits = 16         # width of the packet counter (0: it never wraps)
    delimiter = ","           # ",", ";", "tab" or "whitespace"
    header = true             # false: columns are 0-based indices
    [columns]                 # role = column (optional roles may be left out)
    counter = "counter"       # free-running packet counter (required)
    pps = "pps"               # A/D level of the receiver's PPS line (required)
    photo = "photo"           # light sensor behind the viewfinder (required)
    trigger = "trigger"       # shutter command sent (1) or not (0)
    laser = "laser"           # laser range finder, down
    baro = "baro"             # barometric altitude or pressure
    gps_time = "gps_sow"      # GNSS time the logger received in its own packets
    [units]
    laser = "m"               # m, cm, mm, ft
    baro = "m"                # m, ft, or hPa / Pa (pressure, turned into altitude by the standard atmosphere)
    gps_time = "sow"          # sow (week from the GNSS log) or gps (continuous GPS seconds)
    [signals]
    photo_polarity = 0        # -1: spikes go down, +1: up, 0: the larger excursion
    pps_inverted = false      # true: the PPS line is low in the first half of the second
    trigger_level = 0.5       # trigger channel threshold
    [gnss]                    # the GNSS packet log
    rate_hz = 50.0            # packet rate (Hz; default: rate_hz)
    delimiter = ","
    week = "gps_week"         # with sow; leave out for continuous GPS seconds in `time`
    time = "gps_sow"
    height = "h"              # ellipsoidal height (m), for the coarse alignment against laser / baro

Flags override single entries (`--logger-column laser=range_cm --laser-unit cm`).
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.fields.key_values import split_key_value
from dgcal.fields.io import validate
from dgcal.fields.io.text_files import read_text

LOGGER_ROLES = ("counter", "pps", "photo", "trigger", "laser", "baro", "gps_time")
REQUIRED_ROLES = ("counter", "pps", "photo")
LENGTH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "ft": 0.3048}
PRESSURE_UNITS = {"hpa": 100.0, "mbar": 100.0, "pa": 1.0}
_DELIMS = {",": ",", ";": ";", "tab": "\t", "\t": "\t", "whitespace": None, " ": None}


@dataclass
class GnssLogFormat:
    """Layout of the GNSS packet log: columns of week + seconds of week (or continuous GPS seconds when `week` is
    empty), height (m), delimiter, header, packet rate (Hz, None: the logger's)."""

    time: str | int = "gps_sow"
    week: str | int | None = "gps_week"
    height: str | int | None = "h"
    delimiter: str = ","
    header: bool = True
    rate_hz: float | None = None


@dataclass
class LoggerFormat:
    """Layout of a logger stream: role -> column, delimiter, header, sample rate (Hz), counter width (bits, 0 =
    no wrap), units of laser / baro / gps_time, light-sensor polarity, PPS inversion, trigger threshold."""

    columns: dict = field(default_factory=lambda: {r: r for r in ("counter", "pps", "photo", "trigger", "laser",
                                                                  "baro")} | {"gps_time": "gps_sow"})
    delimiter: str = ","
    header: bool = True
    rate_hz: float = 50.0
    counter_bits: int = 16
    units: dict = field(default_factory=lambda: {"laser": "m", "baro": "m", "gps_time": "sow"})
    photo_polarity: int = 0
    pps_inverted: bool = False
    trigger_level: float = 0.5
    gnss: GnssLogFormat = field(default_factory=GnssLogFormat)
    source: str | None = None

    def with_columns(self, items) -> "LoggerFormat":
        """A copy with `ROLE=COLUMN` items (flags) applied; InputError naming the bad item."""
        cols = dict(self.columns)
        for item in items or ():
            role, col = split_key_value(item, "logger_columns")
            role = role.lower()
            if role not in LOGGER_ROLES:
                raise InputError(f"bad column {item!r}: ROLE=COLUMN with ROLE one of {', '.join(LOGGER_ROLES)}",
                                 field="logger_columns")
            cols[role] = int(col) if col.isdigit() and not self.header else col
        return replace(self, columns=cols)


def _check_unit(path, role: str, unit: str) -> str:
    u = str(unit).lower()
    ok = (set(LENGTH_UNITS) | (set(PRESSURE_UNITS) if role == "baro" else set())) if role != "gps_time" \
        else {"sow", "gps"}
    if u not in ok:
        raise InputError(f"unknown unit {unit!r} (one of {', '.join(sorted(ok))})", path, field=f"units.{role}")
    return u


def read_logger_format(path: str | Path) -> LoggerFormat:
    """A LoggerFormat from a TOML description (see the module documentation); unknown keys are errors."""
    path = Path(path)
    try:
        text = read_text(path, encoding="utf-8")
        cfg = validate.toml_numbers_in_range(tomllib.loads(text), path, text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not a TOML file: {' '.join(str(exc).split())}", path) from None
    except RecursionError:
        raise InputError("not a TOML file: nested too deeply", path) from None
    fmt = LoggerFormat(source=str(path))
    top = {"rate_hz", "counter_bits", "delimiter", "header", "columns", "units", "signals", "gnss"}
    for k in cfg:
        if k not in top:
            raise InputError(f"unknown key (one of {', '.join(sorted(top))})", path, field=k)
    header = bool(cfg.get("header", True))
    cols = dict(fmt.columns) if header else {}
    for name in ("columns", "units", "signals", "gnss"):
        if name in cfg and not isinstance(cfg[name], dict):
            raise InputError(f"must be a [{name}] table", path, field=name)
    for role, col in (cfg.get("columns") or {}).items():
        if role not in LOGGER_ROLES:
            raise InputError(f"unknown role (one of {', '.join(LOGGER_ROLES)})", path, field=f"columns.{role}")
        if not isinstance(col, (str, int)) or isinstance(col, bool) or (not header and not isinstance(col, int)):
            raise InputError("a column name (or a 0-based index when header = false)", path, field=f"columns.{role}")
        cols[role] = col
    if "columns" in cfg:  # a description lists its columns: optional roles it leaves out are absent
        cols = {r: c for r, c in cols.items() if r in REQUIRED_ROLES or r in cfg["columns"]}
    units = dict(fmt.units)
    for role, u in (cfg.get("units") or {}).items():
        if role not in ("laser", "baro", "gps_time"):
            raise InputError("units for laser, baro or gps_time", path, field=f"units.{role}")
        units[role] = _check_unit(path, role, u)
    sig = cfg.get("signals") or {}
    for k in sig:
        if k not in ("photo_polarity", "pps_inverted", "trigger_level"):
            raise InputError("unknown key (photo_polarity, pps_inverted, trigger_level)", path, field=f"signals.{k}")
    g = cfg.get("gnss") or {}
    for k in g:
        if k not in ("rate_hz", "delimiter", "header", "week", "time", "height"):
            raise InputError("unknown key (rate_hz, delimiter, header, week, time, height)", path, field=f"gnss.{k}")
    rate = validate.positive(cfg.get("rate_hz", fmt.rate_hz), path, None, "rate_hz", hi=1e6)
    bits = validate.integer(cfg.get("counter_bits", fmt.counter_bits), 0, 63, path, None, "counter_bits")
    pol = validate.integer(sig.get("photo_polarity", 0), -1, 1, path, None, "signals.photo_polarity")
    level = validate.finite(sig.get("trigger_level", 0.5), path, None, "signals.trigger_level")
    grate = None if g.get("rate_hz") is None else validate.positive(g["rate_hz"], path, None, "gnss.rate_hz", hi=1e6)
    for key, table in (("header", cfg), ("pps_inverted", sig), ("header", g)):
        if key in table and not isinstance(table[key], bool):
            raise InputError("must be true or false", path, field=key if table is cfg else
                             f"{'signals' if table is sig else 'gnss'}.{key}")
    for key in ("time", "week", "height"):
        if key in g and not isinstance(g[key], (str, int)) or isinstance(g.get(key), bool):
            raise InputError("a column name (or a 0-based index)", path, field=f"gnss.{key}")
    delim = str(cfg.get("delimiter", ","))
    gdelim = str(g.get("delimiter", ","))
    for name, d in (("delimiter", delim), ("gnss.delimiter", gdelim)):
        if d not in _DELIMS:
            raise InputError(f"unknown delimiter {d!r} (',', ';', 'tab', 'whitespace')", path, field=name)
    gfmt = GnssLogFormat(time=g.get("time", "gps_sow"), week=g.get("week", "gps_week" if "time" not in g else None),
                         height=g.get("height", "h"), delimiter=gdelim, header=bool(g.get("header", True)),
                         rate_hz=grate)
    return replace(fmt, columns=cols, delimiter=delim, header=header, rate_hz=rate, counter_bits=bits, units=units,
                   photo_polarity=pol, pps_inverted=bool(sig.get("pps_inverted", False)), trigger_level=level,
                   gnss=gfmt)


def _read_columns(path: Path, delimiter: str, header: bool, wanted: dict, required: tuple[str, ...]
                  ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Numeric columns by role from a delimited text file; (values by role, file line of each row)."""
    text = read_text(path)
    sep = _DELIMS.get(delimiter, delimiter)
    rows, lines, names, header_line = [], [], None, None
    for ln, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        cells = [c.strip() for c in (s.split(sep) if sep else s.split())]
        if header and names is None:
            names, header_line = [c.lower() for c in cells], ln
            continue
        rows.append(cells)
        lines.append(ln)
    if header and names is None:
        raise InputError("empty file, expected a header row", path)
    idx = {}
    for role, col in wanted.items():
        if col is None:
            continue
        if isinstance(col, int) and not header:
            idx[role] = col
        elif names is not None and str(col).lower() in names:
            idx[role] = names.index(str(col).lower())
        elif role in required:
            have = ", ".join(names) if names else "no header"
            raise InputError(f"missing column {col!r} for {role} (header has {have})", path, header_line, str(col))
    if not rows:
        raise InputError("no data rows", path)
    out = {}
    lines_a = np.array(lines, dtype=int)
    for role, j in idx.items():
        col = wanted[role]
        out[role] = np.array([validate.number(r[j], path, int(lines_a[i]), str(col)) if j < len(r) and r[j] != ""
                              else np.nan for i, r in enumerate(rows)])
        bad = ~np.isfinite(out[role])
        if role in required and bad.any():
            i = int(np.argmax(bad))
            raise InputError("missing or non-finite value", path, int(lines_a[i]), str(col))
        # optional values may be missing (NaN), never infinite or beyond what a float64 counts exactly
        validate.values_in_range(out[role], -2.0 ** 53, 2.0 ** 53, path, str(col), lines_a, allow_nan=True)
    return out, lines_a


@dataclass
class LoggerStreams:
    """A logger stream by role (raw values, recorded packets only): counter, pps, photo and the optional
    trigger (0/1), laser (m), baro (m of altitude), gps_time (continuous GPS s); file lines of the rows."""

    counter: np.ndarray
    pps: np.ndarray
    photo: np.ndarray
    trigger: np.ndarray | None = None
    laser: np.ndarray | None = None
    baro: np.ndarray | None = None
    gps_time: np.ndarray | None = None
    lines: np.ndarray | None = None
    path: Path | None = None


def read_logger(path: str | Path, fmt: LoggerFormat | None = None, gps_week: int | None = None) -> LoggerStreams:
    """Read a logger stream described by `fmt` (default: dgcal's `counter,pps,photo[,trigger][,laser]` CSV); units
    converted to m (laser), m of altitude (baro) and continuous GPS s (gps_time, with `gps_week` for sow)."""
    fmt = fmt or LoggerFormat()
    path = Path(path)
    cols, lines = _read_columns(path, fmt.delimiter, fmt.header, fmt.columns, REQUIRED_ROLES)
    c = cols["counter"]
    if np.any(c != np.round(c)):
        i = int(np.argmax(c != np.round(c)))
        raise InputError(f"counter is not an integer: {c[i]!r}", path, int(lines[i]), str(fmt.columns["counter"]))
    trig = None
    if "trigger" in cols:
        trig = (np.nan_to_num(cols["trigger"], nan=0.0) > fmt.trigger_level).astype(int)
    laser = cols.get("laser")
    if laser is not None:
        laser = laser * LENGTH_UNITS[fmt.units.get("laser", "m")]
        laser = np.where(laser > 0, laser, np.nan)  # no return
    baro = cols.get("baro")
    if baro is not None:
        u = fmt.units.get("baro", "m")
        if u in PRESSURE_UNITS:
            p = baro * PRESSURE_UNITS[u]
            baro = 44330.77 * (1.0 - (np.where(p > 0, p, np.nan) / 101325.0) ** 0.190263)
        else:
            baro = baro * LENGTH_UNITS[u]
    gt = cols.get("gps_time")
    if gt is not None and fmt.units.get("gps_time", "sow") == "sow":
        if gps_week is None:
            raise InputError("gps_time in seconds of week needs the GNSS log's week", path,
                             field=str(fmt.columns["gps_time"]))
        gt = gt + gps_week * SECONDS_PER_WEEK
    return LoggerStreams(c.astype(np.int64), cols["pps"], cols["photo"], trig, laser, baro, gt, lines, path)


@dataclass
class GnssLog:
    """GNSS packet log: continuous GPS time tags (s), optional height (m), file lines."""

    t: np.ndarray
    h: np.ndarray | None
    lines: np.ndarray
    path: Path


def read_gnss_log(path: str | Path, fmt: GnssLogFormat | None = None) -> GnssLog:
    """Read a GNSS packet log (default: CSV `gps_week,gps_sow[,h]`); times must increase."""
    fmt = fmt or GnssLogFormat()
    path = Path(path)
    wanted = {"time": fmt.time, "week": fmt.week, "height": fmt.height}
    req = ("time", "week") if fmt.week is not None else ("time",)
    cols, lines = _read_columns(path, fmt.delimiter, fmt.header, wanted, req)
    if "week" in cols:
        validate.gps_week_sow(cols["week"], cols["time"], path, lines, (str(fmt.week), str(fmt.time)))
    t = cols["time"] + (cols["week"] * SECONDS_PER_WEEK if "week" in cols else 0.0)
    validate.gps_seconds_values(t, path, str(fmt.time), lines)
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        raise InputError("time does not increase", path, int(lines[back[0] + 1]), str(fmt.time))
    if cols.get("height") is not None:
        validate.values_in_range(cols["height"], -validate.MAX_HEIGHT_M, validate.MAX_HEIGHT_M, path, str(fmt.height),
                                 lines, unit="m")
    return GnssLog(t, cols.get("height"), lines, path)
