"""Heading that the motion cannot determine is reported as such (issue 27): a static record starts from the prior of
an unknown heading (no course), its error stays within its sigma (the earth rate is all that is left: gyrocompassing
as far as the grade allows), and a warning says the heading was never observed."""
from __future__ import annotations

import numpy as np

from dgcal.fields.constants import OMEGA_EARTH
from dgcal.fields.crs import ecef_to_geodetic
from dgcal.pos.gnss_ins import process
from dgcal.pos.ins.imu_data import ImuData
from dgcal.pos.smoother.initial import GnssFixes

P = np.array([-3962108.673, 3381309.574, 3668678.638])


def _static(heading_deg: float, gyro_bias_deg_h: float = 0.0, seconds: float = 120.0):
    lat, _, _ = ecef_to_geodetic(P)
    rate = 100.0
    t = 1.3e9 + np.arange(1, int(seconds * rate) + 1) / rate
    rng = np.random.default_rng(1)
    h = np.radians(heading_deg)
    w_ned = OMEGA_EARTH * np.array([np.cos(np.radians(lat)), 0.0, -np.sin(np.radians(lat))])
    R_ned_to_body = np.array([[np.cos(h), np.sin(h), 0.0], [-np.sin(h), np.cos(h), 0.0], [0.0, 0.0, 1.0]])
    w_b = R_ned_to_body @ w_ned + np.array([0.0, 0.0, np.radians(gyro_bias_deg_h / 3600.0)])
    dth = w_b / rate + rng.normal(0, np.radians(0.3) / 60 / np.sqrt(rate), (len(t), 3))
    dv = np.array([0.0, 0.0, -9.797]) / rate + rng.normal(0, 0.029 / 60 / np.sqrt(rate), (len(t), 3))
    tf = np.arange(t[0] + 0.5, t[-1], 1.0)
    fixes = GnssFixes(tf, np.tile(P, (len(tf), 1)) + rng.normal(0, 0.01, (len(tf), 3)), np.full((len(tf), 3), 0.02))
    return ImuData(t, dth, dv, rate), fixes


def test_a_static_record_reports_an_unknown_heading():
    imu, fixes = _static(heading_deg=120.0)
    res = process("lc", imu, "consumer", np.zeros(3), lc_fixes=fixes)        # no gyrocompassing from its gyros
    sig_heading = float(np.median(res.trajectory.sigma[:, 5]))
    err = abs((float(np.median(res.trajectory.rph[:, 2])) - 120.0 + 180.0) % 360.0 - 180.0)
    assert sig_heading > 20.0 and err < 3.0 * sig_heading, (err, sig_heading)
    assert any("heading not observable" in w for w in res.summary["warnings"])
