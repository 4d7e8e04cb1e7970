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


def _windows_profile(vertices, curvatures, noise_sd=0.0, seed=0):
    """chi2_at(d) -> (total, per-window) for windows whose shares are parabolas a_w (d - v_w)^2 (+ white noise of
    `noise_sd` on each share, the smoother's convergence noise)."""
    v, a = np.asarray(vertices, float), np.asarray(curvatures, float)
    rng = np.random.default_rng(seed)

    def chi2(d):
        parts = a * (d - v) ** 2 + 50.0 + rng.normal(0.0, noise_sd, len(v))
        return float(parts.sum()), parts
    return chi2


def test_window_jackknife_matches_the_curvature_for_white_errors():
    """Windows whose vertices scatter as their own curvature says (white errors): over 400 draws the jackknife
    variance averages the curvature's (ratio of RMS 0.9-1.1), and estimate_time_offset's sigma is then the larger
    of the two, error/sigma RMS within 0.7-1.1."""
    from dgcal.pos.smoother.time_offset import window_jackknife
    rng = np.random.default_rng(3)
    a = np.array([1.0, 2.0, 4.0, 3.0, 1.0, 2.0, 5.0, 2.0]) * 1e4      # 1/s^2 (sigma_w 3-10 ms)
    formal = 1.0 / np.sqrt(a.sum())
    jk, z = [], []
    for _ in range(400):
        v = 0.04 + rng.normal(0.0, 1.0 / np.sqrt(a))
        d_hat = float(np.sum(a * v) / a.sum())
        d = d_hat + np.array([-3, -1, 0, 1, 3]) * formal
        C = a * (d[:, None] - v) ** 2
        jk.append(window_jackknife(d, C, d_hat)[0])
    ratio = np.sqrt(np.mean(np.square(jk))) / formal
    assert 0.9 < ratio < 1.1, ratio
    for seed in range(40):
        v = 0.04 + np.random.default_rng(100 + seed).normal(0.0, 1.0 / np.sqrt(a))
        e = estimate_time_offset(_windows_profile(v, a))
        assert e.windows == 8 and e.formal_sigma_s == pytest.approx(formal, rel=1e-6)
        assert e.sigma_s == pytest.approx(max(formal, e.jackknife_sigma_s))
        z.append((e.offset_s - 0.04) / e.sigma_s)
    assert 0.7 <= np.sqrt(np.mean(np.square(z))) <= 1.1


def test_windows_that_disagree_make_the_offset_not_determinable():
    """Window vertices spread 20 ms while each window's curvature claims 3 ms (correlated errors): the sigma is
    the jackknife's, far above the curvature's, the offset is declared not determinable; a steady drift of the
    windows' offsets over the record is named (a clock-rate error)."""
    a = np.full(8, 1e5)
    v = 0.05 + np.array([0.02, -0.03, 0.01, 0.025, -0.02, 0.0, 0.03, -0.015])
    e = estimate_time_offset(_windows_profile(v, a, noise_sd=0.01))
    assert e.offset_s == pytest.approx(np.mean(v), abs=1e-4)
    assert e.jackknife_sigma_s > 5 * e.formal_sigma_s and e.sigma_s == e.jackknife_sigma_s
    assert not e.determinable and "disagree" in e.note and "drift" not in e.note
    assert e.as_dict()["determinable"] is False and len(e.as_dict()["window_offsets_ms"]) == 8
    drift = estimate_time_offset(_windows_profile(-0.1 - 0.02 * np.arange(8), a))
    assert not drift.determinable and "drift from -100 to -240 ms" in drift.note, drift.note
    # consistent windows around a clear offset: determinable, sigma the curvature's (within the jackknife's noise)
    ok = estimate_time_offset(_windows_profile(0.05 + np.array([1, -1, 2, 0, -2, 1, 0, -1]) * 1e-3, a))
    assert ok.determinable and ok.sigma_s < 0.003


def test_a_sigma_larger_than_the_estimate_is_not_determinable():
    """A profile 40 ms wide around 10 ms: neither a correction nor a confirmation of the offset given."""
    e = estimate_time_offset(lambda d: 100.0 + (d - 0.01) ** 2 / 0.04 ** 2)
    assert not e.determinable and "exceeds the estimate" in e.note
    # a narrow one at zero confirms the offset given
    assert estimate_time_offset(lambda d: 100.0 + (d - 0.0005) ** 2 / 0.002 ** 2).determinable
