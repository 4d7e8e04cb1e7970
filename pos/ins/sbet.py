"""Applanix SBET trajectories (and their SMRMSG accuracy files): binary read/write.

SBET: headerless little-endian records of 17 float64 (136 bytes): GPS seconds of week, latitude,
longitude (rad), ellipsoidal height (m), velocity x, y, z (m/s, wander-azimuth frame, z down), roll,
pitch, platform (true) heading, wander angle (rad), body acceleration x, y, z (m/s^2), body angular
rate x, y, z (rad/s). The wander frame's x axis is `wander` clockwise from true north, so
v_N = x cos(w) - y sin(w), v_E = x sin(w) + y cos(w). dgcal writes wander = 0.
SMRMSG: records of 10 float64: time, north/east/down position RMS (m), north/east/down velocity RMS
(m/s), roll/pitch/heading RMS (arc minutes).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.io.formats import Trajectory, read_trajectory

SBET_FIELDS = ("time", "lat", "lon", "alt", "vx", "vy", "vz", "roll", "pitch", "heading", "wander",
               "ax", "ay", "az", "wx", "wy", "wz")
SBET_DTYPE = np.dtype([(n, "<f8") for n in SBET_FIELDS])
SMRMSG_FIELDS = ("time", "s_north", "s_east", "s_down", "s_vn", "s_ve", "s_vd", "s_roll", "s_pitch", "s_heading")
SMRMSG_DTYPE = np.dtype([(n, "<f8") for n in SMRMSG_FIELDS])
ARCMIN = 1.0 / 60.0  # degrees
SMRMSG_MAX_SIGMA = 21600.0   # m, m/s or arcmin (360 deg): a larger sigma is no estimate


@dataclass
class Sbet:
    """An SBET as a dgcal trajectory plus the fields dgcal's trajectory has no place for."""

    trajectory: Trajectory
    wander_rad: np.ndarray
    accel_b: np.ndarray  # m/s^2, body
    omega_b: np.ndarray  # rad/s, body


def _read_records(path: Path, dtype: np.dtype, what: str) -> np.ndarray:
    if not path.is_file():
        raise InputError("file not found", path)
    size = path.stat().st_size
    if size == 0:
        raise InputError(f"empty {what} file", path)
    if size % dtype.itemsize:
        n_full = size // dtype.itemsize
        raise InputError(f"{what} file size {size} is not a multiple of {dtype.itemsize} bytes "
                         f"(record {n_full + 1} is truncated)", path, field="record")
    rec = np.fromfile(path, dtype=dtype)
    flat = rec.view("<f8").reshape(len(rec), -1)
    bad = np.flatnonzero(~np.isfinite(flat).all(axis=1))
    if bad.size:
        j = int(np.flatnonzero(~np.isfinite(flat[bad[0]]))[0])
        raise InputError(f"non-finite value in record {bad[0] + 1}", path, field=dtype.names[j])
    return rec


def _gps_time(path: Path, sow: np.ndarray, gps_week: int | None) -> np.ndarray:
    if gps_week is None:  # already continuous GPS seconds
        return sow.astype(float)
    roll = np.concatenate([[0.0], np.cumsum(np.diff(sow) < -SECONDS_PER_WEEK / 2)]) * SECONDS_PER_WEEK
    t = gps_week * SECONDS_PER_WEEK + sow + roll
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        raise InputError(f"time does not increase at record {back[0] + 2}", path, field="time")
    return t


# what an SBET record can hold (radians, metres, m/s, m/s^2, rad/s): beyond is a corrupt file or another format
SBET_LIMITS = {"time": (-1.0, 2.0e9), "lat": (-np.pi / 2, np.pi / 2), "lon": (-2 * np.pi, 2 * np.pi),
               "alt": (-1.0e3, 1.0e5), "vx": (-1.0e3, 1.0e3), "vy": (-1.0e3, 1.0e3), "vz": (-1.0e3, 1.0e3),
               "roll": (-7.0, 7.0), "pitch": (-7.0, 7.0), "heading": (-7.0, 7.0), "wander": (-7.0, 7.0),
               "ax": (-2.0e3, 2.0e3), "ay": (-2.0e3, 2.0e3), "az": (-2.0e3, 2.0e3),
               "wx": (-100.0, 100.0), "wy": (-100.0, 100.0), "wz": (-100.0, 100.0)}


def _check_sbet_ranges(r: np.ndarray, path: Path) -> None:
    """Every field of every record within `SBET_LIMITS`; InputError naming the record and field."""
    for name, (lo, hi) in SBET_LIMITS.items():
        bad = np.flatnonzero((r[name] < lo) | (r[name] > hi))
        if bad.size:
            raise InputError(f"{r[name][bad[0]]:.6g} in record {bad[0] + 1} is outside [{lo:g}, {hi:g}]: a corrupt "
                             "file, or not an SBET", path, field=name)


def read_sbet(path: str | Path, gps_week: int | None) -> Sbet:
    """Read an SBET; times are GPS seconds of week of `gps_week` (None: the file holds continuous GPS seconds)."""
    path = Path(path)
    r = _read_records(path, SBET_DTYPE, "SBET")
    _check_sbet_ranges(r, path)
    t = _gps_time(path, r["time"], gps_week)
    w = r["wander"]
    cw, sw = np.cos(w), np.sin(w)
    v_ned = np.column_stack([r["vx"] * cw - r["vy"] * sw, r["vx"] * sw + r["vy"] * cw, r["vz"]])
    rph = np.degrees(np.column_stack([r["roll"], r["pitch"], r["heading"]]))
    rph[:, 2] = np.mod(rph[:, 2], 360.0)
    tr = Trajectory(t=t, lat=np.degrees(r["lat"]), lon=np.degrees(r["lon"]), h=r["alt"].copy(), v_ned=v_ned,
                    rph=rph, lines=np.arange(1, len(r) + 1), path=path)
    return Sbet(tr, w.copy(), np.column_stack([r["ax"], r["ay"], r["az"]]),
                np.column_stack([r["wx"], r["wy"], r["wz"]]))


def write_sbet(path: str | Path, traj: Trajectory, accel_b: np.ndarray | None = None,
               omega_b: np.ndarray | None = None) -> None:
    """Write a trajectory as an SBET (seconds of week, wander 0), atomically."""
    n = len(traj.t)
    rec = np.zeros(n, dtype=SBET_DTYPE)
    rec["time"] = np.mod(np.asarray(traj.t, float), SECONDS_PER_WEEK)
    rec["lat"], rec["lon"], rec["alt"] = np.radians(traj.lat), np.radians(traj.lon), traj.h
    rec["vx"], rec["vy"], rec["vz"] = traj.v_ned[:, 0], traj.v_ned[:, 1], traj.v_ned[:, 2]
    rec["roll"], rec["pitch"], rec["heading"] = (np.radians(traj.rph[:, i]) for i in range(3))
    if accel_b is not None:
        rec["ax"], rec["ay"], rec["az"] = np.asarray(accel_b, float).T
    if omega_b is not None:
        rec["wx"], rec["wy"], rec["wz"] = np.asarray(omega_b, float).T
    with atomic_write(path, "wb") as fh:
        fh.write(rec.tobytes())


def read_smrmsg(path: str | Path, gps_week: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Read an SMRMSG file: (t GPS s, sigma (N,6) = s_north, s_east, s_down m, s_roll, s_pitch, s_heading deg)."""
    path = Path(path)
    r = _read_records(path, SMRMSG_DTYPE, "SMRMSG")
    for name in SMRMSG_FIELDS[1:]:     # sigmas: m, m/s, arcmin (NaN, negative and 1e20 are a corrupt file)
        bad = np.flatnonzero(~((r[name] >= 0) & (r[name] <= SMRMSG_MAX_SIGMA)))
        if bad.size:
            raise InputError(f"{r[name][bad[0]]:.6g} in record {bad[0] + 1} is outside [0, {SMRMSG_MAX_SIGMA:g}]: a "
                             "corrupt file, or not an SMRMSG", path, field=name)
    t = _gps_time(path, r["time"], gps_week)
    sig = np.column_stack([r["s_north"], r["s_east"], r["s_down"],
                           r["s_roll"] * ARCMIN, r["s_pitch"] * ARCMIN, r["s_heading"] * ARCMIN])
    return t, sig


def write_smrmsg(path: str | Path, traj: Trajectory, sigma_v: np.ndarray | None = None) -> None:
    """Write the trajectory's sigmas (s_lat_m, s_lon_m, s_h_m, s_roll, s_pitch, s_heading) as SMRMSG."""
    if traj.sigma is None:
        raise ValueError("trajectory has no sigmas to write")
    n = len(traj.t)
    rec = np.zeros(n, dtype=SMRMSG_DTYPE)
    rec["time"] = np.mod(np.asarray(traj.t, float), SECONDS_PER_WEEK)
    s = np.asarray(traj.sigma, float)
    rec["s_north"], rec["s_east"], rec["s_down"] = s[:, 0], s[:, 1], s[:, 2]
    if sigma_v is not None:
        rec["s_vn"], rec["s_ve"], rec["s_vd"] = np.asarray(sigma_v, float).T
    rec["s_roll"], rec["s_pitch"], rec["s_heading"] = s[:, 3] / ARCMIN, s[:, 4] / ARCMIN, s[:, 5] / ARCMIN
    with atomic_write(path, "wb") as fh:
        fh.write(rec.tobytes())


def read_sbet_with_sigmas(sbet_path: str | Path, smrmsg_path: str | Path, gps_week: int | None) -> Sbet:
    """An SBET whose trajectory carries the SMRMSG sigmas, linearly interpolated to the SBET times."""
    sb = read_sbet(sbet_path, gps_week)
    ts, sig = read_smrmsg(smrmsg_path, gps_week)
    t = sb.trajectory.t
    if t[0] < ts[0] - 1.0 or t[-1] > ts[-1] + 1.0:
        raise InputError(f"SMRMSG covers [{ts[0]:.3f}, {ts[-1]:.3f}] but the SBET spans "
                         f"[{t[0]:.3f}, {t[-1]:.3f}]", smrmsg_path, field="time")
    sb.trajectory.sigma = np.column_stack([np.interp(t, ts, sig[:, j]) for j in range(6)])
    return sb


def smrmsg_path_for(sbet_path: str | Path) -> Path:
    """The accuracy file beside an SBET, named as POSPac names it: sbet_X.out -> smrmsg_X.out (else X_smrmsg.out)."""
    p = Path(sbet_path)
    if p.name.lower().startswith("sbet"):
        return p.with_name("smrmsg" + p.name[4:])
    return p.with_name(p.stem + "_smrmsg" + (p.suffix or ".out"))


def write_sbet_files(path: str | Path, traj: Trajectory) -> list[Path]:
    """Write a trajectory as SBET (wander 0, body rates/accelerations 0) and, when it has sigmas, its SMRMSG
    (`smrmsg_path_for`); returns the paths written."""
    path = Path(path)
    write_sbet(path, traj)
    out = [path]
    if traj.sigma is not None:
        sp = smrmsg_path_for(path)
        write_smrmsg(sp, traj)
        out.append(sp)
    return out


def is_sbet_file(path: str | Path) -> bool:
    """True for a headerless binary SBET: a whole number of 136-byte records whose first is plausible
    (seconds of week, latitude/longitude in radians)."""
    p = Path(path)
    try:
        size = p.stat().st_size
        with open(p, "rb") as fh:
            head = fh.read(SBET_DTYPE.itemsize)
    except OSError:
        return False
    if size == 0 or size % SBET_DTYPE.itemsize or len(head) < SBET_DTYPE.itemsize:
        return False
    r = np.frombuffer(head, SBET_DTYPE, 1)[0]
    return bool(0 <= r["time"] < SECONDS_PER_WEEK * 1.01 and abs(r["lat"]) <= np.pi / 2 and abs(r["lon"]) <= 2 * np.pi
                and -1e4 < r["alt"] < 1e5)


def read_any_trajectory(path: str | Path, near_t: float | None = None, gps_week: int | None = None) -> Trajectory:
    """A trajectory from dgcal's CSV or an SBET (with its SMRMSG beside it, if there); an SBET's seconds of week
    get `gps_week`, else the week that puts them nearest to `near_t` (continuous GPS s, e.g. the first event)."""
    path = Path(path)
    if not is_sbet_file(path):
        return read_trajectory(path)
    if gps_week is None:
        if near_t is None:
            raise InputError("an SBET holds seconds of week only: give the GPS week (or the events file)", path,
                             field="time")
        first = float(np.frombuffer(open(path, "rb").read(8), "<f8")[0])
        gps_week = int(np.round((float(near_t) - first) / SECONDS_PER_WEEK))
    sp = smrmsg_path_for(path)
    if sp.is_file():
        return read_sbet_with_sigmas(path, sp, gps_week).trajectory
    return read_sbet(path, gps_week).trajectory
