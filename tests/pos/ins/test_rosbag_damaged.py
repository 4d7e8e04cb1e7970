"""Damaged ROS bags (issue 31): ROS 1 and ROS 2 bags written by rosbags' own writers, then overwritten, cut or
shortened at 150 seeded places each: every read returns IMU data within any IMU's range or fails with one InputError
naming the bag, within seconds (rosbags' ReaderError, sqlite's 'malformed', UnicodeDecodeError, KeyError and
AssertionError from a damaged chunk or index were internal errors); values beyond any IMU, and fixes
far from the Earth are refused."""
from __future__ import annotations

import time

import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.pos.ros_bags import read_rosbag_imu, read_rosbag_navsatfix

from test_pos_io_rosbags import T0_UNIX, TS, TS1, _fix_msg, _imu_msg, _write


def _imu_bag(tmp_path, version, g=(0.1, 0.0, 0.0), a=(0.0, 0.0, 9.8), n=50, t0=T0_UNIX):
    u = t0 + np.arange(n) / 100
    bag = tmp_path / ("imu.bag" if version == 1 else "imu_bag")
    _write(bag, version, {"/imu": ("sensor_msgs/msg/Imu", [(x, _imu_msg(x, g, a, TS1 if version == 1 else TS))
                                                            for x in u])})
    return bag


@pytest.mark.parametrize("version", [1, 2])
def test_damaged_bags_read_or_refused(tmp_path, version):
    bag = _imu_bag(tmp_path, version)
    src = bag if version == 1 else next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    data = src.read_bytes()
    rng = np.random.default_rng(31 + version)
    counts = {"read": 0, "refused": 0}
    slowest = 0.0
    for _ in range(150):
        b = bytearray(data)
        i = int(rng.integers(0, len(b)))
        op = int(rng.integers(3))
        if op == 0:
            b[i:i + 4] = rng.integers(0, 256, 4, dtype=np.uint8).tobytes()
        elif op == 1:
            b = b[:i]
        else:
            del b[i:i + 3]
        src.write_bytes(bytes(b))
        t0 = time.perf_counter()
        try:
            imu = read_rosbag_imu(bag)
            assert np.all(np.abs(imu.gyro_rad_s) <= 100) and np.all(np.abs(imu.accel_m_s2) <= 2000)
            counts["read"] += 1
        except InputError as exc:
            assert bag.name in str(exc) and "\n" not in str(exc), str(exc)
            counts["refused"] += 1
        slowest = max(slowest, time.perf_counter() - t0)
    assert counts["refused"] >= 50 and slowest < 5.0, (counts, slowest)


@pytest.mark.parametrize("g, a, match", [((1e20, 0, 0), (0, 0, 9.8), "angular_velocity"),
                                         ((0.1, 0, 0), (0, float("inf"), 9.8), "non-finite"),
                                         ((0.1, 0, 0), (0, 0, 3e3), "linear_acceleration")])
def test_values_beyond_any_imu_refused(tmp_path, g, a, match):
    with pytest.raises(InputError, match=match):
        read_rosbag_imu(_imu_bag(tmp_path, 2, g, a))


def test_fix_far_from_the_earth_refused(tmp_path):
    u = T0_UNIX + np.arange(5.0)
    bag = tmp_path / "fix_bag"
    _write(bag, 2, {"/fix": ("sensor_msgs/msg/NavSatFix",
                             [(x, _fix_msg(x, (40.0, -105.0, 1e7), np.eye(3).ravel(), 0)) for x in u])})
    with pytest.raises(InputError, match="not near its surface"):
        read_rosbag_navsatfix(bag)
