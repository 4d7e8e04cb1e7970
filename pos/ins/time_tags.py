"""RTKLIB time-tag files (`FILE.tag` beside a stream logged by `str2str`/`rtknavi` with the `-t` time tag option).

Layout (RTKLIB src/stream.c, `openfile_` and `writefile`), little-endian:
- a 64-byte header: the text `TIMETAG RTKLIB <version>`, NUL padded, whose last 4 bytes hold the logger's
  millisecond tick at file start (uint32, `tick_f`);
- uint32 `time` + float64 `sec`: the file start as RTKLIB's gtime_t **in GPS time** (seconds since
  1970-01-01 counted on the GPS time scale, plus the fraction);
- then one record per write: uint32 tick (ms since file start) and the byte position in the data file after
  that write, uint32 (the default `size_fpos` 4) or uint64 (`::P=8`).
`read_time_tag` returns the start as continuous GPS seconds (t = week*604800 + sow) with the records.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dgcal.fields.constants import GPS_EPOCH_UNIX_S
from dgcal.fields.errors import InputError
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.io.timescales import gps_from_unix_gpst

MAX_DATA_FILE_BYTES = 1e12     # a terabyte: no IMU log is larger (a larger position is a damaged tag)

HEADER_LEN = 64
MAGIC = b"TIMETAG RTKLIB"


@dataclass
class TimeTag:
    """An RTKLIB time-tag file: start `t0_gps` (continuous GPS s), `tick_f` (ms tick at start), records."""

    t0_gps: float
    tick_f: int
    version: str
    tick_ms: np.ndarray      # (N,) uint32, ms since the file start
    fpos: np.ndarray         # (N,) bytes of the data file written by then
    path: Path | None = None

    @property
    def t_last_gps(self) -> float:
        """GPS time (s) of the last record."""
        return self.t0_gps + (float(self.tick_ms[-1]) * 1e-3 if len(self.tick_ms) else 0.0)


def read_time_tag(path: str | Path, fpos_bytes: int | None = None) -> TimeTag:
    """Read an RTKLIB `.tag` file; `fpos_bytes` 4 or 8 (default: whichever makes the positions increase)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("time-tag file not found", path)
    raw = path.read_bytes()
    if len(raw) < HEADER_LEN + 12:
        raise InputError(f"time-tag file of {len(raw)} bytes is shorter than its {HEADER_LEN + 12}-byte header",
                         path, field="header")
    if not raw.startswith(MAGIC):
        raise InputError(f"not an RTKLIB time-tag file (starts {raw[:14]!r}, expected {MAGIC!r})", path,
                         field="header")
    version = raw[len(MAGIC):HEADER_LEN - 4].split(b"\0", 1)[0].decode("ascii", "replace").strip()
    tick_f = int(np.frombuffer(raw, "<u4", 1, HEADER_LEN - 4)[0])
    time_s = int(np.frombuffer(raw, "<u4", 1, HEADER_LEN)[0])
    frac = float(np.frombuffer(raw, "<f8", 1, HEADER_LEN + 4)[0])
    if not (np.isfinite(frac) and 0.0 <= frac < 1.0):
        raise InputError(f"start-time fraction {frac!r} is not in [0, 1)", path, field="time")
    if time_s < 315964800:
        raise InputError(f"start time {time_s} s is before the GPS epoch", path, field="time")
    body = raw[HEADER_LEN + 12:]
    sizes = (fpos_bytes,) if fpos_bytes else (4, 8)
    tick = fpos = None
    for size in sizes:
        rec = 4 + size
        if len(body) % rec:
            continue
        n = len(body) // rec
        dt = np.dtype([("tick", "<u4"), ("fpos", "<u4" if size == 4 else "<u8")])
        r = np.frombuffer(body, dt, n)
        if n == 0 or fpos_bytes or np.all(np.diff(r["fpos"].astype(np.int64)) >= 0):
            tick, fpos = r["tick"].astype(np.int64), r["fpos"].astype(np.int64)
            break
    if tick is None:
        raise InputError(f"record block of {len(body)} bytes is not a whole number of (tick, position) records",
                         path, field="record")
    big = np.flatnonzero(fpos > MAX_DATA_FILE_BYTES)
    if big.size:
        raise InputError(f"file position {fpos[big[0]]} at record {big[0] + 1} is beyond any data file "
                         f"({MAX_DATA_FILE_BYTES:.0e} bytes)", path, field="fpos")
    back = np.flatnonzero(np.diff(tick) < 0)
    if back.size:
        raise InputError(f"tick goes back at record {back[0] + 2} ({tick[back[0] + 1]} after {tick[back[0]]} ms)",
                         path, field="tick")
    return TimeTag(float(gps_from_unix_gpst(time_s)) + frac, tick_f, version, tick, fpos, path)


def write_time_tag(path: str | Path, t0_gps: float, tick_ms, fpos, tick_f: int = 0,
                   version: str = "demo5") -> None:
    """Write an RTKLIB time-tag file (4-byte positions), for tests and simulated loggers."""
    u = float(t0_gps) + GPS_EPOCH_UNIX_S
    whole = int(np.floor(u))
    head = bytearray(HEADER_LEN)
    text = MAGIC + b" " + version.encode("ascii")
    head[:len(text)] = text
    head[HEADER_LEN - 4:] = np.uint32(tick_f).tobytes()
    dt = np.dtype([("tick", "<u4"), ("fpos", "<u4")])
    rec = np.zeros(len(tick_ms), dt)
    rec["tick"], rec["fpos"] = tick_ms, fpos
    with atomic_write(path, "wb") as fh:
        fh.write(bytes(head) + np.uint32(whole).tobytes() + np.float64(u - whole).tobytes() + rec.tobytes())


def ticks_to_gps(tag: TimeTag, counter: np.ndarray, tick_s: float = 1e-3) -> np.ndarray:
    """GPS times (s) of samples stamped by their own counter, mapped linearly so that the first sample is at the
    tag's start and the last at its last record (rtklibexplorer GNSS_IMU `convert_imu_file.py`)."""
    c = np.asarray(counter, float) * tick_s
    span = c[-1] - c[0]
    if len(c) < 2 or span <= 0:
        raise InputError("the sample counter does not increase over the file", tag.path, field="tick")
    dur = tag.t_last_gps - tag.t0_gps
    if dur <= 0:
        raise InputError("the time-tag file has no records after its start", tag.path, field="record")
    return tag.t0_gps + (c - c[0]) * (dur / span)
