"""IMU descriptions, GNSS solution files and event files of other software: values, frames and round trips."""
from __future__ import annotations

import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.io.timescales import gps_from_unix_utc, unix_from_calendar, unix_utc_from_gps
from dgcal.pos.events import read_any_events, read_mrk
from dgcal.pos.gnss.solution_files import read_nmea_gga, read_rtklib_pos, sqvar_to_cov, write_rtklib_pos
from dgcal.pos.ins.imu_formats import (R_sensor_to_body_from_axes, R_sensor_to_body_from_euler_zyx,
                                       axes_from_R_sensor_to_body, euler_zyx_from_R_sensor_to_body, imu_format,
                                       read_imu)

from test_formats_fuzz import MRK, NMEA, POS


@pytest.mark.parametrize("eul", [(10.0, -20.0, 30.0), (180.0, -6.79, 185.35 - 360.0), (-45.0, 80.0, -170.0)])
def test_sensor_to_body_euler_round_trip(eul):
    R = R_sensor_to_body_from_euler_zyx(*eul)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(R_sensor_to_body_from_euler_zyx(*euler_zyx_from_R_sensor_to_body(R)), R, atol=1e-12)


def test_sensor_axes_letters():
    R = R_sensor_to_body_from_axes("FLU")              # ROS REP-103 body -> FRD
    assert np.allclose(R, np.diag([1, -1, -1]))
    assert axes_from_R_sensor_to_body(R_sensor_to_body_from_axes("RFU")) == "RFU"
    with pytest.raises(ValueError):
        R_sensor_to_body_from_axes("FRU")             # left-handed


def test_imu_description_units_time_and_signs(tmp_path):
    """Rates in deg/s and g with Unix UTC stamps in microseconds, FLU sensor axes, a flipped gyro z."""
    t_u = 1752003258.0 + 0.01 * np.arange(1, 51)
    rows = "\n".join(f"{int(round(u * 1e6))};0.5;1.0;-2.0;0.01;0.02;1.0" for u in t_u)
    p = tmp_path / "imu.txt"
    p.write_text("# my logger\nstamp_us;wx;wy;wz;fx;fy;fz\n" + rows + "\n")
    f = imu_format({"delimiter": ";", "kind": "rates",
                    "columns": {"time": "stamp_us", "gx": "wx", "gy": "wy", "gz": "wz", "ax": "fx", "ay": "fy",
                                "az": "fz"},
                    "units": {"gyro": "deg/s", "accel": "g"}, "time": {"kind": "unix_utc", "scale": 1e-6},
                    "axes": {"sensor_axes": "FLU", "gyro_sign": [1, 1, -1]}})
    imu = read_imu(p, f)
    assert np.max(np.abs(imu.t - gps_from_unix_utc(t_u))) < 1e-6
    assert abs(imu.t[0] - (t_u[0] - 315964800 + 18)) < 1e-6
    assert np.allclose(np.degrees(imu.gyro_rad_s[1]), [0.5, -1.0, -2.0])   # FLU->FRD flips y, z; sign flips z
    assert np.allclose(imu.accel_m_s2[1], np.array([0.01, -0.02, -1.0]) * 9.80665)
    bad = tmp_path / "bad.txt"
    bad.write_text("stamp_us;wx;wy;wz;fx;fy;fz\n" + rows.replace(";0.02;", ";x;", 1) + "\n")
    with pytest.raises(InputError) as e:
        read_imu(bad, f)
    assert "bad.txt:2" in str(e.value) and "column 6" in str(e.value)


def test_utc_round_trip_and_leap_seconds():
    u = unix_from_calendar("2016-12-31 23:59:59.5")
    assert gps_from_unix_utc(u) - (u - 315964800) == 17
    assert gps_from_unix_utc(u + 1.0) - (u + 1.0 - 315964800) == 18
    for v in (u, u + 1.0, 1.7e9):
        assert abs(unix_utc_from_gps(gps_from_unix_utc(v)) - v) < 1e-6


def test_rtklib_pos_covariance_and_round_trip(tmp_path):
    p = tmp_path / "rover.pos"
    p.write_text(POS)
    s = read_rtklib_pos(p)
    assert list(s.quality) == [1, 1, 2]
    C = s.cov_ned[1]
    # sdne = +0.0010 -> cov(N,E) = +1e-6; sdeu = -0.0020 -> cov(E,U) = -4e-6 -> cov(E,D) = +4e-6; sdun -> cov(N,D) < 0
    assert np.isclose(C[0, 1], 1e-6) and np.isclose(C[1, 2], 4e-6) and np.isclose(C[0, 2], -0.0005 ** 2)
    assert np.isclose(sqvar_to_cov(-0.002), -4e-6)
    write_rtklib_pos(tmp_path / "back.pos", s)
    b = read_rtklib_pos(tmp_path / "back.pos")
    assert np.max(np.abs(b.p_ecef - s.p_ecef)) < 1e-4 and np.max(np.abs(b.cov_ned - s.cov_ned)) < 2e-7
    bad = tmp_path / "bad.pos"
    bad.write_text(POS.replace("1601.4760   1  21", "1601.4760   1  x1", 1))
    with pytest.raises(InputError) as e:
        read_rtklib_pos(bad)
    assert "bad.pos:5" in str(e.value) and "'ns'" in str(e.value)


def test_nmea_gga_heights_and_quality(tmp_path):
    p = tmp_path / "log.nmea"
    p.write_text(NMEA)
    s = read_nmea_gga(p)
    from dgcal.fields.crs import ecef_to_geodetic
    geo = ecef_to_geodetic(s.p_ecef)
    assert np.allclose(geo[:, 2], [1621.1 - 19.6, 1621.2 - 19.6], atol=1e-6)    # altitude + separation
    assert list(s.quality) == [1, 2]                                              # RTK fixed, float
    assert abs(geo[0, 0] - (40 + 5.79761 / 60)) < 1e-9 and abs(geo[0, 1] + (105 + 8.84690 / 60)) < 1e-9
    assert abs(s.t[0] - gps_from_unix_utc(unix_from_calendar("2025-07-08 19:34:18.40"))) < 1e-6


def test_dji_mrk_real_layout(tmp_path):
    p = tmp_path / "DJI_202507081934_001_Timestamp.MRK"
    p.write_text(MRK)
    m = read_mrk(p)
    assert np.allclose(m.offset_nev_m[1], [-0.007, 0.013, 0.212]) and list(m.quality) == [50, 50]
    assert abs(m.t[0] - (2404 * 604800 + 282401.669089)) < 1e-6
    ev = read_any_events(p)
    assert list(ev.image) == ["DJI_0001.JPG", "DJI_0002.JPG"]
