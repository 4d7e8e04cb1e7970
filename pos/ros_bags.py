"""ROS 1 (.bag) and ROS 2 (folder or .db3/.mcap) bags, read with `rosbags`: `sensor_msgs/Imu` as IMU data and
`sensor_msgs/NavSatFix` as GNSS antenna positions, in dgcal's time and frames.

- Frames: ROS's REP 103 body frame is FLU (x forward, y left, z up); dgcal's body is FRD, so y and z change
  sign. `linear_acceleration` is the specific force (+g up at rest in FLU, -g along FRD z).
- Time: `header.stamp` (the sensor's time, Unix UTC by ROS convention) or the bag's receive time
  (`time="bag"`), both made GPS seconds with the leap seconds (dgcal.fields.io.timescales).
- NavSatFix: latitude/longitude deg, altitude m above the WGS 84 ellipsoid, `position_covariance` row-major in
  ENU m^2 (type 0 = unknown: a default from the fix status), `status.status` -1 no fix (dropped), 0 fix,
  1 SBAS, 2 GBAS (RTK drivers such as ublox_gps report an RTK fix this way) -> RTKLIB Q 5, 3, 1.

`write_rosbag` writes IMU data and fixes the other way (a simulated robot log, `dgcal.sim.robot_motion`).
"""
from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from dgcal.fields.crs import ecef_to_geodetic, geodetic_to_ecef
from dgcal.fields.errors import InputError
from dgcal.fields.io.timescales import gps_from_unix_utc, unix_utc_from_gps
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


# RTKLIB Q -> NavSatStatus (fixed and float: GBAS, as RTK drivers report them; SBAS and DGPS: SBAS; else a fix)
Q_TO_STATUS = {1: 2, 2: 2, 3: 1, 4: 1}


def _header(ts, u: float, frame_id: str, version: int):
    sec = int(np.floor(u))
    nsec = min(int(round((u - sec) * 1e9)), 999_999_999)
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
    if version == 1:
        return ts.types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame_id), sec * 10 ** 9 + nsec
    return ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id), sec * 10 ** 9 + nsec


def write_rosbag(path: str | Path, imu: ImuData, fixes: GnssSolution | None = None, version: int = 2,
                 imu_topic: str = "/imu/data", fix_topic: str = "/gps/fix") -> Path:
    """Write `imu` (body FRD increments, GPS s) as `sensor_msgs/Imu` (FLU mean rates over each interval, stamped at
    its end in Unix UTC) and `fixes` (antenna ECEF m, NED covariance m^2) as `sensor_msgs/NavSatFix` (ENU covariance,
    type known) into a ROS 1 bag file or a ROS 2 bag folder (`version`); bag times are the stamps."""
    path = Path(path)
    if version not in (1, 2):
        raise ValueError(f"ROS version {version!r} is not 1 or 2")
    ts = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
    serialize = ts.serialize_ros1 if version == 1 else ts.serialize_cdr
    v3, quat = ts.types["geometry_msgs/msg/Vector3"], ts.types["geometry_msgs/msg/Quaternion"]
    imu_t = ts.types["sensor_msgs/msg/Imu"]
    msgs = []
    u = unix_utc_from_gps(imu.t)
    gyro, accel = imu.gyro_rad_s * FLU_TO_FRD, imu.accel_m_s2 * FLU_TO_FRD
    for uk, g, a in zip(u, gyro.tolist(), accel.tolist()):
        head, ns = _header(ts, float(uk), "imu_link", version)
        msgs.append((ns, 0, imu_t(header=head, orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
                                  orientation_covariance=np.array([-1.0] + [0.0] * 8),
                                  angular_velocity=v3(x=g[0], y=g[1], z=g[2]), angular_velocity_covariance=np.zeros(9),
                                  linear_acceleration=v3(x=a[0], y=a[1], z=a[2]),
                                  linear_acceleration_covariance=np.zeros(9))))
    if fixes is not None and len(fixes):
        fix_t, status_t = ts.types["sensor_msgs/msg/NavSatFix"], ts.types["sensor_msgs/msg/NavSatStatus"]
        llh = ecef_to_geodetic(np.asarray(fixes.p_ecef, float))
        cov_enu = np.einsum("ji,njk,kl->nil", P_ENU_TO_NED, np.asarray(fixes.cov_ned, float), P_ENU_TO_NED)
        for uk, p, c, q in zip(unix_utc_from_gps(fixes.t), llh, cov_enu, np.asarray(fixes.quality, int)):
            head, ns = _header(ts, float(uk), "gps", version)
            msgs.append((ns, 1, fix_t(header=head, status=status_t(status=Q_TO_STATUS.get(int(q), 0), service=1),
                                      latitude=float(p[0]), longitude=float(p[1]), altitude=float(p[2]),
                                      position_covariance=c.ravel().copy(), position_covariance_type=3)))
    msgs.sort(key=lambda m: (m[0], m[1]))
    types = ("sensor_msgs/msg/Imu", "sensor_msgs/msg/NavSatFix")
    writer = Writer1(path) if version == 1 else Writer2(path, version=9)
    with writer as w:
        conns = {}
        for i in sorted({m[1] for m in msgs}):
            conns[i] = w.add_connection((imu_topic, fix_topic)[i], types[i], typestore=ts)
        for ns, i, m in msgs:
            w.write(conns[i], ns, serialize(m, types[i]))
    return path
