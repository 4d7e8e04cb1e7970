"""PX4 ULog flight logs (read with pyulog): IMU samples and camera-capture events in dgcal's time and frames.

- IMU: `vehicle_imu` (preferred: `delta_angle` rad and `delta_velocity` m/s integrated over `delta_angle_dt` /
  `delta_velocity_dt` µs, ending at `timestamp_sample`) or `sensor_combined` (`gyro_rad` rad/s and
  `accelerometer_m_s2` averaged over `gyro_integral_dt` / `accelerometer_integral_dt`, at `timestamp` and
  `timestamp + accelerometer_timestamp_relative`). Both are in PX4's body frame, FRD, after the board rotation:
  no axis change.
- Camera events: `camera_capture` (`timestamp` boot µs, `timestamp_utc` µs UTC, `seq`); images are named
  `name_pattern.format(seq=..)`.
- Time: PX4 stamps are microseconds since boot. The boot-to-UTC offset is the median of
  `time_utc_usec - timestamp` of `vehicle_gps_position` (or `sensor_gps`) — as PX4 itself forms
  `timestamp_utc` — and UTC becomes GPS time with the leap seconds (dgcal.fields.io.timescales).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from pyulog import ULog

from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import Events
from dgcal.fields.io.timescales import gps_from_unix_utc
from dgcal.pos.ins.imu_data import ImuData, estimate_rate_hz

GPS_TOPICS = ("vehicle_gps_position", "sensor_gps")


ULOG_MAGIC = b"ULog\x01\x12\x35"


def is_ulog(path: str | Path) -> bool:
    """True when the file starts with the ULog magic bytes."""
    try:
        with open(path, "rb") as fh:
            return fh.read(7) == ULOG_MAGIC
    except OSError:
        return False


def _open(path: Path, topics: list[str]):
    """A pyulog ULog of `topics`; any failure of the library is one InputError naming the file."""
    if not path.is_file():
        raise InputError("file not found", path)
    with open(path, "rb") as fh:
        magic = fh.read(7)
    if magic != ULOG_MAGIC:
        raise InputError(f"not a PX4 ULog file (starts {magic!r})", path, field="header")
    try:
        return ULog(str(path), topics, disable_str_exceptions=True)
    except Exception as exc:  # noqa: BLE001 - pyulog raises many kinds on corrupt files
        msg = str(exc).strip().splitlines()[0][:80] if str(exc).strip() else type(exc).__name__
        raise InputError(f"cannot read the ULog ({msg})", path) from None


def _topic(ulog, name: str, instance: int = 0):
    for d in ulog.data_list:
        if d.name == name and d.multi_id == instance:
            return d
    return None


def boot_to_unix_offset_us(ulog, path: Path) -> float:
    """Median `time_utc_usec - timestamp` (µs) of the GPS messages: boot µs + offset = Unix UTC µs."""
    for name in GPS_TOPICS:
        d = _topic(ulog, name)
        if d is None or "time_utc_usec" not in d.data:
            continue
        utc = d.data["time_utc_usec"].astype(np.int64)
        ts = d.data["timestamp"].astype(np.int64)
        ok = utc > 0
        if ok.sum():
            return float(np.median(utc[ok] - ts[ok]))
    raise InputError(f"no GPS time in the log ({' or '.join(GPS_TOPICS)} with time_utc_usec): cannot map PX4 boot "
                     "time to GPS time", path, field="time_utc_usec")


def _gps_seconds(boot_us: np.ndarray, offset_us: float, leap_seconds: float | None) -> np.ndarray:
    """Continuous GPS seconds of PX4 boot-time stamps (µs) through the boot-to-UTC offset."""
    u = (boot_us.astype(np.float64) + offset_us) * 1e-6
    return gps_from_unix_utc(u, leap_seconds)


def read_ulog_imu(path: str | Path, topic: str = "auto", instance: int = 0,
                  leap_seconds: float | None = None) -> ImuData:
    """IMU data (body FRD increments, continuous GPS s) from a PX4 ULog: `vehicle_imu` or `sensor_combined`."""
    path = Path(path)
    topics = ["vehicle_imu", "sensor_combined", *GPS_TOPICS]
    ulog = _open(path, topics)
    off = boot_to_unix_offset_us(ulog, path)
    d = None
    if topic in ("auto", "vehicle_imu"):
        d = _topic(ulog, "vehicle_imu", instance)
        sc = _topic(ulog, "sensor_combined", instance)
        if topic == "auto" and d is not None and sc is not None and len(sc.data["timestamp"]) > 2 * len(
                d.data["timestamp"]):
            d = None   # vehicle_imu logged decimated: the full-rate sensor_combined is better
        if d is not None:
            ts = d.data["timestamp_sample"].astype(np.int64)
            dth = np.column_stack([d.data[f"delta_angle[{i}]"] for i in range(3)]).astype(float)
            dv = np.column_stack([d.data[f"delta_velocity[{i}]"] for i in range(3)]).astype(float)
            dt_g = d.data["delta_angle_dt"].astype(float) * 1e-6
            dt_a = d.data["delta_velocity_dt"].astype(float) * 1e-6
            t = _gps_seconds(ts, off, leap_seconds)
            keep = _increasing(t)
            t, dth, dv, dt_g, dt_a = t[keep], dth[keep], dv[keep], dt_g[keep], dt_a[keep]
            # rates over each message's own interval, as increments over the gaps between messages
            dt = np.diff(t, prepend=t[0] - (dt_g[0] if dt_g[0] > 0 else 1.0 / estimate_rate_hz(t)))
            g = dth / np.where(dt_g > 0, dt_g, dt)[:, None]
            a = dv / np.where(dt_a > 0, dt_a, dt)[:, None]
            return _checked(ImuData.from_rates(t, g, a), path, "vehicle_imu")
        if topic == "vehicle_imu":
            raise InputError(f"no vehicle_imu instance {instance} in the log", path, field="vehicle_imu")
    d = _topic(ulog, "sensor_combined", instance)
    if d is None:
        raise InputError("no IMU topic (vehicle_imu or sensor_combined) in the log", path, field="sensor_combined")
    ts = d.data["timestamp"].astype(np.int64)
    g = np.column_stack([d.data[f"gyro_rad[{i}]"] for i in range(3)]).astype(float)
    a = np.column_stack([d.data[f"accelerometer_m_s2[{i}]"] for i in range(3)]).astype(float)
    t = _gps_seconds(ts, off, leap_seconds)
    keep = _increasing(t)
    return _checked(ImuData.from_rates(t[keep], g[keep], a[keep]), path, "sensor_combined")


def _increasing(t: np.ndarray) -> np.ndarray:
    """Mask keeping strictly increasing times (PX4 logs repeat a stamp when a message is re-published)."""
    keep = np.ones(len(t), bool)
    keep[1:] = np.diff(t) > 0
    return keep & (t >= np.maximum.accumulate(t))


def _checked(imu: ImuData, path: Path, topic: str) -> ImuData:
    imu.path = path
    if len(imu) < 2:
        raise InputError("fewer than two IMU samples", path, field=topic)
    bad = ~(np.isfinite(imu.dtheta).all(axis=1) & np.isfinite(imu.dvel).all(axis=1))
    if bad.any():
        raise InputError(f"non-finite IMU sample {int(np.flatnonzero(bad)[0]) + 1}", path, field=topic)
    return imu


def read_ulog_camera_capture(path: str | Path, name_pattern: str = "IMG_{seq:04d}.JPG",
                             leap_seconds: float | None = None) -> Events:
    """Camera events from the `camera_capture` messages of a PX4 ULog (trigger times in GPS s)."""
    path = Path(path)
    ulog = _open(path, ["camera_capture", *GPS_TOPICS])
    d = _topic(ulog, "camera_capture")
    if d is None or len(d.data["timestamp"]) == 0:
        raise InputError("no camera_capture messages in the log", path, field="camera_capture")
    seq = d.data["seq"].astype(np.int64) if "seq" in d.data else np.arange(1, len(d.data["timestamp"]) + 1)
    utc = d.data.get("timestamp_utc")
    if utc is not None and np.all(utc > 0):
        t = gps_from_unix_utc(utc.astype(np.float64) * 1e-6, leap_seconds)
    else:
        t = _gps_seconds(d.data["timestamp"].astype(np.int64), boot_to_unix_offset_us(ulog, path), leap_seconds)
    order = np.argsort(t, kind="stable")
    t, seq = t[order], seq[order]
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise InputError(f"camera_capture {int(seq[k])} has the time of the one before", path, field="timestamp")
    _, first = np.unique(seq, return_index=True)
    if len(first) < len(seq):
        k = int(np.setdiff1d(np.arange(len(seq)), first)[0])
        raise InputError(f"camera_capture seq {int(seq[k])} appears twice", path, field="seq")
    names = np.array([name_pattern.format(seq=int(s)) for s in seq], dtype=object)
    return Events(names, t, None, path)
