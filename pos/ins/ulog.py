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

import contextlib
import io
from pathlib import Path

import numpy as np
from pyulog import ULog

from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import Events
from dgcal.fields.io.timescales import gps_from_unix_utc
from dgcal.fields.io.validate import gps_seconds_values, values_in_range
from dgcal.pos.ins.imu_data import MAX_ACCEL_M_S2, MAX_GYRO_RAD_S, ImuData, estimate_rate_hz
from dgcal.pos.ins.ulog_stream import scan_ulog

GPS_TOPICS = ("vehicle_gps_position", "sensor_gps")
MAX_UNIX_US = 4e15          # µs since 1970: the year 2096 (a larger UTC stamp is a damaged one)


ULOG_MAGIC = b"ULog\x01\x12\x35"


def is_ulog(path: str | Path) -> bool:
    """True when the file starts with the ULog magic bytes."""
    try:
        with open(path, "rb") as fh:
            return fh.read(7) == ULOG_MAGIC
    except OSError:
        return False


def _open(path: Path, topics: list[str]):
    """A pyulog ULog of `topics`, after its message stream was checked (`scan_ulog`: a damaged log is refused in one
    pass instead of pyulog's byte-by-byte recovery); any failure of the library is one InputError naming the file.
    pyulog's prints about corruption are kept off dgcal's output."""
    if not path.is_file():
        raise InputError("file not found", path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path) from None
    if data[:7] != ULOG_MAGIC:
        raise InputError(f"not a PX4 ULog file (starts {data[:7]!r})", path, field="header")
    scan_ulog(path, data)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            return ULog(io.BytesIO(data), topics, disable_str_exceptions=True)
    except Exception as exc:  # noqa: BLE001 - pyulog raises many kinds on corrupt files
        msg = str(exc).strip().splitlines()[0][:80] if str(exc).strip() else type(exc).__name__
        raise InputError(f"cannot read the ULog ({msg})", path) from None


def _topic(ulog, name: str, instance: int = 0):
    for d in ulog.data_list:
        if d.name == name and d.multi_id == instance:
            return d
    return None


def _field(d, name: str, path: Path, dtype=float) -> np.ndarray:
    """Field `name` of topic data `d` as an array of `dtype`; InputError naming the topic.field when the log's format
    of the topic lacks it."""
    if name not in d.data:
        raise InputError(f"topic {d.name} has no field {name} (another PX4 version's format, or a damaged log)", path,
                         field=f"{d.name}.{name}")
    return d.data[name].astype(dtype)


def _vec(d, name: str, path: Path) -> np.ndarray:
    """The three components name[0..2] of topic data `d`, (N, 3) float."""
    return np.column_stack([_field(d, f"{name}[{i}]", path) for i in range(3)])


def boot_to_unix_offset_us(ulog, path: Path) -> float:
    """Median `time_utc_usec - timestamp` (µs) of the GPS messages: boot µs + offset = Unix UTC µs."""
    for name in GPS_TOPICS:
        d = _topic(ulog, name)
        if d is None or "time_utc_usec" not in d.data:
            continue
        utc = _field(d, "time_utc_usec", path, np.float64)
        ts = _field(d, "timestamp", path, np.float64)
        ok = (utc > 0) & (utc < MAX_UNIX_US)
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
        if topic == "auto" and d is not None and sc is not None and len(_field(sc, "timestamp", path)) > 2 * len(
                _field(d, "timestamp", path)):
            d = None   # vehicle_imu logged decimated: the full-rate sensor_combined is better
        if d is not None:
            ts = _field(d, "timestamp_sample", path, np.float64)
            dth = _vec(d, "delta_angle", path)
            dv = _vec(d, "delta_velocity", path)
            dt_g = _field(d, "delta_angle_dt", path) * 1e-6
            dt_a = _field(d, "delta_velocity_dt", path) * 1e-6
            t = _gps_seconds(ts, off, leap_seconds)
            keep = _increasing(t)
            t, dth, dv, dt_g, dt_a = t[keep], dth[keep], dv[keep], dt_g[keep], dt_a[keep]
            if len(t) < 2:
                raise InputError("fewer than two IMU samples with increasing times", path, field="vehicle_imu")
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
    ts = _field(d, "timestamp", path, np.float64)
    g = _vec(d, "gyro_rad", path)
    a = _vec(d, "accelerometer_m_s2", path)
    t = _gps_seconds(ts, off, leap_seconds)
    keep = _increasing(t)
    return _checked(ImuData.from_rates(t[keep], g[keep], a[keep]), path, "sensor_combined")


def _increasing(t: np.ndarray) -> np.ndarray:
    """Mask keeping strictly increasing times (PX4 logs repeat a stamp when a message is re-published)."""
    keep = np.ones(len(t), bool)
    keep[1:] = np.diff(t) > 0
    return keep & (t >= np.maximum.accumulate(t))


def _checked(imu: ImuData, path: Path, topic: str) -> ImuData:
    """`imu` with its file, when it has two samples or more, all finite, its rates within any IMU's range and its
    times within GPS weeks 0..5000; else InputError naming the topic."""
    imu.path = path
    if len(imu) < 2:
        raise InputError("fewer than two IMU samples", path, field=topic)
    bad = ~(np.isfinite(imu.dtheta).all(axis=1) & np.isfinite(imu.dvel).all(axis=1))
    if bad.any():
        raise InputError(f"non-finite IMU sample {int(np.flatnonzero(bad)[0]) + 1}", path, field=topic)
    gps_seconds_values(imu.t, path, f"{topic}.timestamp")
    with np.errstate(invalid="ignore", divide="ignore"):
        values_in_range(imu.dtheta / imu.dt[:, None], -MAX_GYRO_RAD_S, MAX_GYRO_RAD_S, path, f"{topic} gyro",
                        unit="rad/s")
        values_in_range(imu.dvel / imu.dt[:, None], -MAX_ACCEL_M_S2, MAX_ACCEL_M_S2, path, f"{topic} accel",
                        unit="m/s^2")
    return imu


def read_ulog_camera_capture(path: str | Path, name_pattern: str = "IMG_{seq:04d}.JPG",
                             leap_seconds: float | None = None) -> Events:
    """Camera events from the `camera_capture` messages of a PX4 ULog (trigger times in GPS s)."""
    path = Path(path)
    ulog = _open(path, ["camera_capture", *GPS_TOPICS])
    d = _topic(ulog, "camera_capture")
    if d is None or len(_field(d, "timestamp", path)) == 0:
        raise InputError("no camera_capture messages in the log", path, field="camera_capture")
    stamps = _field(d, "timestamp", path, np.float64)
    seq = _field(d, "seq", path, np.int64) if "seq" in d.data else np.arange(1, len(stamps) + 1)
    utc = d.data.get("timestamp_utc")
    if utc is not None and np.all(utc > 0):
        t = gps_from_unix_utc(utc.astype(np.float64) * 1e-6, leap_seconds)
    else:
        t = _gps_seconds(stamps, boot_to_unix_offset_us(ulog, path), leap_seconds)
    gps_seconds_values(t, path, "camera_capture.timestamp")
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
