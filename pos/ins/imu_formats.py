"""Declarative IMU text/CSV formats: one description (a TOML file, a preset, or KEY=VALUE flags) -> `ImuData`.

A description says where each quantity is and what it means:

    preset = "rtklibexplorer"     # optional: start from a preset, then override
    delimiter = ","                # "," ";" "tab" "whitespace"; default: comma if the first row has one
    header = "auto"                # "auto" (first row not numeric = header), true, false
    skip_first = 1                 # data rows dropped at the start / end (a logger's truncated lines)
    skip_last = 1
    kind = "rates"                 # "rates" (gyro deg/s.., accel g..) or "increments" (rad, m/s)
    [columns]                      # 0-based index or header name
    gx = 3; gy = 4; gz = 5; ax = 0; ay = 1; az = 2; tick = 6      # time: "time" (+ "week"), or "tick"
    [units]
    gyro = "deg/s"                 # rates: rad/s deg/s deg/h; increments: rad deg
    accel = "g"                    # rates: m/s2 g mg; increments: m/s
    [time]
    kind = "tick"                  # gps_sow (+ week column or --gps-week), gps (continuous GPS s), unix_utc,
                                   # unix_gpst (RTKLIB's seconds since 1970 on the GPS scale), utc / gpst
                                   # (calendar text), tick (counter + RTKLIB time-tag file)
    scale = 1.0                    # numeric time column -> seconds (1e-6 for microseconds)
    tick_s = 0.001                 # tick: counter unit (s)
    tag = "auto"                   # tick: the RTKLIB .tag file ("auto": the IMU file + ".tag"; relative to it)
    offset_s = 0.0                 # added to every sample time (e.g. a logging delay of -0.125 s)
    leap_seconds = 18              # unix_utc / utc: GPS-UTC (default: the leap-second table)
    [axes]                         # sensor axes -> body FRD, applied after the signs
    sensor_axes = "FRD"            # where sensor x, y, z point in the body: letters of F/B, R/L, D/U
    euler_zyx_deg = [180, 0, 180]  # roll, pitch, yaw of the body axes seen from the sensor axes:
                                   # R_body_to_sensor = Rz(yaw) Ry(pitch) Rx(roll) (as dgcal's NED->body attitude)
    mounting_deg = [0, -6.79, 5.35]
    mounting = "add"               # "add": angles added to euler_zyx_deg (rtklibexplorer GNSS_IMU's convention),
                                   # "compose": a further rotation from the nominal frame to the body
    gyro_sign = [1, 1, 1]          # per sensor axis, before the rotation
    accel_sign = [1, 1, 1]         # (-1, -1, -1) for a sensor that reports gravity instead of specific force

Presets: `dgcal` (dgcal's CSV), `kf-gins` (KF-GINS/OB_GINS text), `rtklibexplorer` (the rtklibexplorer
GNSS_IMU logger CSV `ax,ay,az[g],gx,gy,gz[deg/s],ms counter` + `.tag`, sensor axes as logged),
`rtklibexplorer-sf` (GNSS_IMU's converted `*_sf.csv`: RTKLIB GPST seconds, accel in g, gyro rad/s).
"""
from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.fields.key_values import split_key_value
from dgcal.fields.io.timescales import gps_from_unix_gpst, gps_from_unix_utc
from dgcal.fields.io.validate import toml_numbers_in_range
from dgcal.pos.ins.imu_data import ACC_UNITS, GYRO_UNITS, ImuData, data_lines, finish_imu, parse_numeric
from dgcal.pos.ins.time_tags import read_time_tag, ticks_to_gps

TIME_KINDS = ("gps_sow", "gps", "unix_utc", "unix_gpst", "utc", "gpst", "tick")
_DELIMS = {",": ",", ";": ";", "tab": "\t", "\t": "\t", "whitespace": None, "space": None, " ": None}
_AXIS = {"F": (1, 0, 0), "B": (-1, 0, 0), "R": (0, 1, 0), "L": (0, -1, 0), "D": (0, 0, 1), "U": (0, 0, -1)}
_TOP_KEYS = {"preset", "name", "delimiter", "header", "skip_first", "skip_last", "kind", "comment",
             "columns", "units", "time", "axes"}
_SECTION_KEYS = {
    "columns": {"time", "week", "tick", "gx", "gy", "gz", "ax", "ay", "az"},
    "units": {"gyro", "accel"},
    "time": {"kind", "scale", "tick_s", "tag", "offset_s", "leap_seconds", "gps_week"},
    "axes": {"sensor_axes", "euler_zyx_deg", "mounting_deg", "mounting", "gyro_sign", "accel_sign",
             "R_sensor_to_body"},
}

PRESETS: dict[str, dict] = {
    "dgcal": {"delimiter": ",", "header": True, "kind": "increments",
              "columns": {"week": "gps_week", "time": "gps_sow", "gx": "gx", "gy": "gy", "gz": "gz",
                          "ax": "ax", "ay": "ay", "az": "az"},
              "units": {"gyro": "rad", "accel": "m/s"}, "time": {"kind": "gps_sow"}},
    "kf-gins": {"delimiter": "whitespace", "header": "auto", "kind": "increments",
                "columns": {"time": 0, "gx": 1, "gy": 2, "gz": 3, "ax": 4, "ay": 5, "az": 6},
                "units": {"gyro": "rad", "accel": "m/s"}, "time": {"kind": "gps_sow"}},
    "rtklibexplorer": {"delimiter": ",", "header": False, "skip_first": 1, "skip_last": 1, "kind": "rates",
                       "columns": {"ax": 0, "ay": 1, "az": 2, "gx": 3, "gy": 4, "gz": 5, "tick": 6},
                       "units": {"gyro": "deg/s", "accel": "g"},
                       "time": {"kind": "tick", "tick_s": 0.001, "tag": "auto"}},
    "rtklibexplorer-sf": {"delimiter": ",", "header": False, "kind": "rates",
                          "columns": {"time": 0, "ax": 1, "ay": 2, "az": 3, "gx": 4, "gy": 5, "gz": 6},
                          "units": {"gyro": "rad/s", "accel": "g"}, "time": {"kind": "unix_gpst"}},
}


@dataclass
class ImuFormat:
    """A resolved IMU file description (see the module docstring); `source` names where it came from."""

    delimiter: str | None = None
    header: str | bool = "auto"
    skip_first: int = 0
    skip_last: int = 0
    kind: str = "increments"
    columns: dict[str, Any] = field(default_factory=dict)
    gyro_unit: str | None = None
    accel_unit: str | None = None
    time_kind: str = "gps_sow"
    time_scale: float = 1.0
    tick_s: float = 1e-3
    tag: str | None = "auto"
    time_offset_s: float = 0.0
    leap_seconds: float | None = None
    gps_week: int | None = None
    R_sensor_to_body: np.ndarray = field(default_factory=lambda: np.eye(3))
    gyro_sign: np.ndarray = field(default_factory=lambda: np.ones(3))
    accel_sign: np.ndarray = field(default_factory=lambda: np.ones(3))
    source: str = "default"
    base_dir: Path | None = None


# --------------------------------------------------------------------------------------------- rotations
def R_sensor_to_body_from_euler_zyx(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """R_sensor_to_body from the Z-Y-X Euler angles (deg) of the body axes seen from the sensor axes:
    R_body_to_sensor = Rz(yaw) Ry(pitch) Rx(roll), so R_sensor_to_body is its transpose (Groves' C_s^b)."""
    r, p, y = np.radians([roll_deg, pitch_deg, yaw_deg])
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return (Rz @ Ry @ Rx).T


def euler_zyx_from_R_sensor_to_body(R_sensor_to_body: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (deg) of `R_sensor_to_body_from_euler_zyx` (pitch in [-90, 90])."""
    C = np.asarray(R_sensor_to_body, float)   # = R_body_to_sensor^T, Groves' C_s^b
    roll = np.arctan2(C[1, 2], C[2, 2])
    pitch = -np.arcsin(np.clip(C[0, 2], -1.0, 1.0))
    yaw = np.arctan2(C[0, 1], C[0, 0])
    return np.degrees([roll, pitch, yaw])


def R_sensor_to_body_from_axes(axes: str) -> np.ndarray:
    """R_sensor_to_body of a sensor whose x, y, z axes point along body F/B, R/L, D/U (e.g. 'FLU' for ROS)."""
    a = str(axes).strip().upper()
    if len(a) != 3 or any(c not in _AXIS for c in a):
        raise ValueError(f"sensor axes {axes!r}: three letters of F, B, R, L, D, U")
    R = np.array([_AXIS[c] for c in a], float).T   # column j: body direction of sensor axis j
    if abs(np.linalg.det(R) - 1.0) > 1e-9:
        raise ValueError(f"sensor axes {axes!r} are not a right-handed frame")
    return R


def axes_from_R_sensor_to_body(R_sensor_to_body: np.ndarray) -> str:
    """The letters of `R_sensor_to_body_from_axes` for an axis-permutation rotation."""
    R = np.round(np.asarray(R_sensor_to_body, float)).astype(int)
    inv = {v: k for k, v in _AXIS.items()}
    return "".join(inv[tuple(int(x) for x in R[:, j])] for j in range(3))


# --------------------------------------------------------------------------------------------- descriptions
def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _parse_value(text: str):
    """A flag value as TOML would read it (number, bool, list, string)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def format_dict(spec: str | Path | dict | None, overrides=(), where: str = "imu.format"
                ) -> tuple[dict, str, Path | None]:
    """The raw description of a preset name, a TOML file or a dict, with `overrides` (`section.key=value`)
    and any `preset` it names merged under it; returns (dict, source name, directory of the TOML file)."""
    base_dir = None
    if spec is None:
        d, src = {}, "default"
    elif isinstance(spec, dict):
        d, src = copy.deepcopy(spec), "dict"
    elif str(spec).lower() in PRESETS:
        d, src = {"preset": str(spec).lower()}, str(spec).lower()
    else:
        path = Path(spec)
        if not path.is_file():
            raise InputError(f"neither a preset ({', '.join(PRESETS)}) nor a file", path, field=where)
        try:
            text = path.read_text(encoding="utf-8")
            d = toml_numbers_in_range(tomllib.loads(text), path, text)
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"cannot read: {exc}", path) from None
        except tomllib.TOMLDecodeError as exc:
            line = getattr(exc, "lineno", None)
            msg = str(exc).split(" (at line")[0]
            raise InputError(f"not valid TOML: {msg}", path, line) from None
        src, base_dir = str(path), path.parent
    for item in overrides:
        key, val = split_key_value(item, "imu.overrides")
        parts = key.split(".")
        node = d
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise InputError(f"{key!r}: {p!r} is not a section", field="imu.overrides")
        node[parts[-1]] = _parse_value(val)
    preset = d.pop("preset", None)
    if preset is not None:
        if str(preset).lower() not in PRESETS:
            raise InputError(f"unknown preset {preset!r} (one of {', '.join(PRESETS)})", src, field="preset")
        d = _merge(PRESETS[str(preset).lower()], d)
    return d, src, base_dir


def _check_keys(d: dict, src: str) -> None:
    for k, v in d.items():
        if k not in _TOP_KEYS:
            raise InputError(f"unknown key {k!r} (one of {', '.join(sorted(_TOP_KEYS))})", src, field=k)
        if k in _SECTION_KEYS:
            if not isinstance(v, dict):
                raise InputError("must be a table ([section])", src, field=k)
            bad = [s for s in v if s not in _SECTION_KEYS[k]]
            if bad:
                raise InputError(f"unknown key {bad[0]!r} (one of {', '.join(sorted(_SECTION_KEYS[k]))})", src,
                                 field=f"{k}.{bad[0]}")


def _vec3(v, src: str, name: str) -> np.ndarray:
    try:
        a = np.asarray(v, float)
    except (TypeError, ValueError):
        raise InputError(f"expected three numbers, got {v!r}", src, field=name) from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"expected three numbers, got {v!r}", src, field=name)
    return a


def imu_format(spec: str | Path | dict | None = None, overrides=(), time_offset_s: float | None = None,
               gps_week: int | None = None) -> ImuFormat:
    """Resolve a description (preset name, TOML path or dict) with `--imu-set` overrides into an ImuFormat;
    `time_offset_s` (the CLI's --imu-time-offset) is added to the description's own offset."""
    d, src, base_dir = format_dict(spec, overrides)
    _check_keys(d, src)
    f = ImuFormat(source=src, base_dir=base_dir)
    delim = d.get("delimiter")
    if delim is not None:
        if str(delim).lower() not in _DELIMS:
            raise InputError(f"unknown delimiter {delim!r} (one of ',', ';', 'tab', 'whitespace')", src,
                             field="delimiter")
        f.delimiter = _DELIMS[str(delim).lower()]
        f.delimiter = "ws" if f.delimiter is None else f.delimiter
    hdr = d.get("header", "auto")
    if hdr not in (True, False, "auto"):
        raise InputError(f"header must be true, false or \"auto\", not {hdr!r}", src, field="header")
    f.header = hdr
    for k in ("skip_first", "skip_last"):
        v = d.get(k, 0)
        if not isinstance(v, int) or isinstance(v, bool) or v < 0:
            raise InputError(f"must be a whole number >= 0, not {v!r}", src, field=k)
        setattr(f, k, v)
    f.kind = str(d.get("kind", "increments"))
    if f.kind not in ("rates", "increments"):
        raise InputError(f"kind must be \"rates\" or \"increments\", not {f.kind!r}", src, field="kind")
    cols = dict(d.get("columns", {}))
    for k, v in cols.items():
        if not (isinstance(v, str) and v.strip()) and not (isinstance(v, int) and not isinstance(v, bool) and v >= 0):
            raise InputError(f"a column is a 0-based index or a header name, not {v!r}", src, field=f"columns.{k}")
    units = d.get("units", {})
    f.gyro_unit = units.get("gyro") or ("rad" if f.kind == "increments" else "rad/s")
    f.accel_unit = units.get("accel") or ("m/s" if f.kind == "increments" else "m/s2")
    ok_g = ("rad", "deg") if f.kind == "increments" else ("rad/s", "deg/s", "deg/h")
    ok_a = ("m/s",) if f.kind == "increments" else ("m/s2", "m/s^2", "g", "mg")
    if f.gyro_unit not in ok_g:
        raise InputError(f"gyro unit {f.gyro_unit!r} for {f.kind} (one of {', '.join(ok_g)})", src, field="units.gyro")
    if f.accel_unit not in ok_a:
        raise InputError(f"accelerometer unit {f.accel_unit!r} for {f.kind} (one of {', '.join(ok_a)})", src,
                         field="units.accel")
    tm = d.get("time", {})
    f.time_kind = str(tm.get("kind", "gps_sow"))
    if f.time_kind not in TIME_KINDS:
        raise InputError(f"time kind {f.time_kind!r} (one of {', '.join(TIME_KINDS)})", src, field="time.kind")
    for key, attr in (("scale", "time_scale"), ("tick_s", "tick_s"), ("offset_s", "time_offset_s"),
                      ("leap_seconds", "leap_seconds")):
        if key in tm:
            v = tm[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise InputError(f"must be a number, not {v!r}", src, field=f"time.{key}")
            setattr(f, attr, float(v))
    if f.time_scale <= 0 or f.tick_s <= 0:
        raise InputError("must be positive", src, field="time.scale" if f.time_scale <= 0 else "time.tick_s")
    f.tag = tm.get("tag", "auto")
    wk = tm.get("gps_week", gps_week)
    if wk is not None:
        if isinstance(wk, bool) or not isinstance(wk, int) or wk < 0:
            raise InputError(f"must be a whole number >= 0, not {wk!r}", src, field="time.gps_week")
        f.gps_week = int(wk)
    if time_offset_s is not None:
        f.time_offset_s += float(time_offset_s)
    need = ["gx", "gy", "gz", "ax", "ay", "az"] + (["tick"] if f.time_kind == "tick" else ["time"])
    missing = [k for k in need if k not in cols]
    if missing:
        raise InputError(f"no column given for {', '.join(missing)}", src, field=f"columns.{missing[0]}")
    f.columns = cols
    ax = d.get("axes", {})
    try:
        R = R_sensor_to_body_from_axes(ax.get("sensor_axes", "FRD"))
    except ValueError as exc:
        raise InputError(str(exc), src, field="axes.sensor_axes") from None
    if "R_sensor_to_body" in ax:
        try:
            M = np.asarray(ax["R_sensor_to_body"], float)
        except (TypeError, ValueError):
            M = np.zeros(0)
        if M.shape != (3, 3) or not np.allclose(M @ M.T, np.eye(3), atol=1e-6) or np.linalg.det(M) < 0:
            raise InputError("must be a 3x3 rotation matrix (rows)", src, field="axes.R_sensor_to_body")
        R = M @ R
    eul = _vec3(ax.get("euler_zyx_deg", [0.0, 0.0, 0.0]), src, "axes.euler_zyx_deg")
    mnt = _vec3(ax.get("mounting_deg", [0.0, 0.0, 0.0]), src, "axes.mounting_deg")
    mode = str(ax.get("mounting", "compose"))
    if mode not in ("add", "compose"):
        raise InputError(f"must be \"add\" or \"compose\", not {mode!r}", src, field="axes.mounting")
    if mode == "add":
        R = R_sensor_to_body_from_euler_zyx(*(eul + mnt)) @ R
    else:
        R = R_sensor_to_body_from_euler_zyx(*mnt) @ R_sensor_to_body_from_euler_zyx(*eul) @ R
    f.R_sensor_to_body = R
    for key in ("gyro_sign", "accel_sign"):
        s = _vec3(ax.get(key, [1, 1, 1]), src, f"axes.{key}")
        if not np.all(np.isin(s, (-1.0, 1.0))):
            raise InputError(f"signs are 1 or -1, not {s.tolist()}", src, field=f"axes.{key}")
        setattr(f, key, s)
    return f


# --------------------------------------------------------------------------------------------- reading
def _tag_path(fmt: ImuFormat, path: Path, tag: str | Path | None) -> Path:
    if tag is not None:
        return Path(tag)
    if fmt.tag in (None, "", "auto"):
        return path.with_name(path.name + ".tag")
    p = Path(fmt.tag)
    return p if p.is_absolute() or fmt.base_dir is None else fmt.base_dir / p


def _column_index(fmt: ImuFormat, names: list[str] | None, key: str, path: Path, header_line: int) -> int:
    c = fmt.columns[key]
    if isinstance(c, int):
        return c
    if names is None:
        raise InputError(f"column {c!r} named but the file has no header row", path, field=f"columns.{key}")
    low = [n.lower() for n in names]
    if c.strip().lower() not in low:
        raise InputError(f"column {c!r} not in the header ({', '.join(names)})", path, header_line or None, key)
    return low.index(c.strip().lower())


def read_imu(path: str | Path, fmt: ImuFormat | str | dict | None = None, tag: str | Path | None = None,
             gps_week: int | None = None, rate_hz: float | None = None) -> ImuData:
    """Read an IMU text/CSV file as `fmt` describes it -> ImuData (body FRD increments, continuous GPS s).

    `tag`: the RTKLIB time-tag file for tick counters (default from the description); `gps_week` for
    seconds-of-week times without a week column (the description's own `time.gps_week` wins)."""
    path = Path(path)
    if not isinstance(fmt, ImuFormat):
        fmt = imu_format(fmt)
    rows, lines, header, header_line = data_lines(path, header=fmt.header, delimiter=fmt.delimiter)
    if fmt.skip_first or fmt.skip_last:
        n = len(rows)
        sl = slice(fmt.skip_first, n - fmt.skip_last)
        rows, lines = rows[sl], lines[sl]
        if not rows:
            raise InputError(f"no IMU rows left after skipping {fmt.skip_first} first and {fmt.skip_last} last",
                             path)
    delim = fmt.delimiter if fmt.delimiter is not None else ("," if "," in rows[0] else "ws")
    sep = None if delim == "ws" else delim
    names = None
    if header is not None:
        names = [c.strip() for c in (header.split(sep) if sep else header.split())]
    keys = ["gx", "gy", "gz", "ax", "ay", "az"]
    tkey = "tick" if fmt.time_kind == "tick" else "time"
    idx = {k: _column_index(fmt, names, k, path, header_line) for k in keys + [tkey]}
    if "week" in fmt.columns and fmt.time_kind == "gps_sow":
        idx["week"] = _column_index(fmt, names, "week", path, header_line)
    text_time = fmt.time_kind in ("utc", "gpst")
    numeric = sorted({j for k, j in idx.items() if not (text_time and k == "time")})
    arr = parse_numeric(path, rows, lines, max(idx.values()) + 1, sep, usecols=numeric)
    col = {k: arr[:, numeric.index(j)] for k, j in idx.items() if j in numeric and not (text_time and k == "time")}
    t = _sample_times(fmt, path, rows, lines, sep, idx, col, tag, gps_week)
    t = t + fmt.time_offset_s
    g = np.column_stack([col[k] for k in keys[:3]]) * GYRO_UNITS[fmt.gyro_unit] * fmt.gyro_sign
    a = np.column_stack([col[k] for k in keys[3:]]) * ACC_UNITS[fmt.accel_unit] * fmt.accel_sign
    R = fmt.R_sensor_to_body
    return finish_imu(path, lines, t, g @ R.T, a @ R.T, fmt.kind, rate_hz, None)


def _sample_times(fmt: ImuFormat, path: Path, rows, lines, sep, idx, col, tag, gps_week) -> np.ndarray:
    """Continuous GPS seconds of every row from the description's time kind."""
    kind = fmt.time_kind
    if kind == "tick":
        tt = read_time_tag(_tag_path(fmt, path, tag))
        c = col["tick"]
        back = np.flatnonzero(np.diff(c) <= 0)
        if back.size:
            k = back[0] + 1
            raise InputError(f"counter does not increase ({c[k]:g} after {c[k - 1]:g})", path, int(lines[k]), "tick")
        return ticks_to_gps(tt, c, fmt.tick_s)
    if kind in ("utc", "gpst"):
        j = idx["time"]
        toks = [(r.split(sep) if sep else r.split()) for r in rows]
        short = [k for k, tk in enumerate(toks) if len(tk) <= j]
        if short:
            raise InputError(f"no time column {j + 1}", path, int(lines[short[0]]), "time")
        txt = np.array([tk[j].strip() for tk in toks])
        u = _calendar_seconds(txt, path, lines)
        return gps_from_unix_utc(u, fmt.leap_seconds) if kind == "utc" else gps_from_unix_gpst(u)
    v = col["time"] * fmt.time_scale
    if kind == "gps":
        return v
    if kind == "unix_utc":
        return gps_from_unix_utc(v, fmt.leap_seconds)
    if kind == "unix_gpst":
        return gps_from_unix_gpst(v)
    # gps_sow
    bad = np.flatnonzero((v < 0) | (v >= SECONDS_PER_WEEK))
    if bad.size:
        raise InputError(f"seconds of week out of range: {v[bad[0]]!r}", path, int(lines[bad[0]]), "time")
    if "week" in col:
        w = col["week"]
        badw = np.flatnonzero((w != np.round(w)) | (w < 0))
        if badw.size:
            raise InputError(f"GPS week must be a whole number >= 0: {w[badw[0]]!r}", path, int(lines[badw[0]]),
                             "week")
        return w * SECONDS_PER_WEEK + v
    week = fmt.gps_week if fmt.gps_week is not None else gps_week
    roll = np.concatenate([[0.0], np.cumsum(np.diff(v) < -SECONDS_PER_WEEK / 2)]) * SECONDS_PER_WEEK
    return v + roll + (0.0 if week is None else week * SECONDS_PER_WEEK)


def _calendar_seconds(txt: np.ndarray, path: Path, lines: np.ndarray) -> np.ndarray:
    """Seconds since 1970 of ISO-like date-time texts (vectorised through numpy datetime64)."""
    norm = np.char.replace(np.char.replace(np.char.rstrip(np.char.rstrip(txt, "Z"), "z"), "/", "-"), " ", "T")
    try:
        d = norm.astype("datetime64[ns]")
    except ValueError:
        d = None
    if d is None or np.isnat(d).any():
        for k, s in enumerate(norm):
            try:
                x = np.datetime64(str(s), "ns")
                if np.isnat(x):
                    raise ValueError
            except ValueError:
                raise InputError(f"not a date-time: {txt[k]!r}", path, int(lines[k]), "time") from None
    return (d - np.datetime64("1970-01-01T00:00:00", "ns")).astype(np.int64) * 1e-9


def describe(fmt: ImuFormat) -> dict:
    """A JSON-able summary of a resolved format (for reports)."""
    return {"source": fmt.source, "kind": fmt.kind, "gyro_unit": fmt.gyro_unit, "accel_unit": fmt.accel_unit,
            "time_kind": fmt.time_kind, "time_offset_s": fmt.time_offset_s, "columns": dict(fmt.columns),
            "R_sensor_to_body": np.round(fmt.R_sensor_to_body, 12).tolist(),
            "euler_zyx_deg": euler_zyx_from_R_sensor_to_body(fmt.R_sensor_to_body).round(9).tolist()}
