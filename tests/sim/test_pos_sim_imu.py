"""IMU simulator and grades: noise densities, bias processes, scale/misalignment recovered from the output."""
from dataclasses import replace

import numpy as np
import pytest

from dgcal.fields.constants import G0
from dgcal.pos.ins.error_model import DEG, GRADES, ImuErrorModel, imu_grade
from dgcal.sim.imu import gauss_markov, simulate_imu
from dgcal.sim.trajectory import simulate_true_trajectory


@pytest.fixture(scope="module")
def truth():
    return simulate_true_trajectory(heights_agl=(200.0,), n_strips=2, strip_length_m=600.0, rate_hz=100.0,
                                    duration_s=400.0)


def test_datasheet_round_trip_and_presets():
    g = imu_grade("adis16488")
    ds = g.datasheet()
    assert ds["gyro_arw_deg_rt_h"] == pytest.approx(0.3)
    assert ds["gyro_bias_instability_deg_h"] == pytest.approx(6.0)
    assert ds["accel_vrw_m_s_rt_h"] == pytest.approx(0.029)
    assert ds["accel_bias_instability_mg"] == pytest.approx(0.1)
    assert g.gyro_arw == pytest.approx(0.3 * DEG / 60)
    assert ImuErrorModel.from_dict(g.as_dict()) == g
    assert imu_grade("tactical") is GRADES["adis16488"] and imu_grade("ADIS-16405").name == "adis16405"
    # presets are ordered by quality (the old ADIS16405 is noisier than today's consumer parts)
    order = ["navigation", "adis16488", "consumer"]
    for name in ("gyro_arw", "accel_vrw", "gyro_bias_instability", "accel_bias_instability", "gyro_bias_sigma"):
        v = [getattr(GRADES[k], name) for k in order]
        assert v == sorted(v), name
    with pytest.raises(ValueError, match="unknown IMU grade"):
        imu_grade("gold")


def test_perfect_grade_returns_truth(truth):
    imu, err = simulate_imu(truth, imu_grade("consumer").scaled(0.0), seed=3)
    np.testing.assert_array_equal(imu.dtheta, truth.dtheta)
    np.testing.assert_array_equal(imu.dvel, truth.dvel)
    assert imu.rate_hz == truth.rate_hz and np.array_equal(imu.t, truth.t)


def test_white_noise_density_and_error_model(truth):
    g = imu_grade("adis16405")
    imu, err = simulate_imu(truth, g, seed=7)
    dt = 1.0 / truth.rate_hz
    e_g = imu.dtheta - truth.dtheta @ err.gyro_matrix.T - err.gyro_bias * dt
    e_a = imu.dvel - truth.dvel @ err.accel_matrix.T - err.accel_bias * dt
    assert np.std(e_g) / np.sqrt(dt) == pytest.approx(g.gyro_arw, rel=0.02)
    assert np.std(e_a) / np.sqrt(dt) == pytest.approx(g.accel_vrw, rel=0.02)
    assert np.abs(err.gyro_turn_on).max() < 5 * g.gyro_bias_sigma
    assert np.abs(err.accel_bias - err.accel_turn_on).max() < 6 * g.accel_bias_instability


def test_scale_and_misalignment_recovered_from_output(truth):
    g = replace(imu_grade("consumer"), gyro_arw=0.0, accel_vrw=0.0)
    imu, err = simulate_imu(truth, g, seed=5)
    dt = 1.0 / truth.rate_hz
    for true_inc, meas, M in ((truth.dtheta, imu.dtheta - err.gyro_bias * dt, err.gyro_matrix),
                              (truth.dvel, imu.dvel - err.accel_bias * dt, err.accel_matrix)):
        assert np.abs(M - np.eye(3)).max() > 1e-3  # errors of a few mrad / 0.1 % were drawn
        X, *_ = np.linalg.lstsq(true_inc, meas, rcond=None)
        np.testing.assert_allclose(X.T, M, atol=1e-9)
    np.testing.assert_allclose(np.diag(err.gyro_matrix) - 1, err.gyro_scale)


def test_gauss_markov_statistics():
    rng = np.random.default_rng(1)
    x = gauss_markov(400_000, 0.05, sigma=2.0, tau=5.0, rng=rng)
    assert np.std(x) == pytest.approx(2.0, rel=0.05)
    lag = int(5.0 / 0.05)
    r = np.mean(x[:-lag] * x[lag:]) / np.var(x)
    assert r == pytest.approx(np.exp(-1), abs=0.05)


def test_seed_reproducible_and_distinct(truth):
    a, _ = simulate_imu(truth, "adis16488", seed=11)
    b, _ = simulate_imu(truth, "adis16488", seed=11)
    c, _ = simulate_imu(truth, "adis16488", seed=12)
    assert np.array_equal(a.dtheta, b.dtheta) and not np.array_equal(a.dtheta, c.dtheta)


def test_smoother_reads_the_grade():
    g = imu_grade("adis16488")
    n = g.smoother_noise()
    assert n.gyro_arw == pytest.approx(g.gyro_arw) and n.accel_vrw == pytest.approx(g.accel_vrw)
    assert n.gyro_bias_sigma >= g.gyro_bias_sigma and n.accel_bias_sigma >= g.accel_bias_sigma
    assert G0 == pytest.approx(9.80665)


def test_simulate_imu_dataset_files_read_back(tmp_path):
    import json

    from dgcal.fields.io.formats import read_events, read_trajectory
    from dgcal.pos.ins.imu_data import read_kf_gins
    from dgcal.sim.imu import simulate_imu_dataset
    info = simulate_imu_dataset(tmp_path / "out", seed=2, grade="consumer", heights_agl=(150.0,), n_strips=2,
                                duration_s=120.0, rate_hz=50.0, delay_s=-0.05)
    d = tmp_path / "out"
    assert json.loads((d / "truth.json").read_text())["imu_errors"]["gyro_turn_on_rad_s"] == \
        info["imu_errors"]["gyro_turn_on_rad_s"]
    imu = read_kf_gins(d / "imu.txt", gps_week=info["gps_week"])
    assert len(imu) == 120 * 50 + 1 and imu.rate_hz == 50.0
    tr = read_trajectory(d / "trajectory_true.csv")
    assert tr.t[0] == pytest.approx(imu.t[0], abs=1e-5)
    ev = read_events(d / "events.csv")
    assert len(ev.t) > 0 and (ev.t - 0.05 >= tr.t[0]).all()
    assert not list(d.glob(".staging*"))


def test_first_order_recursion_is_the_iir_filter():
    """The blocked Gauss-Markov recursion equals scipy.signal.lfilter([1], [1, -phi]) to rounding, across block
    edges, for short and long series and for fast and slow processes."""
    from scipy.signal import lfilter

    from dgcal.sim.imu import first_order_recursion
    rng = np.random.default_rng(3)
    for n, phi in [(1, 0.9), (255, 0.99), (256, 0.5), (257, 0.999), (20_001, 0.9999), (3000, 0.01)]:
        w = rng.standard_normal((n, 3))
        ref = lfilter([1.0], [1.0, -phi], w, axis=0)
        np.testing.assert_allclose(first_order_recursion(w, phi), ref, rtol=0, atol=1e-13 * np.abs(ref).max())
    assert first_order_recursion(np.zeros((0, 3)), 0.5).shape == (0, 3)
