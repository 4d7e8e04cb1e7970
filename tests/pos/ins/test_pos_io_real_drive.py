"""Acceptance: the real rtklibexplorer car drive (../shared/data/gnss-imu-drive) processed from its own files
through the CLI only: IMU CSV + RTKLIB time-tag file through a format description, the RTKLIB .pos as LC input
with its covariance, the -0.125 s logging delay as --imu-time-offset, fixes withheld in 15 s outages."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from dgcal.cli import main
from dgcal.fields.io.formats import read_trajectory
from dgcal.pos.ins.imu_formats import R_sensor_to_body_from_euler_zyx, imu_format, read_imu
from dgcal.pos.ins.sbet import read_any_trajectory
from dgcal.pos.ins.time_tags import read_time_tag

DOCS = Path(__file__).resolve().parents[3] / "docs" / "examples"


def _drive(shared_data: Path) -> Path:
    return shared_data / "gnss-imu-drive"


def _pos_cli(d: Path, out: Path, *extra: str) -> dict:
    argv = ["pos", "--mode", "lc", "--imu", str(d / "imu_1934.csv"), "--imu-format",
            str(DOCS / "gnss_imu_drive_imu.toml"), "--imu-time-offset", "-0.125", "--gnss", str(d / "gnss_1934_sf.pos"),
            "--lever-arm", "0", "-0.05", "0", "--imu-grade", str(DOCS / "gnss_imu_drive_grade.toml"),
            "--gnss-outages", "40", "15", "45", "--out", str(out), "--no-progress", *extra]
    assert main(argv) == 0
    return json.loads((out / "pos_summary.json").read_text())


def test_time_tag_header_and_records(shared_data):
    tag = read_time_tag(_drive(shared_data) / "imu_1934.csv.tag")
    assert tag.version == "demo5"
    # 2025-07-08 19:34:21.854 GPST = week 2374, sow 243261.854
    assert abs(tag.t0_gps - (2374 * 604800 + 243261.854)) < 1e-5
    assert len(tag.tick_ms) == 37632 and tag.tick_ms[-1] == 548731
    assert np.all(np.diff(tag.fpos) >= 0)


def test_imu_description_reproduces_gnss_imu_reading(shared_data):
    """The description gives the samples GNSS_IMU's convert_imu_file.py + GNSS_IMU.py compute: time from the
    counter mapped onto [tag start, last tick] + imu_t_off, f_b = C(imu_misalign) f_s with Groves' Euler_to_CTM."""
    d = _drive(shared_data)
    imu = read_imu(d / "imu_1934.csv", imu_format(DOCS / "gnss_imu_drive_imu.toml", time_offset_s=-0.125))
    raw = np.genfromtxt(d / "imu_1934.csv", delimiter=",", skip_header=1, skip_footer=1)
    tag = read_time_tag(d / "imu_1934.csv.tag")
    sec = raw[:, 6] / 1000.0
    sec -= sec[0]
    ts = tag.t0_gps + sec * (tag.tick_ms[-1] / 1000.0) / (sec[-1] - sec[0]) - 0.125
    assert len(imu) == len(raw) == 54858
    assert np.max(np.abs(imu.t - ts)) < 1e-6
    e = np.radians([180.0, -6.79, 185.35])            # drive_config.py: [180, 0, 180] + [0, -6.79, 5.35]
    sp, cp, st, ct, ss, cs = np.sin(e[0]), np.cos(e[0]), np.sin(e[1]), np.cos(e[1]), np.sin(e[2]), np.cos(e[2])
    C = np.array([[ct * cs, ct * ss, -st], [-cp * ss + sp * st * cs, cp * cs + sp * st * ss, sp * ct],
                  [sp * ss + cp * st * cs, -sp * cs + cp * st * ss, cp * ct]])    # imu_transforms.Euler_to_CTM
    assert np.allclose(R_sensor_to_body_from_euler_zyx(*np.degrees(e)), C, atol=1e-12)
    f_b = raw[:, 0:3] * 9.80665 @ C.T
    w_b = np.radians(raw[:, 3:6]) @ C.T
    assert np.allclose(imu.accel_m_s2, f_b, atol=1e-9)
    assert np.allclose(imu.gyro_rad_s, w_b, atol=1e-12)
    # at rest at the start the specific force points up: body z (down) reads about -g
    assert -10.2 < imu.accel_m_s2[:200, 2].mean() < -9.4


def test_drive_lc_cli_window(shared_data, tmp_path):
    """A 140 s window of the drive, fixes withheld 15 s of every 45 s: the smoothed antenna track inside the
    outages stays within decimetres of the withheld RTK fixes; SBET written beside the trajectory reads back."""
    s = _pos_cli(_drive(shared_data), tmp_path / "lc", "--t-start", "1436038560", "--t-end", "1436038700",
                 "--sbet-out", "sbet_drive.out")
    w = s["withheld_fixes"]
    assert w["n"] >= 100
    assert w["rms_3d_m"] < 0.35, w             # measured 0.19 m
    assert s["residuals"]["pos"]["rms"] < 0.05  # at the fixes: centimetres
    tr = read_trajectory(tmp_path / "lc" / "trajectory.csv")
    sb = read_any_trajectory(tmp_path / "lc" / "sbet_drive.out", near_t=float(tr.t[0]))
    assert np.max(np.abs(sb.t - tr.t)) < 2e-6
    assert np.max(np.abs(sb.lat - tr.lat)) < 1e-9 and np.max(np.abs(sb.h - tr.h)) < 1e-4
    d = np.abs(((sb.rph - tr.rph) + 180.0) % 360.0 - 180.0)
    assert d.max() < 1e-5
    assert sb.sigma is not None


@pytest.mark.slow
def test_drive_lc_cli_full(shared_data, tmp_path):
    """The whole 549 s drive: 3D RMS inside the outages (GNSS_IMU's forward EKF with ZUPTs: about 0.31 m)."""
    s = _pos_cli(_drive(shared_data), tmp_path / "lc")
    w = s["withheld_fixes"]
    assert w["n"] > 600
    assert w["rms_3d_m"] < 0.3, w               # measured 0.214 m
    shutil.rmtree(tmp_path / "lc")
