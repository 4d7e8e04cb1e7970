"""ROS 1 (.bag) and ROS 2 (folder or .db3/.mcap) bags, read with `rosbags`: `sensor_msgs/Imu` as IMU data and
`sensor_msgs/NavSatFix` as GNSS antenna positions, in dgcal's time and frames.

- Frames: ROS's REP 103 body frame is FLU (x forward, y left, z up); dgcal's body is FRD, so y and z change
  sign. `linear_acceleration` is the specific force (+g up at rest in FLU, -g along FRD z).
- Time: `header.stamp` (the sensor's time, Unix UTC by ROS convention) or the bag's receive time
  (`time="bag"`), both made GPS seconds with the leap seconds (dgcal.fields.io.timescales).
- NavSatFix: latitude/longitude deg, altitude m above the WGS 84 ellipsoid, `position_covariance` row-major in
  ENU m^2 (type 0 = unknown: a default from the fix status), `status.status` -1 no fix (dropped), 0 fix,
  1 SBAS, 2 GBAS (RTK drivers such as ublox_gps report an RTK fix this way) -> RTKLIB Q 5, 3, 1.
"""
from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from dgcal.fields.crs import geodetic_to_ecef
from dgcal.fields.errors import InputError
from dgcal.fields.io.timescales import gps_from_unix_utc
from dgcal.fields.io.validate import ecef_near_surface, gps_seconds_values, values_in_range
from dgcal.pos.gnss.solution_files import GnssSolution
from dgcal.pos.ins.imu_data import MAX_ACCEL_M_S2, MAX_GYRO_RAD_S, ImuData

IMU_TYPES = ("sensor_msgs/msg/Imu", "sensor_msgs/Imu")
FIX_TYPES = ("sensor_msgs/msg/NavSatFix", "sensor_msgs/NavSatFix")
FLU_TO_FRD = np.array([1.0, -1.0, -1.0])
STATUS_TO_Q = {0: 5, 1: 3, 2: 1}
# sigmas (horizontal, vertical m) for a fix without covariance (position_covariance_type 0), per RTKLIB Q
DEFAULT_SIGMA = {5: (2.5, 5.0), 3: (1.0, 2.0), 1: (0.02, 0.04)}
# ENU -> NED axis permutation (N = E-row 1, E = row 0, D = -U)
MAX_COVARIANCE_M2 = 1e8     # a (10 km)^2 variance: a larger one is no information (taken as not given)
P_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def is_ros_bag(path: str | Path) -> bool:
    """True for a ROS 1 bag (its '#ROSBAG V2.0' magic) or a ROS 2 bag (a folder with metadata.yaml, .db3, .mcap)."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    if path.suffix in (".db3", ".mcap"):
        return True
    try:
        with open(path, "rb") as fh:
            return fh.read(13) == b"#ROSBAG V2.0\n"
    except OSError:
        return False


def _bag_path(path: Path) -> Path:
    """The path rosbags opens: a ROS 2 storage file stands for its folder."""
    if path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
        return path.parent
    return path


def _bag_error(path: Path, exc: BaseException, doing: str) -> InputError:
    """One InputError naming the bag for what rosbags (or sqlite, the YAML or the decoder) raised on a damaged bag."""
    msg = " ".join(str(exc).split())[:100] or type(exc).__name__
    return InputError(f"cannot {doing} ({msg}): a damaged or incomplete bag", path)


def _messages(path: Path, types: tuple[str, ...], topic: str | None, what: str):
    """(bag time ns, message) of the one topic of `types` (or `topic`) in the bag; InputError when ambiguous, and
    for any failure of rosbags on a damaged bag (its own errors, sqlite's, decoding, assertions)."""
    if not path.exists():
        raise InputError("file not found", path)
    try:
        reader = AnyReader([_bag_path(path)], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises its own and OS errors on corrupt bags
        raise _bag_error(path, exc, "read the ROS bag") from None
    try:
        conns = [c for c in reader.connections if c.msgtype in types and (topic is None or c.topic == topic)]
        topics = sorted({c.topic for c in conns})
        if not topics:
            have = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})) or "none"
            want = f"topic {topic!r} of type {types[0]}" if topic else f"no {types[0]} topic"
            raise InputError(f"{want} in the bag (topics: {have})", path, field=topic or what)
        if len(topics) > 1:
            raise InputError(f"several {types[0]} topics ({', '.join(topics)}): choose one with the topic option",
                             path, field=what)
        out = []
        for conn, t_ns, raw in reader.messages(connections=conns):
            try:
                out.append((t_ns, reader.deserialize(raw, conn.msgtype)))
            except Exception as exc:  # noqa: BLE001 - a truncated message in a damaged bag
                raise InputError(f"message {len(out) + 1} of {topics[0]} cannot be decoded "
                                 f"({' '.join(str(exc).split())[:80] or type(exc).__name__})", path,
                                 field=topics[0]) from None
        return topics[0], out
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - the chunks, index or database of a damaged bag
        raise _bag_error(path, exc, "read the ROS bag's messages") from None
    finally:
        with contextlib.suppress(Exception):
            reader.close()


def _times(bag_ns: np.ndarray, stamp_s: np.ndarray, time: str, leap_seconds: float | None, path: Path,
           topic: str) -> np.ndarray:
    """GPS seconds of the messages from their header stamps (`time="header"`) or the bag's receive times."""
    if time not in ("header", "bag"):
        raise InputError(f"time source {time!r} is not 'header' or 'bag'", path, field="time")
    u = stamp_s if time == "header" else bag_ns * 1e-9
    if time == "header" and np.any(u <= 0):
        raise InputError("header stamps are zero: the driver did not stamp the messages (use the bag time)", path,
                         field=f"{topic}.header.stamp")
    t = gps_from_unix_utc(u, leap_seconds)
    return gps_seconds_values(t, path, f"{topic}.header.stamp" if time == "header" else f"{topic} bag time")


def read_rosbag_imu(path: str | Path, topic: str | None = None, time: str = "header",
                    leap_seconds: float | None = None) -> ImuData:
    """IMU data (body FRD increments, GPS s) from the `sensor_msgs/Imu` messages of a ROS 1 or ROS 2 bag."""
    path = Path(path)
    name, msgs = _messages(path, IMU_TYPES, topic, "imu topic")
    n = len(msgs)
    if n < 2:
        raise InputError(f"fewer than two messages on {name}", path, field=name)
    bag_ns = np.fromiter((m[0] for m in msgs), np.int64, n)
    stamp = np.fromiter((m[1].header.stamp.sec + 1e-9 * m[1].header.stamp.nanosec for m in msgs), float, n)
    g = np.array([(m[1].angular_velocity.x, m[1].angular_velocity.y, m[1].angular_velocity.z) for m in msgs])
    a = np.array([(m[1].linear_acceleration.x, m[1].linear_acceleration.y, m[1].linear_acceleration.z)
                  for m in msgs])
    t = _times(bag_ns, stamp, time, leap_seconds, path, name)
    order = np.argsort(t, kind="stable")
    t, g, a = t[order], g[order] * FLU_TO_FRD, a[order] * FLU_TO_FRD
    keep = np.ones(n, bool)
    keep[1:] = np.diff(t) > 0      # a driver re-publishing a stamp
    bad = ~(np.isfinite(g).all(axis=1) & np.isfinite(a).all(axis=1))
    if bad.any():
        raise InputError(f"non-finite IMU message {int(np.flatnonzero(bad)[0]) + 1}", path, field=name)
    values_in_range(g, -MAX_GYRO_RAD_S, MAX_GYRO_RAD_S, path, f"{name}.angular_velocity", unit="rad/s")
    values_in_range(a, -MAX_ACCEL_M_S2, MAX_ACCEL_M_S2, path, f"{name}.linear_acceleration", unit="m/s^2")
    if keep.sum() < 2:
        raise InputError(f"fewer than two messages with increasing times on {name}", path, field=name)
    imu = ImuData.from_rates(t[keep], g[keep], a[keep])
    imu.path = path
    return imu


def read_rosbag_navsatfix(path: str | Path, topic: str | None = None, time: str = "header",
                          leap_seconds: float | None = None) -> GnssSolution:
    """Antenna positions (ECEF m, NED covariances m^2, GPS s) from the `sensor_msgs/NavSatFix` messages of a bag."""
    path = Path(path)
    name, msgs = _messages(path, FIX_TYPES, topic, "fix topic")
    status = np.array([int(m[1].status.status) for m in msgs], int)
    ok = np.isin(status, list(STATUS_TO_Q))
    llh = np.array([(m[1].latitude, m[1].longitude, m[1].altitude) for m in msgs], float).reshape(-1, 3)
    ok &= np.isfinite(llh).all(axis=1)
    if ok.sum() < 2:
        raise InputError(f"fewer than two messages with a fix on {name}", path, field=f"{name}.status")
    if np.any(np.abs(llh[ok, 0]) > 90) or np.any(np.abs(llh[ok, 1]) > 180):
        raise InputError("latitude or longitude out of range", path, field=f"{name}.latitude")
    idx = np.flatnonzero(ok)
    bag_ns = np.array([msgs[i][0] for i in idx], np.int64)
    stamp = np.array([msgs[i][1].header.stamp.sec + 1e-9 * msgs[i][1].header.stamp.nanosec for i in idx])
    cov_enu = np.array([np.asarray(msgs[i][1].position_covariance, float).reshape(3, 3) for i in idx])
    cov_type = np.array([int(msgs[i][1].position_covariance_type) for i in idx])
    q = np.array([STATUS_TO_Q[s] for s in status[idx]], int)
    t = _times(bag_ns, stamp, time, leap_seconds, path, name)
    cov_ned = np.einsum("ij,njk,lk->nil", P_ENU_TO_NED, cov_enu, P_ENU_TO_NED)
    with np.errstate(invalid="ignore"):
        unknown = ((cov_type == 0) | ~np.isfinite(cov_ned).all(axis=(1, 2)) | (np.einsum("nii->n", cov_ned) <= 0)
                   | (np.abs(cov_ned) > MAX_COVARIANCE_M2).any(axis=(1, 2)))
    for k in np.flatnonzero(unknown):
        sh, sv = DEFAULT_SIGMA[int(q[k])]
        cov_ned[k] = np.diag([sh ** 2, sh ** 2, sv ** 2])
    order = np.argsort(t, kind="stable")
    keep = np.ones(len(t), bool)
    keep[1:] = np.diff(t[order]) > 0
    order = order[keep]
    p = ecef_near_surface(geodetic_to_ecef(llh[idx, 0], llh[idx, 1], llh[idx, 2]), path, field=f"{name}.altitude")
    return GnssSolution(t[order], p[order], cov_ned[order], q[order], np.zeros(len(order), int), path=path,
                        info={"format": "rosbag", "topic": name, "time": time,
                              "covariance": "default" if unknown.all() else "from the messages"})
