"""The IMU-GNSS time offset from the smoother's chi-square profile (issue 12, dgcal.pos.smoother.time_offset)."""
from __future__ import annotations

import numpy as np
import pytest


from dgcal.pos.smoother.time_offset import estimate_time_offset, parabola_vertex, shifted_imu  # noqa: E402


@pytest.mark.parametrize("true,sigma", [(0.037, 0.004), (-0.3, 0.05), (0.0015, 0.0008), (0.5, 0.002)])
def test_profile_search_finds_the_vertex_and_its_width(true, sigma):
    """An exact chi-square parabola: the search reaches its vertex from 0 (also 250 sigma away) and the sigma is
    where the chi-square grows by one."""
    e = estimate_time_offset(lambda d: 100.0 + (d - true) ** 2 / sigma ** 2)
    assert e.offset_s == pytest.approx(true, abs=1e-6)
    assert e.sigma_s == pytest.approx(sigma, rel=1e-6)
    assert len(e.trials) <= 16


def test_a_flat_profile_is_unobservable_not_an_estimate():
    e = estimate_time_offset(lambda d: 42.0)
    assert e.sigma_s == np.inf and "too little motion" in e.note
    assert parabola_vertex(np.array([-1.0, 0.0, 1.0]), np.array([1.0, 2.0, 1.0])) != parabola_vertex(
        np.array([-1.0, 0.0, 1.0]), np.array([2.0, 1.0, 2.0]))
    assert np.isnan(parabola_vertex(np.array([-1.0, 0.0, 1.0]), np.array([1.0, 2.0, 1.0]))[0])


def test_shifted_imu_moves_samples_and_bridges():
    from dgcal.pos.ins.imu_data import ImuData
    from dgcal.pos.ins.integrity import Bridge
    t = np.arange(1.0, 2.0, 0.01)
    imu = ImuData(t, np.zeros((len(t), 3)), np.zeros((len(t), 3)), 100.0,
                  bridges=[Bridge(1.2, 1.3, np.eye(3), np.eye(3))])
    s = shifted_imu(imu, 0.125)
    assert np.allclose(s.t, t + 0.125) and s.bridges[0].t0 == pytest.approx(1.325)
    assert imu.t[0] == 1.0   # the original is untouched
