"""LC with time-correlated fix errors and fix velocities of unknown timing (issue 27, `dgcal.pos.smoother.fix_errors`,
`dgcal.pos.smoother.fix_velocity`).

Fixes whose errors are Gauss-Markov (RTK-like centimetres over half a minute; a low-cost receiver's metres over a
minute) are averaged by a white-noise smoother as independent and its sigmas come out several to tens of times too
small; with the error states and the white share estimated from the data they cover the errors. White fixes keep
their weight (the white share stays one). Velocities that lag the positions are found, and used with the lag
removed.
"""
from __future__ import annotations

import numpy as np
import pytest

from dgcal.fields.frames import R_ecef_to_ned
from dgcal.pos.ins.error_model import imu_grade
from dgcal.pos.smoother.batch import SmootherOptions, smooth
from dgcal.pos.smoother.fix_velocity import shifted_velocities, velocity_latency, velocity_mode
from dgcal.pos.smoother.initial import GnssFixes
from dgcal.sim.imu import simulate_imu
from dgcal.sim.pos import navigation_errors
from dgcal.sim.trajectory import simulate_true_trajectory


def rms(x, axis=0):
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=axis))


@pytest.fixture(scope="module")
def flight():
    """A 4-strip fixed-wing flight (300 m above ground, coordinated turns) with a misaligned ADIS16488-class IMU."""
    truth = simulate_true_trajectory("fixed-wing", heights_agl=(300.0,), n_strips=4, strip_length_m=700.0,
                                     rate_hz=100.0)
    grade = imu_grade("adis16488")
    imu, _ = simulate_imu(truth, grade, seed=3, misalignment=True)
    return truth, imu, grade


def _gm(n: int, dt: float, sigma, tau: float, rng) -> np.ndarray:
    """(n,3) first-order Gauss-Markov sequences of per-axis sigma and correlation time tau at step dt."""
    phi = np.exp(-dt / tau)
    e = np.empty((n, 3))
    e[0] = rng.standard_normal(3) * sigma
    w = rng.standard_normal((n, 3)) * np.asarray(sigma) * np.sqrt(1 - phi ** 2)
    for k in range(1, n):
        e[k] = phi * e[k - 1] + w[k]
    return e


def _fixes(truth, seed: int, rate_hz: float, gm_sigma, tau_s: float, white_m: float, lag_s: float = 0.0,
           sigma_v: float = 0.03):
    """Antenna fixes (lever arm zero) with Gauss-Markov plus white errors, stated with their total sigma, and
    velocities lagging by `lag_s`."""
    rng = np.random.default_rng(seed)
    t = np.arange(np.ceil(truth.t[0]) + 1.0, truth.t[-1] - 1.0, 1.0 / rate_hz)
    st = truth.at(t)
    e_ned = _gm(len(t), 1.0 / rate_hz, gm_sigma, tau_s, rng) + rng.normal(0, white_m, (len(t), 3))
    R_ned_to_ecef = np.swapaxes(R_ecef_to_ned(st.lat, st.lon), 1, 2)
    p = st.p_ecef + np.einsum("nij,nj->ni", R_ned_to_ecef, e_ned)
    v = truth.at(t - lag_s).v_ecef + rng.normal(0, sigma_v, (len(t), 3))
    s = np.tile(np.hypot(gm_sigma, white_m), (len(t), 1))
    return GnssFixes(t, p, s, v, np.full((len(t), 3), sigma_v)), e_ned


def _z(sol, truth):
    dp, dth, sp, sa = navigation_errors(sol, truth)
    return dp / sp, dth / sa, dp


def test_rtk_like_correlated_fixes_get_honest_sigmas(flight):
    """1 Hz fixes with 1 cm of Gauss-Markov error (30 s) and 3 mm white, stated as 1.04 cm: as white noise the
    smoother's sigmas are several times too small; with the error states they cover the errors (three seeds
    pooled), and the white share found is about the simulated 0.08."""
    truth, imu, grade = flight
    z_gm, z_white = [], []
    for seed in range(3):
        fx, _ = _fixes(truth, seed, 1.0, [0.01, 0.01, 0.01], 30.0, 0.003)
        z_gm.append(_z(smooth(imu, fx, grade, SmootherOptions(), mode="lc"), truth)[0])
        if seed == 0:
            s = smooth(imu, fx, grade, SmootherOptions(lc_fix_tau_s=None), mode="lc")
            z_white.append(_z(s, truth)[0])
    sol = smooth(imu, fx, grade, SmootherOptions(), mode="lc")
    shares = sol.info["lc_fix_errors"]["white_share"]
    z_gm, z_white = np.concatenate(z_gm), np.concatenate(z_white)
    print(f"\nerror/sigma with error states {rms(z_gm).round(2)} (largest {np.abs(z_gm).max():.1f}), as white "
          f"{rms(z_white).round(2)}; white share {shares}")
    assert rms(z_white.ravel()) > 2.0
    assert np.all((rms(z_gm) > 0.7) & (rms(z_gm) < 1.4)) and np.abs(z_gm).max() < 5.0
    assert 0.03 < shares[-1] < 0.3


def test_white_fixes_keep_their_weight(flight):
    """2 cm white fixes: the white share stays one, the positions are as good as the white model's and honest."""
    truth, imu, grade = flight
    fx, _ = _fixes(truth, 7, 1.0, [1e-6] * 3, 30.0, 0.02)
    sol = smooth(imu, fx, grade, SmootherOptions(), mode="lc")
    white = smooth(imu, fx, grade, SmootherOptions(lc_fix_tau_s=None), mode="lc")
    z, _, dp = _z(sol, truth)
    _, _, dp_w = _z(white, truth)
    assert sol.info["lc_fix_errors"]["white_share"][-1] > 0.8
    assert rms(np.linalg.norm(dp, axis=1)) < 1.1 * rms(np.linalg.norm(dp_w, axis=1))
    assert 0.7 < rms(z.ravel()) < 1.4


def test_low_cost_fixes_metres_correlated_over_a_minute():
    """Seed 000's low-cost flight (`dgcal simulate lowcost`: ADIS16405, 1.5 m horizontal Gauss-Markov errors over
    60 s plus 0.2 m white, fixes at 50 Hz taken at 10 Hz): error/sigma 0.7-1.4 pooled over three flights, none
    beyond 5 sigma; the white model is off by more than ten."""
    from dgcal.sim.lowcost_flight import simulate_lowcost_flight
    z, z_white = [], None
    for seed in range(3):
        f = simulate_lowcost_flight(duration_s=150.0, seed=seed)
        fx = f.fixes
        s = slice(None, None, 5)
        fx = GnssFixes(fx.t[s], fx.p_ecef[s], fx.sigma_ned[s], fx.v_ecef[s], fx.sigma_v_ned[s])
        z.append(_z(smooth(f.imu, fx, f.imu_errors.grade, SmootherOptions(), mode="lc"), f.truth)[0])
        if seed == 0:
            z_white = _z(smooth(f.imu, fx, f.imu_errors.grade, SmootherOptions(lc_fix_tau_s=None), mode="lc"),
                         f.truth)[0]
    z = np.concatenate(z)
    print(f"\nlow-cost error/sigma {rms(z).round(2)} pooled {rms(z.ravel()):.2f} (largest {np.abs(z).max():.1f}); "
          f"white model {rms(z_white).round(1)}")
    assert 0.7 < rms(z.ravel()) < 1.4 and np.abs(z).max() < 5.0
    assert rms(z_white.ravel()) > 10.0


def test_velocity_latency_estimated():
    """Velocities lagging by 0.12 s: the latency comes back within a few ms and the shift restores them; on time
    velocities give zero; without acceleration the latency is not determined and the velocities are not used."""
    t = np.arange(0.0, 200.0, 0.25)
    v = np.column_stack([10 + 3 * np.sin(0.3 * t), 4 * np.cos(0.2 * t), 0.5 * np.sin(0.5 * t)])
    lag = 0.12
    v_late = np.column_stack([10 + 3 * np.sin(0.3 * (t - lag)), 4 * np.cos(0.2 * (t - lag)),
                              0.5 * np.sin(0.5 * (t - lag))])
    rng = np.random.default_rng(0)
    sig = np.full((len(t), 3), 0.02)
    k = np.arange(len(t))
    lat = velocity_latency(t, v, k, v_late + rng.normal(0, 0.02, v.shape), sig)
    assert abs(lat.latency_s - lag) < 3 * lat.sigma_s and lat.sigma_s < 0.005 and lat.used
    assert np.max(np.abs(shifted_velocities(t, v_late, lag)[4:-4] - v[4:-4])) < 0.01
    on_time = velocity_latency(t, v, k, v + rng.normal(0, 0.02, v.shape), sig)
    assert abs(on_time.latency_s) < 3 * on_time.sigma_s and on_time.used
    still = np.tile([10.0, 0.0, 0.0], (len(t), 1))
    assert not velocity_latency(t, still, k, still + rng.normal(0, 0.02, v.shape), sig).used
    # level circles at constant speed: a lag looks exactly like a heading error there (the velocity rotated)
    circ = np.column_stack([20 * np.cos(0.1 * t), 20 * np.sin(0.1 * t), np.zeros_like(t)])
    circ_late = np.column_stack([20 * np.cos(0.1 * (t - lag)), 20 * np.sin(0.1 * (t - lag)), np.zeros_like(t)])
    lat = velocity_latency(t, circ, k, circ_late + rng.normal(0, 0.02, v.shape), sig)
    assert not lat.used and lat.shift_s == 0.0 and lat.sigma_left_s == 0.2
    assert velocity_mode(False) == "false" and velocity_mode("auto") == "auto" and velocity_mode("on") == "true"


@pytest.mark.parametrize("kind", ["multirotor", "fixed-wing"])
def test_lagging_velocities_are_used_with_the_lag_removed(flight, kind):
    """LC with cm fixes whose velocities lag by 0.15 s (as RTKLIB's filter velocities): "auto" finds the lag, on a
    multirotor (it stops and starts at every strip end) and on the fixed-wing (its climb and bank changes tell the
    lag from a heading error), removes it, and the attitude is better than with the velocities used as stated
    (much better on the fixed-wing, whose turns turn the lag into heading and pitch errors)."""
    if kind == "multirotor":
        truth = simulate_true_trajectory("multirotor", heights_agl=(100.0,), n_strips=3, strip_length_m=300.0,
                                         strip_spacing_m=60.0, rate_hz=100.0)
        grade = imu_grade("adis16488")
        imu, _ = simulate_imu(truth, grade, seed=5, misalignment=True)
    else:
        truth, imu, grade = flight
    fx, _ = _fixes(truth, 11, 2.0, [0.005] * 3, 30.0, 0.005, lag_s=0.15)
    auto = smooth(imu, fx, grade, SmootherOptions(), mode="lc")
    used = smooth(imu, fx, grade, SmootherOptions(lc_velocity="true"), mode="lc")
    info = auto.info["lc_velocity"]
    e_auto = rms(np.degrees(navigation_errors(auto, truth)[1]).ravel())
    e_used = rms(np.degrees(navigation_errors(used, truth)[1]).ravel())
    print(f"\n{kind}: latency {info}; attitude RMS auto {e_auto:.4f} deg, as stated {e_used:.4f} deg")
    assert info["used"] and abs(info["removed_ms"] - 150.0) < max(3 * info["sigma_ms"], 5.0), info
    assert e_auto < e_used
