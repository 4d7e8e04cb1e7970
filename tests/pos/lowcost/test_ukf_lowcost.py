"""15-state UKF (seed 000 eq. 1-19): unscented transform, kinematics, and accuracy on a simulated low-cost flight."""
import numpy as np
import pytest

from dgcal.fields.frames import R_body_to_ned_from_rph
from dgcal.pos.lowcost.ukf import SigmaPoints, _R_body_to_nav_from_euler, _mean_cov, euler_rates, wrap_pi
from dgcal.sim.lowcost_flight import compare_ukf_smoother, format_accuracy_table, simulate_lowcost_flight


def test_dcm_matches_frames_convention():
    rng = np.random.default_rng(1)
    e = np.column_stack([rng.uniform(-1, 1, 20), rng.uniform(-1.2, 1.2, 20), rng.uniform(-3, 3, 20)])
    R = _R_body_to_nav_from_euler(e)
    R_ref = R_body_to_ned_from_rph(*np.degrees(e).T)
    assert np.allclose(R, R_ref, atol=1e-12)


def test_euler_rates_match_rotation_derivative():
    rng = np.random.default_rng(2)
    e = np.column_stack([rng.uniform(-1, 1, 10), rng.uniform(-1, 1, 10), rng.uniform(-3, 3, 10)])
    w = rng.normal(0, 0.5, (10, 3))
    h = 1e-6
    # R(e + h e_dot) ~ R(e) (I + h [w]x): body rates are in body axes
    R1 = _R_body_to_nav_from_euler(e + h * euler_rates(e, w))
    skew_w = np.array([[[0, -c, b], [c, 0, -a], [-b, a, 0]] for a, b, c in w])
    Rw = _R_body_to_nav_from_euler(e) @ (np.eye(3) + h * skew_w)
    assert np.abs(R1 - Rw).max() < 1e-11


def test_unscented_transform_is_exact_for_linear_maps():
    rng = np.random.default_rng(3)
    n = 6
    A = rng.normal(size=(n, n))
    P = A @ A.T + np.eye(n)
    x = rng.normal(size=n)
    sp = SigmaPoints(n, 0.5, 2.0, 0.0)
    chi = sp.points(x, P)
    M = rng.normal(size=(4, n))
    m, C = _mean_cov(chi @ M.T, sp, None)
    assert np.allclose(m, M @ x) and np.allclose(C, M @ P @ M.T)
    # angles wrap around the central point
    chi2 = np.zeros((3, 1)) + np.array([[np.pi - 0.01], [-np.pi + 0.01], [np.pi - 0.03]])
    sp1 = SigmaPoints(1, 1.0, 0.0, 0.0)
    sp1.wm = np.array([0.0, 0.5, 0.5])
    m1, _ = _mean_cov(chi2, sp1, slice(0, 1))
    assert abs(wrap_pi(m1[0] - (np.pi - 0.01))) < 1e-12


@pytest.fixture(scope="module")
def report():
    f = simulate_lowcost_flight(duration_s=120.0, rate_hz=100.0, gnss_hz=50.0, seed=4)
    rep = compare_ukf_smoother(f, smoother_rate_hz=10.0, skip_s=30.0)
    print("\n" + format_accuracy_table(rep))
    return rep


def test_ukf_attitude_beats_seed_figures(report):
    u = report["ukf"]
    assert report["gnss_rate_hz"] == pytest.approx(50.0)
    assert u["roll"]["rms_deg"] < 2.6 and u["pitch"]["rms_deg"] < 2.1
    # a tuned filter on a matching simulation does far better than the seed's real flight
    assert u["roll"]["rms_deg"] < 0.5 and u["pitch"]["rms_deg"] < 0.5 and u["heading"]["rms_deg"] < 2.0
    assert max(u["pos_rms_ned_m"]) < 3.0


def test_smoother_better_than_ukf(report):
    # combined tilt (roll+pitch) and attitude RMS: per axis the smoother wins on most but not all simulated
    # flights (in 2 of 6 seeds one axis was slightly worse), combined it won on all six
    u, s = report["ukf"], report["smoother"]
    assert s["tilt_rms_deg"] < u["tilt_rms_deg"]
    assert s["attitude_rms_deg"] < u["attitude_rms_deg"]


def test_ukf_sigmas_are_honest(report):
    z = np.array(report["ukf_normalised_error_rms"])
    assert np.all(z[:2] > 0.3) and np.all(z[:2] < 2.0), z


def test_ukf_with_antenna_lever_arm():
    from dgcal.pos.lowcost.ukf import UkfOptions, run_ukf
    from dgcal.sim.lowcost_flight import _rph_error, gnss_fixes
    f = simulate_lowcost_flight(duration_s=75.0, rate_hz=50.0, seed=2)
    lever = np.array([0.3, -0.2, -0.4])
    fixes, _ = gnss_fixes(f.truth, 50.0, seed=3, lever_arm_b=lever)
    # the seed's 15 states (fixes taken as white)
    u = run_ukf(f.imu, fixes, f.imu_errors.grade, UkfOptions(lever_arm_b=lever, gnss_error_states=False))
    a = u.t > u.t[0] + 25.0
    e = _rph_error(f.truth, u.t[a], u.rph_deg[a])
    assert np.all(np.sqrt(np.mean(e[:, :2] ** 2, axis=0)) < 0.5)
    p_true = u.frame.from_ecef(f.truth.at(u.t[a]).p_ecef)
    assert np.sqrt(np.mean(np.sum((u.p_nav[a] - p_true) ** 2, axis=1))) < 3.0
    # the default adds the GNSS error states: the same attitude, and a position error its sigma accounts for (this
    # flight's GNSS errors average 3.3 m over the window, so no filter can be much closer)
    g = run_ukf(f.imu, fixes, f.imu_errors.grade, UkfOptions(lever_arm_b=lever))
    assert g.info["n_states"] == 18
    e = _rph_error(f.truth, g.t[a], g.rph_deg[a])
    assert np.all(np.sqrt(np.mean(e[:, :2] ** 2, axis=0)) < 0.5)
    z = (g.p_nav[a] - p_true) / g.sigma_p_nav[a]
    assert np.sqrt(np.mean(z ** 2)) < 2.0


def test_ukf_solution_as_trajectory_file(tmp_path):
    from dgcal.fields.io.formats import read_trajectory, write_trajectory
    from dgcal.pos.lowcost.ukf import run_ukf
    f = simulate_lowcost_flight(duration_s=40.0, rate_hz=50.0, seed=5)
    u = run_ukf(f.imu, f.fixes, f.imu_errors.grade)
    tr = u.to_trajectory()
    write_trajectory(tmp_path / "ukf.csv", tr)
    back = read_trajectory(tmp_path / "ukf.csv")
    assert np.allclose(back.t, u.t, atol=1e-6) and np.allclose(back.rph[:, :2], u.rph_deg[:, :2], atol=0.05)
    truth = f.truth.at(u.t)
    a = u.t > u.t[0] + 15
    assert np.abs(back.h[a] - truth.h[a]).max() < 5.0
    assert np.all(back.sigma[:, 3:] > 0)
