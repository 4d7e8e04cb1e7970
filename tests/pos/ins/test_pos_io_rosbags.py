"""ROS 1 and ROS 2 bags (written by rosbags' own writers) read as IMU data and GNSS fixes: frames, times, covariance."""
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from dgcal.fields.crs import ecef_to_geodetic
from dgcal.fields.errors import InputError
from dgcal.fields.io.timescales import gps_from_unix_utc
from dgcal.pos.readers import ImuInput, read_imu_input
from dgcal.pos.ros_bags import is_ros_bag, read_rosbag_imu, read_rosbag_navsatfix

TS = get_typestore(Stores.ROS2_HUMBLE)
TS1 = get_typestore(Stores.ROS1_NOETIC)
T0_UNIX = 1_700_000_000.0            # 2023-11-14, GPS - UTC = 18 s


def _stamp(u: float, ts=TS):
    sec = int(np.floor(u))
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((u - sec) * 1e9)))
    if ts is TS1:
        return ts.types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="imu_link")
    return ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id="imu_link")


def _imu_msg(u, g_flu, a_flu, ts=TS):
    v3 = ts.types["geometry_msgs/msg/Vector3"]
    return ts.types["sensor_msgs/msg/Imu"](
        header=_stamp(u, ts), orientation=ts.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.full(9, -1.0), angular_velocity=v3(x=g_flu[0], y=g_flu[1], z=g_flu[2]),
        angular_velocity_covariance=np.zeros(9), linear_acceleration=v3(x=a_flu[0], y=a_flu[1], z=a_flu[2]),
        linear_acceleration_covariance=np.zeros(9))


def _fix_msg(u, llh, cov_enu, status, cov_type=3):
    return TS.types["sensor_msgs/msg/NavSatFix"](
        header=_stamp(u), status=TS.types["sensor_msgs/msg/NavSatStatus"](status=status, service=1),
        latitude=llh[0], longitude=llh[1], altitude=llh[2], position_covariance=np.asarray(cov_enu, float).ravel(),
        position_covariance_type=cov_type)


def _write(path, version, topics):
    """A bag at `path` (ROS 1 file or ROS 2 folder) with {topic: (msgtype, [(unix s, msg)])}."""
    if version == 1:
        with Writer1(path) as w:
            for topic, (mtype, msgs) in topics.items():
                c = w.add_connection(topic, mtype, typestore=TS1)
                for u, m in msgs:
                    w.write(c, int(u * 1e9), TS1.serialize_ros1(m, mtype))
    else:
        with Writer2(path, version=9) as w:
            for topic, (mtype, msgs) in topics.items():
                c = w.add_connection(topic, mtype, typestore=TS)
                for u, m in msgs:
                    w.write(c, int(u * 1e9), TS.serialize_cdr(m, mtype))


@pytest.fixture(scope="module")
def motion():
    rng = np.random.default_rng(1)
    n = 400
    u = T0_UNIX + np.arange(n) / 100.0
    g = rng.normal(0, 0.2, (n, 3))
    a = rng.normal(0, 0.5, (n, 3)) + [0.0, 0.0, 9.81]   # at rest a ROS IMU reads +g along its z (up)
    return u, g, a


@pytest.mark.parametrize("version", [1, 2])
def test_imu_bag_in_body_frd_and_gps_time(tmp_path, motion, version):
    u, g, a = motion
    bag = tmp_path / ("imu.bag" if version == 1 else "imu_bag")
    ts = TS1 if version == 1 else TS
    _write(bag, version, {"/imu/data": ("sensor_msgs/msg/Imu", [(x + 0.004, _imu_msg(x, gi, ai, ts))
                                                                for x, gi, ai in zip(u, g, a)])})
    assert is_ros_bag(bag)
    imu = read_rosbag_imu(bag)
    assert np.allclose(imu.t, gps_from_unix_utc(u), atol=2e-9 * np.abs(imu.t).max())
    assert abs((imu.t[0] - (u[0] - 315964800.0)) - 18.0) < 1e-5          # leap seconds of 2023
    assert np.allclose(imu.gyro_rad_s[1:], g[1:] * [1, -1, -1], atol=1e-9)
    assert np.allclose(imu.accel_m_s2[1:], a[1:] * [1, -1, -1], atol=1e-9)
    assert np.mean(imu.accel_m_s2[:, 2]) < -9.0                         # FRD: gravity's reaction along -z
    # the CLI's loader recognises the bag by its content
    assert np.allclose(read_imu_input(ImuInput(bag)).dtheta, imu.dtheta)
    # bag receive time instead of the header stamp
    assert np.allclose(read_rosbag_imu(bag, time="bag").t - imu.t, 0.004, atol=1e-5)


def test_navsatfix_bag_positions_covariances_and_status(tmp_path):
    rng = np.random.default_rng(2)
    n = 30
    u = T0_UNIX + np.arange(n)
    llh = np.column_stack([30.5 + 1e-6 * np.arange(n), 114.3 + 2e-6 * np.arange(n), 40.0 + 0.1 * rng.normal(size=n)])
    cov_enu = np.diag([0.01 ** 2, 0.02 ** 2, 0.05 ** 2])
    cov_enu[0, 1] = cov_enu[1, 0] = 0.5 * 0.01 * 0.02
    status = np.array([2] * 20 + [0] * 5 + [-1] * 5)
    msgs = [(x, _fix_msg(x, p, cov_enu, int(s), cov_type=3 if k < 20 else 0))
            for k, (x, p, s) in enumerate(zip(u, llh, status))]
    bag = tmp_path / "fix_bag"
    _write(bag, 2, {"/fix": ("sensor_msgs/msg/NavSatFix", msgs), "/imu": (
        "sensor_msgs/msg/Imu", [(x, _imu_msg(x, [0, 0, 0], [0, 0, 9.81])) for x in u])})
    sol = read_rosbag_navsatfix(bag)
    assert len(sol) == 25                                             # no-fix messages dropped
    back = ecef_to_geodetic(sol.p_ecef)
    assert np.allclose(back[:, :2], llh[:25, :2], atol=1e-10) and np.allclose(back[:, 2], llh[:25, 2], atol=1e-6)
    assert np.array_equal(sol.quality, [1] * 20 + [5] * 5)            # GBAS (RTK) fixed, plain fix single
    assert np.allclose(sol.sigma_ned[0], [0.02, 0.01, 0.05])          # ENU -> NED
    assert np.isclose(sol.cov_ned[0, 0, 1], 0.5 * 0.01 * 0.02)
    assert np.all(sol.sigma_ned[20:, 2] > 1.0)                        # covariance type unknown: the default


def test_bad_bags_are_one_line_errors(tmp_path, motion):
    u, g, a = motion
    bag = tmp_path / "two_imus_bag"
    m = [(x, _imu_msg(x, gi, ai)) for x, gi, ai in zip(u[:5], g, a)]
    _write(bag, 2, {"/imu/a": ("sensor_msgs/msg/Imu", m), "/imu/b": ("sensor_msgs/msg/Imu", m)})
    with pytest.raises(InputError, match="several sensor_msgs/msg/Imu topics"):
        read_rosbag_imu(bag)
    assert len(read_rosbag_imu(bag, topic="/imu/b")) == 5
    with pytest.raises(InputError, match="no sensor_msgs/msg/NavSatFix topic"):
        read_rosbag_navsatfix(bag)
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    with pytest.raises(InputError) as e:
        read_rosbag_imu(junk)
    assert "junk.bag" in str(e.value) and len(str(e.value).splitlines()) == 1
