"""TC with carrier phase against a base (issue 12) on a simulated UAV flight, in a short version for the suite.

ADIS16488-class IMU at 100 Hz (scale factors, no triad misalignment: a misaligned accelerometer triad tilts the
body frame by its x/y-from-z misalignment, 0.02 deg per axis for this class, which no GNSS can see and the
smoother does not estimate, see docs/pos_smoother.md); rover and base RINEX-grade dual-frequency
code and carrier phase from the real broadcast orbits (`dgcal.sim.gnss.simulate_rover_base`: multipath as
Gauss-Markov errors, differential ionosphere and troposphere residuals, cycle slips, a 10 s total outage and
60 s with only three satellites). The 20-minute, 200 Hz version runs in bench/pos.py (`--carrier`).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dgcal.pos.gnss.carrier import code_observations
from dgcal.pos.gnss.spp import SppOptions
from dgcal.pos.gnss_ins import fixes_from_ppk, process
from dgcal.sim.pos import navigation_errors, simulate_pos



def rms(x, axis=0):
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=axis))


@pytest.fixture(scope="module")
def flight():
    sim = simulate_pos(seed=2, duration_s=360.0, rate_hz=100.0, misalignment=False)
    sim.grade = dataclasses.replace(sim.grade, gyro_misalign_sigma=0.0, accel_misalign_sigma=0.0)  # as simulated
    c = sim.carrier
    opts = SppOptions(code_sigma_zenith_m=0.3, doppler_sigma_zenith_mps=0.1, model_errors=False, systems=("G", "E"))
    raw = code_observations(c.rover)
    tc = process("tc", sim.imu, sim.grade, sim.lever_arm_b, raw_obs=raw, nav=sim.nav, spp_opts=opts,
                 events=sim.events, carrier=(c.rover, c.base, c.base_ecef))
    # LC fed with the same PPK positions (fixed and float, with their covariances)
    lc = process("lc", sim.imu, sim.grade, sim.lever_arm_b, lc_fixes=fixes_from_ppk(tc.carrier.ppk),
                 events=sim.events, forward=False)
    return {"sim": sim, "tc": tc, "lc": lc}


def test_tc_with_carrier_reaches_centimetres(flight):
    dp, dth, _, _ = navigation_errors(flight["tc"].smoothed, flight["sim"].traj)
    rms3 = np.sqrt(np.mean(np.sum(dp ** 2, axis=1)))
    att = np.degrees(rms(dth))
    print(f"\nTC carrier: 3D RMS {100 * rms3:.2f} cm, attitude RMS {att.round(4)} deg")
    assert rms3 <= 0.03
    assert att[0] <= 0.02 and att[1] <= 0.02 and att[2] <= 0.06


def test_tc_with_carrier_sigmas_are_honest(flight):
    dp, dth, sp, sa = navigation_errors(flight["tc"].smoothed, flight["sim"].traj)
    nees_p, nees_a = rms((dp / sp).ravel()), rms((dth / sa).ravel())
    print(f"\nnormalised errors: position {nees_p:.2f} {rms(dp / sp).round(2)}, attitude {nees_a:.2f} "
          f"{rms(dth / sa).round(2)}")
    assert 0.7 <= nees_p <= 1.4
    # scale factors are white noise in the turns (not estimated): one realisation per flight of a 1-sigma model,
    # so the attitude sigmas are conservative, mostly in heading (docs/pos_smoother.md)
    assert 0.6 <= nees_a <= 1.4


def test_three_satellites_for_a_minute(flight):
    sim, tc, lc = flight["sim"], flight["tc"].smoothed, flight["lc"].smoothed
    t0, t1, nmax = sim.outage
    inside = (tc.t >= t0 + 1) & (tc.t <= t1 - 1)
    assert inside.sum() >= 55 and np.all(tc.n_sat[inside] <= nmax)
    ddp = [k for k in np.nonzero(inside)[0] if k in tc.problem.dd and np.any(tc.problem.dd[k].cur.kind == 0)]
    assert len(ddp) == inside.sum()                      # every epoch of the minute contributes carrier phase
    e_tc = np.linalg.norm(navigation_errors(tc, sim.traj)[0][inside], axis=1)
    in_lc = (lc.t >= t0 + 1) & (lc.t <= t1 - 1)
    e_lc = np.linalg.norm(navigation_errors(lc, sim.traj)[0][in_lc], axis=1)
    print(f"\n3-satellite minute: TC max {100 * e_tc.max():.1f} cm RMS {100 * rms(e_tc):.1f} cm; LC on the same PPK "
          f"positions max {100 * e_lc.max():.1f} cm RMS {100 * rms(e_lc):.1f} cm")
    assert e_tc.max() <= 0.10
    assert rms(e_tc) < rms(e_lc) and e_tc.max() < e_lc.max()


def test_front_end_fixes_and_reports(flight):
    s = flight["tc"].summary["carrier"]
    assert s["integers"]["conflicts"] == 0 and s["keyframes_with_phase_and_lt4_sats"] >= 55
    assert s["tc_minus_ppk_fixed_rms_m"] < 0.02
    res = flight["tc"].summary["residuals"]
    assert 0.7 <= res["ddp"]["rms_normalised"] <= 1.4 and 0.7 <= res["ddc"]["rms_normalised"] <= 1.4
    # every simulated slip and loss of lock is seen (flag, gap or jump) by the rover's slip detection
    assert s["slips_flagged_rover"] >= len(flight["sim"].carrier.truth["slips"])


def _jacobian(factor):
    import gtsam
    g = gtsam.GaussianFactorGraph()
    g.push_back(factor)
    return g.jacobian()


def test_linearised_dd_factors_equal_the_exact_ones(flight):
    """The smoother's double differences are linearised factors (`linear_dd_factor`): at their linearisation point
    the same error and Jacobian as the exact CustomFactor, 0.5 m and 0.02 deg away a cost within 1e-6 of its; the
    smoother's batch of them (`linear_dd_factors`, every keyframe's rows in one pass) is the same factors."""
    import gtsam
    from dgcal.pos.smoother.carrier import dd_factor, keyframe_poses, linear_dd_factor, linear_dd_factors
    from dgcal.pos.smoother.factors import X
    sol = flight["tc"].smoothed
    problem, values = sol.problem, sol.values
    batch = linear_dd_factors(problem.dd, problem.lever_arm_b, problem.frame, values, X,
                              *keyframe_poses(values, len(problem.t_key)))
    assert set(batch) == set(problem.dd)
    checked = 0
    for k, data in list(problem.dd.items())[::40]:
        xp = X(k - 1) if data.prev is not None else None
        exact = dd_factor(xp, X(k), data, problem.lever_arm_b, problem.frame)
        lin = linear_dd_factor(xp, X(k), data, problem.lever_arm_b, problem.frame, values)
        assert list(batch[k].keys()) == list(lin.keys())
        assert batch[k].error(values) == pytest.approx(lin.error(values), rel=1e-12, abs=1e-15)
        A0, b0 = _jacobian(batch[k].linearize(values))
        A3, b3 = _jacobian(lin.linearize(values))
        np.testing.assert_allclose(A0, A3, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(b0, b3, rtol=1e-10, atol=1e-9)
        assert lin.error(values) == pytest.approx(exact.error(values), rel=1e-9, abs=1e-12)
        A1, b1 = _jacobian(exact.linearize(values))
        A2, b2 = _jacobian(lin.linearize(values))
        # whitening differs by an orthogonal factor (gtsam's upper Cholesky vs ours): compare A'A and A'b
        np.testing.assert_allclose(A1.T @ A1, A2.T @ A2, rtol=1e-8, atol=1e-6)
        np.testing.assert_allclose(A1.T @ b1, A2.T @ b2, rtol=1e-8, atol=1e-6)
        moved = gtsam.Values(values)
        for key in exact.keys():
            moved.update(key, values.atPose3(key).retract(np.r_[np.radians([0.02, -0.02, 0.02]), 0.5, -0.5, 0.5]))
        assert abs(lin.error(moved) - exact.error(moved)) <= 1e-6 * max(exact.error(moved), 1.0)
        checked += 1
    assert checked >= 5


def test_tc_with_carrier_on_the_uav_family():
    """Issue 26: TC with carrier phase on UAV flights as a real airframe sees them (a misaligned ADIS16488-class IMU,
    the airframe masking the low satellites in banks, slips while banked, half cycles, every other flight without
    Doppler, a minute with three satellites): 3D RMS <= 2 cm on every flight, and over the family the position and
    attitude errors within their sigmas (error/sigma RMS 0.7-1.4 per axis)."""
    zp, za = [], []
    for seed in range(12):
        sim = simulate_pos(seed=seed, duration_s=360.0, rate_hz=100.0, misalignment=True, airframe_mask_deg=10.0,
                           turn_slip_rate=0.01, half_cycle_share=0.3, carrier_doppler=seed % 2 == 0)
        c = sim.carrier
        opts = SppOptions(code_sigma_zenith_m=0.3, doppler_sigma_zenith_mps=0.1, model_errors=False,
                          systems=("G", "E"))
        tc = process("tc", sim.imu, sim.grade, sim.lever_arm_b, raw_obs=code_observations(c.rover), nav=sim.nav,
                     spp_opts=opts, events=sim.events, carrier=(c.rover, c.base, c.base_ecef))
        dp, dth, sp, sa = navigation_errors(tc.smoothed, sim.traj)
        rms3 = np.sqrt(np.mean(np.sum(dp ** 2, axis=1)))
        aided = tc.carrier.info.get("imu_aided")
        print(f"\nseed {seed}: 3D RMS {100 * rms3:.2f} cm, slips {len(c.truth['slips'])}, "
              f"half cycles {c.truth['half_cycles']}, PPK fixed {100 * np.mean(tc.carrier.ppk.status == 3):.0f} %, "
              f"IMU-aided integers {aided}, error/sigma position {rms(dp / sp).round(2)} "
              f"attitude {rms(dth / sa).round(2)}")
        assert rms3 <= 0.02
        if seed == 0:          # PPK alone (forward) fixes 62 %: the smoother's positions tie 28 more arcs
            assert aided is not None and aided["arcs_after"] > aided["arcs_before"] + 10
        zp.append(dp / sp)
        za.append(dth / sa)
    zp, za = rms(np.vstack(zp)), rms(np.vstack(za))
    print(f"family: error/sigma RMS position {zp.round(3)}, attitude {za.round(3)}")
    assert np.all((zp > 0.7) & (zp < 1.4)) and np.all((za > 0.7) & (za < 1.4))
