"""The heading sigma of a record whose motion never determined the heading (issue 27,
dgcal.pos.smoother.heading_budget): a static MEMS record's heading is as good as unknown and its sigma says so
(104 deg, error/sigma <= 1.4 over headings and seeds); a navigation-grade one gyrocompasses to hundredths of a
degree with a sigma that holds; a gyro bias beyond the grade's range is flagged."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from dgcal.fields.constants import OMEGA_EARTH
from dgcal.fields.crs import ecef_to_geodetic
from dgcal.pos.gnss_ins import process
from dgcal.pos.ins.error_model import imu_grade
from dgcal.pos.ins.imu_data import ImuData
from dgcal.pos.smoother.heading_budget import (HEADING_UNKNOWN_SIGMA_DEG, gyrocompass_sigma, heading_from_motion,
                                               heading_rows)
from dgcal.pos.smoother.initial import GnssFixes

P = np.array([-3962108.673, 3381309.574, 3668678.638])     # 35.3 deg N


def _static(grade: str, heading_deg: float, seed: int, seconds: float = 120.0, extra_gyro_bias_deg_h=(0, 0, 0),
            velocities: bool = False):
    """A static record whose IMU carries the grade's white noise, a turn-on bias and an in-run (Gauss-Markov) bias
    drawn from it (plus `extra_gyro_bias_deg_h`), with 1 Hz fixes of 1 cm noise (and zero velocities)."""
    g = imu_grade(grade)
    lat = ecef_to_geodetic(P)[0]
    rng = np.random.default_rng(seed)
    rate = 100.0
    t = 1.3e9 + np.arange(1, int(seconds * rate) + 1) / rate
    h = np.radians(heading_deg)
    w_ned = OMEGA_EARTH * np.array([np.cos(np.radians(lat)), 0.0, -np.sin(np.radians(lat))])
    R_ned_to_body = np.array([[np.cos(h), np.sin(h), 0.0], [-np.sin(h), np.cos(h), 0.0], [0.0, 0.0, 1.0]])
    def gauss_markov(sigma: float, tau_s: float) -> np.ndarray:
        phi = np.exp(-1.0 / (rate * tau_s))
        w = rng.normal(0.0, sigma * np.sqrt(1.0 - phi ** 2), (len(t), 3))
        w[0] = rng.normal(0.0, sigma, 3)
        return lfilter([1.0], [1.0, -phi], w, axis=0)
    b_g = (rng.normal(0, g.gyro_bias_sigma, 3) + np.radians(np.asarray(extra_gyro_bias_deg_h, float) / 3600.0)
           + gauss_markov(g.gyro_bias_instability, g.gyro_bias_tau_s))
    b_a = rng.normal(0, g.accel_bias_sigma, 3) + gauss_markov(g.accel_bias_instability, g.accel_bias_tau_s)
    dth = (R_ned_to_body @ w_ned + b_g) / rate + rng.normal(0, g.gyro_arw / np.sqrt(rate), (len(t), 3))
    dv = (np.array([0.0, 0.0, -9.797]) + b_a) / rate + rng.normal(0, g.accel_vrw / np.sqrt(rate), (len(t), 3))
    tf = np.arange(t[0] + 0.5, t[-1], 1.0)
    n = len(tf)
    fixes = GnssFixes(tf, np.tile(P, (n, 1)) + rng.normal(0, 0.01, (n, 3)), np.full((n, 3), 0.02),
                      v_ecef=np.zeros((n, 3)) if velocities else None,
                      sigma_v_ned=np.full((n, 3), 0.02) if velocities else None)
    return ImuData(t, dth, dv, rate), fixes


def _heading_z(grade: str, seeds, **kw):
    out = []
    for seed in seeds:
        heading = (137.0 * seed + 20.0) % 360.0
        imu, fixes = _static(grade, heading, seed, **kw)
        res = process("lc", imu, grade, np.zeros(3), lc_fixes=fixes)
        sig = float(np.median(res.trajectory.sigma[:, 5]))
        err = (float(np.median(res.trajectory.rph[:, 2])) - heading + 180.0) % 360.0 - 180.0
        out.append((err, sig, res))
    return out


def test_gyrocompass_limit_by_grade():
    """sigma_b / (Omega cos lat): a navigation-grade gyro reaches hundredths of a degree in 2 minutes, a MEMS or
    tactical one nothing (the sigma of an unknown heading)."""
    nav = imu_grade("navigation").smoother_noise()
    s = np.degrees(gyrocompass_sigma(nav, 35.3, 120.0))
    sb = np.hypot(nav.gyro_bias_sigma, nav.gyro_arw / np.sqrt(120.0))
    assert s == pytest.approx(np.degrees(sb / (OMEGA_EARTH * np.cos(np.radians(35.3)))), rel=1e-9)
    assert 0.02 < s < 0.1
    for grade in ("consumer", "adis16488"):
        assert np.degrees(gyrocompass_sigma(imu_grade(grade).smoother_noise(), 35.3, 120.0)) == pytest.approx(
            HEADING_UNKNOWN_SIGMA_DEG)
    # at the pole the earth rate has no horizontal part
    assert np.degrees(gyrocompass_sigma(nav, 90.0, 120.0)) == pytest.approx(HEADING_UNKNOWN_SIGMA_DEG)


def test_heading_from_motion_and_heading_rows():
    noise = imu_grade("consumer").smoother_noise()
    t = np.arange(0.0, 60.0, 0.5)
    still = np.zeros((len(t), 3))
    assert not heading_from_motion(t, still, noise)
    fast = np.tile([4.0, 0.0, 0.0], (len(t), 1))
    assert heading_from_motion(t, fast, noise)                     # a course
    turning = np.stack([np.cos(t), np.sin(t), 0 * t], -1) * 2.0   # 2 m/s circles: 2 m/s^2 centripetal
    assert heading_from_motion(t, turning, noise)
    # a rotation about nav down in body axes changes the heading one to one, at any roll and pitch
    from scipy.spatial.transform import Rotation
    R = Rotation.from_euler("ZYX", [[30, 20, -40], [200, -10, 5]], degrees=True).as_matrix()
    u_b = R[:, 2, :]
    assert np.allclose(np.einsum("ni,ni->n", heading_rows(R), u_b), 1.0)


def test_static_mems_record_reports_an_unknown_heading():
    """Consumer grade, static, eight headings/seeds: the heading error is whatever the start was, its sigma 104 deg
    (before: 25-30 deg with 60-150 deg errors, error/sigma up to 4), error/sigma RMS 0.7-1.4 (0.84)."""
    runs = _heading_z("consumer", range(8))
    z = np.array([e / s for e, s, _ in runs])
    print("\nconsumer static: errors", [round(e, 1) for e, _, _ in runs], "sigma", runs[0][1],
          f"error/sigma RMS {np.sqrt(np.mean(z ** 2)):.2f}")
    assert all(s == pytest.approx(HEADING_UNKNOWN_SIGMA_DEG, rel=0.01) for _, s, _ in runs)
    assert 0.7 <= np.sqrt(np.mean(z ** 2)) <= 1.4 and np.abs(z).max() <= 180.0 / HEADING_UNKNOWN_SIGMA_DEG + 1e-6
    res = runs[0][2]
    assert res.smoothed.info["heading_budget_deg"] == pytest.approx(HEADING_UNKNOWN_SIGMA_DEG)
    assert any("heading not observable" in w for w in res.summary["warnings"])
    # roll and pitch untouched by the heading budget (the accelerometers level it)
    assert np.median(res.trajectory.sigma[:, 3]) < 2.0


def test_static_navigation_grade_gyrocompasses():
    """Navigation grade, static, eight headings/seeds: the heading from the earth rate alone, within 0.2 deg, its
    sigma (0.093 deg: the gyrocompassing limit of the turn-on bias, 0.056 deg, with the in-run bias the accelerometers
    and gyros drift by) between the limit and twice it, error/sigma RMS 0.7-1.4 (0.85)."""
    runs = _heading_z("navigation", range(8))
    err = np.array([e for e, _, _ in runs])
    sig = np.array([s for _, s, _ in runs])
    limit = np.degrees(gyrocompass_sigma(imu_grade("navigation").smoother_noise(), 35.3, 120.0))
    z = err / sig
    print(f"\nnavigation static: errors {err.round(3)} deg, sigma {sig.round(3)} (limit {limit:.3f}), error/sigma RMS "
          f"{np.sqrt(np.mean(z ** 2)):.2f}")
    assert np.abs(err).max() < 0.2
    assert np.all(np.abs(z) < 3.0) and np.all(sig >= limit * 0.999) and np.all(sig < 2.0 * limit)
    assert 0.7 <= np.sqrt(np.mean(z ** 2)) <= 1.4


def test_gyro_bias_beyond_the_grade_is_flagged():
    """A consumer gyro with a 3000 deg/h z bias (beyond 3 sigma of the grade's turn-on 720 deg/h) standing still with
    zero-velocity fixes: the smoother's static start estimates the bias and the summary flags it."""
    imu, fixes = _static("consumer", 60.0, 7, extra_gyro_bias_deg_h=(0.0, 0.0, 3000.0), velocities=True)
    res = process("lc", imu, "consumer", np.zeros(3), lc_fixes=fixes)
    assert any("gyro z bias estimate" in w and "beyond" in w for w in res.summary["warnings"]), res.summary["warnings"]
    imu, fixes = _static("consumer", 60.0, 7, velocities=True)
    res = process("lc", imu, "consumer", np.zeros(3), lc_fixes=fixes)
    assert not any("gyro" in w and "beyond" in w for w in res.summary["warnings"])
