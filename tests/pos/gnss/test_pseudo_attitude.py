"""Pseudo attitude from GNSS velocity (seed 001 eq. 1-8) against the simulator's coordinated-turn truth."""
import numpy as np
import pytest

from dgcal.fields.constants import OMEGA_IE_E
from dgcal.pos.gnss.pseudo_attitude import pseudo_attitude, time_derivative
from dgcal.sim.trajectory import G_NOMINAL, simulate_true_trajectory


@pytest.fixture(scope="module")
def truth():
    return simulate_true_trajectory(heights_agl=(200.0,), n_strips=3, strip_length_m=500.0, rate_hz=50.0, aoa_deg=0.0)


def _wrap(d):
    return (d + 180.0) % 360.0 - 180.0


def _gnss(truth, hz):
    k = np.arange(0, len(truth.t), int(round(truth.rate_hz / hz)))
    return k, truth.t[k], truth.v_ned[k]


def test_exact_velocity_and_acceleration_give_true_attitude(truth):
    k, t, v = _gnss(truth, 10.0)
    h = 0.01
    a = (truth.at(t + h).v_ned - truth.at(t - h).v_ned) / (2 * h)
    pa = pseudo_attitude(t, v, a_ned=a, g=G_NOMINAL)
    assert pa.valid.all()
    d = _wrap(pa.rph - truth.rph[k])
    assert np.abs(d[:, 0]).max() < 0.05  # roll: tangent-plane vs local level (~0.01 deg/km) and rounding
    assert np.abs(d[:, 1]).max() < 0.02
    assert np.abs(d[:, 2]).max() < 0.02
    assert np.ptp(truth.rph[k, 0]) > 45  # the flight has +-25 deg turns


def test_noisy_doppler_velocity_smoothed(truth):
    k, t, v = _gnss(truth, 10.0)
    rng = np.random.default_rng(4)
    vn = v + rng.normal(0, 0.02, v.shape)  # Doppler velocity noise
    pa = pseudo_attitude(t, vn, window_s=0.8)
    d = _wrap(pa.rph - truth.rph[k])
    rms = np.sqrt(np.mean(d ** 2, axis=0))
    assert rms[0] < 0.4 and rms[1] < 0.1 and rms[2] < 0.1
    # body rates (eq. 8) against the true rates relative to the earth
    w_eb = truth.omega_ib_b[k] - np.einsum("nji,j->ni", truth.R_body_to_ecef[k], OMEGA_IE_E)
    err = pa.omega_b - w_eb
    assert np.sqrt(np.mean(err ** 2)) < np.radians(1.0)
    # rates: heading rate in turns is the turn rate
    turning = np.abs(truth.rph[k, 0]) > 24.9  # steady part of the turns
    r_true = 9.79 * np.tan(np.radians(25.0)) / 25.0
    np.testing.assert_allclose(np.abs(np.radians(pa.rph_rate[turning, 2])), r_true, rtol=0.05)


def test_slow_samples_invalid_and_derivative():
    t = np.arange(0.0, 10.0, 0.1)
    v = np.column_stack([np.linspace(0, 10, len(t)), np.zeros(len(t)), np.zeros(len(t))])
    pa = pseudo_attitude(t, v, min_speed=3.0)
    assert not pa.valid[0] and pa.valid[-1] and np.isnan(pa.rph[0]).all()
    assert np.abs(pa.rph[pa.valid, :2]).max() < 1e-9 and np.abs(pa.rph[pa.valid, 2]).max() < 1e-9
    y = np.column_stack([np.sin(t), t ** 2])
    dy = time_derivative(t, y, window_s=0.5)
    np.testing.assert_allclose(dy[5:-5, 1], 2 * t[5:-5], atol=1e-9)
    np.testing.assert_allclose(dy[5:-5, 0], np.cos(t[5:-5]), atol=1e-2)
