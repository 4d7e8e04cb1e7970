"""Attitude sigmas that hold on the simulator's families (issue 27), eight IMU draws each (misaligned ADIS16488 class
unless said): roll/pitch/heading error/sigma RMS within 0.7-1.4 and no epoch beyond 5 sigma.

* 5-minute fixed wing (4 strips, coordinated turns), LC on white and on RTK-like fixes (was 0.38-0.63 on seeds 0-2
  and a heading of 0.57 over 0-7: the turn noise counted a roll into a bank and out again twice, and the gyro
  misalignment's whole variance, `dgcal.pos.smoother.preintegration`);
* 5-minute multirotor (`simulate_pos`), TC on code + Doppler;
* slow: the same multirotor over 20 minutes (TC), LC on its SPP, and the low-cost flight (ADIS16405). The 20-minute
  roll looked conservative on seeds 0-2 alone (0.60): those three drew small errors, over 0-7 it is 1.10.
"""
from __future__ import annotations

import numpy as np
import pytest

from dgcal.pos.gnss.spp import SppOptions
from dgcal.pos.gnss_ins import process
from dgcal.pos.ins.error_model import imu_grade
from dgcal.pos.smoother.batch import SmootherOptions, smooth
from dgcal.pos.smoother.initial import GnssFixes
from dgcal.sim.imu import simulate_imu
from dgcal.sim.pos import navigation_errors, simulate_pos
from dgcal.sim.trajectory import simulate_true_trajectory

from test_pos_lc_fix_errors import _fixes

SEEDS = range(8)


def _check(z: list, label: str) -> None:
    """Pool the flights' attitude error/sigma (K,3 each) and hold it to 0.7-1.4 per axis, none beyond 5 sigma."""
    z = np.concatenate(z)
    rms = np.sqrt(np.mean(z ** 2, axis=0))
    print(f"\n{label}: roll/pitch/heading error/sigma RMS {rms.round(2)}, largest {np.abs(z).max():.1f}")
    assert np.all((rms >= 0.7) & (rms <= 1.4)), rms
    assert np.abs(z).max() < 5.0


@pytest.fixture(scope="module")
def truth():
    return simulate_true_trajectory("fixed-wing", heights_agl=(300.0,), n_strips=4, strip_length_m=700.0,
                                    rate_hz=100.0)


@pytest.mark.parametrize("fixes", ["white 2 cm", "rtk-like"])
def test_fixed_wing_attitude_error_sigma(truth, fixes):
    grade = imu_grade("adis16488")
    z = []
    for seed in SEEDS:
        imu, _ = simulate_imu(truth, grade, seed=seed, misalignment=True)
        if fixes == "white 2 cm":
            fx, _ = _fixes(truth, seed + 10, 1.0, [1e-6] * 3, 30.0, 0.02)
        else:
            fx, _ = _fixes(truth, seed + 10, 1.0, [0.01] * 3, 30.0, 0.003)
        _, dth, _, sa = navigation_errors(smooth(imu, fx, grade, SmootherOptions(), mode="lc"), truth)
        z.append(dth / sa)
    _check(z, fixes)


def _multirotor_z(mode: str, duration_s: float) -> list:
    """Attitude error/sigma of `simulate_pos` multirotor flights (100 Hz IMU, code + Doppler of exact models) over
    SEEDS, TC or LC on their SPP (Doppler velocities, on time)."""
    z = []
    for seed in SEEDS:
        sim = simulate_pos(seed=seed, duration_s=duration_s, rate_hz=100.0, carrier=False)
        opts = SppOptions(code_sigma_zenith_m=sim.sigma_pr, doppler_sigma_zenith_mps=sim.sigma_doppler,
                          model_errors=False, systems=("G", "E"))
        so = SmootherOptions(lc_velocity="true") if mode == "lc" else None
        r = process(mode, sim.imu, sim.grade, sim.lever_arm_b, raw_obs=sim.obs, nav=sim.nav, spp_opts=opts,
                    smoother_opts=so)
        _, dth, _, sa = navigation_errors(r.smoothed, sim.traj)
        z.append(dth / sa)
    return z


def test_multirotor_tc_attitude_error_sigma():
    _check(_multirotor_z("tc", 300.0), "multirotor TC, 5 min")


@pytest.mark.slow
def test_multirotor_tc_20_minutes_attitude_error_sigma():
    """Twenty minutes of strips and yaw turns: the turn noise of every turn and the accelerometers' tilt budget
    against the GNSS re-observing roll and pitch between the turns (about a third of the roll variance each)."""
    _check(_multirotor_z("tc", 1200.0), "multirotor TC, 20 min")


@pytest.mark.slow
def test_multirotor_lc_on_spp_attitude_error_sigma():
    _check(_multirotor_z("lc", 300.0), "multirotor LC on SPP, 5 min")


@pytest.mark.slow
def test_low_cost_flight_attitude_error_sigma():
    """The low-cost flight (ADIS16405, metre-level fixes correlated over a minute), LC on 10 Hz of its 50 Hz fixes."""
    from dgcal.sim.lowcost_flight import simulate_lowcost_flight
    z = []
    for seed in SEEDS:
        f = simulate_lowcost_flight(duration_s=300.0, seed=seed)
        s = slice(None, None, 5)
        fx = GnssFixes(f.fixes.t[s], f.fixes.p_ecef[s], f.fixes.sigma_ned[s], f.fixes.v_ecef[s],
                       f.fixes.sigma_v_ned[s])
        _, dth, _, sa = navigation_errors(smooth(f.imu, fx, f.imu_errors.grade, SmootherOptions(), mode="lc"),
                                          f.truth)
        z.append(dth / sa)
    _check(z, "low-cost LC")
