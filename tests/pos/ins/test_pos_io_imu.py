"""IMU readers/writers: round trips, units, rates vs increments, and errors naming file and line."""
import numpy as np
import pytest

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.pos.ins.imu_data import (ImuData, read_imu_csv, read_imu_text, read_kf_gins, write_imu_csv,
                        write_kf_gins)


def _imu(n=2000, rate=200.0, week=2150, sow0=302000.0, seed=1):
    rng = np.random.default_rng(seed)
    t = week * SECONDS_PER_WEEK + sow0 + np.arange(1, n + 1) / rate
    g = rng.normal(0, 0.2, (n, 3))
    a = rng.normal(0, 1.0, (n, 3)) + [0, 0, -9.8]
    return ImuData.from_rates(t, g, a, rate)


def test_kf_gins_round_trip(tmp_path):
    imu = _imu()
    p = tmp_path / "imu.txt"
    write_kf_gins(p, imu)
    back = read_kf_gins(p, gps_week=2150)
    np.testing.assert_allclose(back.t, imu.t, atol=1e-6)
    np.testing.assert_allclose(back.dtheta, imu.dtheta, rtol=1e-11, atol=1e-18)
    np.testing.assert_allclose(back.dvel, imu.dvel, rtol=1e-11, atol=1e-18)
    assert back.rate_hz == pytest.approx(200.0)
    np.testing.assert_allclose(back.gyro_rad_s, imu.gyro_rad_s, rtol=1e-6)


def test_csv_round_trip_rates_and_increments(tmp_path):
    imu = _imu(500)
    for kind in ("increments", "rates"):
        p = tmp_path / f"imu_{kind}.csv"
        write_imu_csv(p, imu, kind=kind)
        back = read_imu_csv(p, kind=kind, rate_hz=200.0)
        np.testing.assert_allclose(back.t, imu.t, atol=1e-6)
        np.testing.assert_allclose(back.dtheta, imu.dtheta, rtol=1e-6, atol=1e-15)
        np.testing.assert_allclose(back.accel_m_s2, imu.accel_m_s2, rtol=1e-6)


def test_generic_text_units_columns_and_axes(tmp_path):
    imu = _imu(300)
    sow = imu.t - 2150 * SECONDS_PER_WEEK
    # rates in deg/s and g, columns shuffled, axes right-forward-up (RFU)
    R_frd_to_rfu = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    g_rfu = np.degrees(imu.gyro_rad_s) @ R_frd_to_rfu.T
    a_rfu = imu.accel_m_s2 / 9.80665 @ R_frd_to_rfu.T
    p = tmp_path / "imu.csv"
    with open(p, "w") as fh:
        fh.write("ax,ay,az,time,wx,wy,wz,temp\n")
        for k in range(len(sow)):
            fh.write(",".join(f"{v:.12g}" for v in [*a_rfu[k], sow[k], *g_rfu[k], 25.0]) + "\n")
    back = read_imu_text(p, columns=["time", "wx", "wy", "wz", "ax", "ay", "az"], kind="rates",
                         gyro_unit="deg/s", accel_unit="g", gps_week=2150, rate_hz=200.0,
                         R_sensor_to_body=R_frd_to_rfu.T)
    np.testing.assert_allclose(back.gyro_rad_s, imu.gyro_rad_s, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(back.accel_m_s2, imu.accel_m_s2, rtol=1e-8, atol=1e-10)


def test_week_rollover_inside_file(tmp_path):
    p = tmp_path / "imu.txt"
    sows = [SECONDS_PER_WEEK - 0.01, SECONDS_PER_WEEK - 0.005, 0.0, 0.005]
    p.write_text("".join(f"{s:.3f} 0 0 0 0 0 -0.049\n" for s in sows))
    imu = read_kf_gins(p, gps_week=100)
    np.testing.assert_allclose(np.diff(imu.t), 0.005, atol=1e-6)
    assert imu.t[2] == pytest.approx(101 * SECONDS_PER_WEEK)


@pytest.mark.parametrize("content, line, word", [
    ("1.0 0 0 0 0 0 0\n1.005 0 0 x 0 0 0\n", 2, "not a number"),
    ("# comment\n1.0 0 0 0 0 0 0\n\n1.005 0 0 0 0 0\n", 4, "columns"),
    ("1.0 0 0 0 0 0 0\n1.005 0 0 0 0 0 0\n1.005 0 0 0 0 0 0\n", 3, "does not increase"),
    ("1.0 0 0 0 0 0 0\n1.005 0 0 nan 0 0 0\n", 2, "finite"),
])
def test_bad_lines_are_named(tmp_path, content, line, word):
    p = tmp_path / "bad.txt"
    p.write_text(content)
    with pytest.raises(InputError) as exc:
        read_kf_gins(p)
    assert f"bad.txt:{line}" in str(exc.value) and word in str(exc.value)


def test_missing_header_column_and_file(tmp_path):
    p = tmp_path / "imu.csv"
    p.write_text("time,gx,gy,gz,ax,ay\n1,0,0,0,0,0\n")
    with pytest.raises(InputError, match="'az' not in header"):
        read_imu_text(p, columns=["time", "gx", "gy", "gz", "ax", "ay", "az"])
    with pytest.raises(InputError, match="file not found"):
        read_kf_gins(tmp_path / "nope.txt")


def test_between_gaps_and_from_rates_consistency():
    imu = _imu(1000)
    assert imu.gaps().size == 0
    keep = np.r_[0:300, 305:1000]
    holey = ImuData(imu.t[keep], imu.dtheta[keep], imu.dvel[keep], imu.rate_hz)
    assert list(holey.gaps()) == [300]
    assert holey.dt[300] == pytest.approx(6 / 200.0)
    sub = imu.between(imu.t[100], imu.t[199])
    assert len(sub) == 100 and sub.t[0] == imu.t[100]
    np.testing.assert_allclose(sub.dtheta, imu.dtheta[100:200])
