"""Flight simulator: exact kinematics (strapdown integration of its IMU output reproduces it), plan geometry."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dgcal.fields.constants import OMEGA_IE_E
from dgcal.sim.strapdown import gravity_ecef, integrate_strapdown_ecef
from dgcal.sim.trajectory import camera_events, simulate_true_trajectory


@pytest.fixture(scope="module")
def flight():
    return simulate_true_trajectory(heights_agl=(300.0, 500.0), n_strips=3, strip_length_m=800.0, rate_hz=100.0)


def test_strapdown_of_noise_free_imu_reproduces_truth_10_min_200hz():
    tr = simulate_true_trajectory(heights_agl=(300.0,), n_strips=4, duration_s=600.0, rate_hz=200.0)
    assert tr.t[-1] - tr.t[0] == pytest.approx(600.0)
    assert np.ptp(tr.rph[:, 0]) > 40.0  # turns at +-25 deg bank were flown
    p, v, R = integrate_strapdown_ecef(tr.t, tr.dtheta, tr.dvel, tr.p_ecef[0], tr.v_ecef[0], tr.R_body_to_ecef[0])
    assert np.linalg.norm(p - tr.p_ecef, axis=1).max() < 0.002  # measured 0.11 mm
    assert np.abs(v - tr.v_ecef).max() < 1e-4
    dR = np.einsum("nji,njk->nik", R, tr.R_body_to_ecef)
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(dR).as_rotvec(), axis=1)).max() < 5e-5


def test_increments_are_interval_integrals(flight):
    # Simpson's rule on the exact state at both ends and the middle of each interval
    k = np.arange(1, len(flight.t), 7)
    mid = flight.at(flight.t[k] - 0.5 / flight.rate_hz)
    simpson_w = (flight.omega_ib_b[k - 1] + 4 * mid.omega_ib_b + flight.omega_ib_b[k]) / 6
    simpson_f = (flight.f_b[k - 1] + 4 * mid.f_b + flight.f_b[k]) / 6
    assert np.abs(flight.dtheta[k] * flight.rate_hz - simpson_w).max() < 1e-6
    assert np.abs(flight.dvel[k] * flight.rate_hz - simpson_f).max() < 1e-5


def test_plan_geometry_strips_heights_headings(flight):
    strips = flight.strips
    assert len(strips) == 6
    assert [s.height_agl for s in strips] == [300.0] * 3 + [500.0] * 3
    for s in strips:
        seg = flight.at(np.linspace(s.t_start, s.t_end, 20))
        assert np.abs(seg.rph[:, 0]).max() < 0.01  # wings level
        dh = (seg.rph[:, 2] - s.heading_deg + 180.0) % 360.0 - 180.0
        assert np.abs(dh).max() < 0.05
        assert np.abs(seg.h - (30.0 + s.height_agl)).max() < 0.2  # tangent-plane vs ellipsoidal height
        cross = seg.p_l[:, 1] - (s.index - 1) * 200.0
        assert np.abs(cross).max() < 2.0
        assert np.abs(np.abs(seg.p_l[[0, -1], 0]) - 400.0).max() < 0.5
    # successive strips at one height alternate heading; each line is flown both ways over the two heights
    hd = [s.heading_deg for s in strips]
    assert hd[0] != hd[1] and hd[1] != hd[2]
    by_line = {}
    for s in strips:
        by_line.setdefault(s.index, set()).add(s.heading_deg)
    assert all(len(v) == 2 for v in by_line.values())


def test_coordinated_turns_and_specific_force(flight):
    # coordinated flight: little lateral specific force; gravity plus centripetal along body z
    assert np.abs(flight.f_b[:, 1]).max() < 0.01
    bank = np.radians(flight.rph[:, 0])
    g = np.linalg.norm(gravity_ecef(flight.p_ecef), axis=1)
    level = (np.abs(flight.v_ned[:, 2]) < 1e-3) & (np.abs(np.gradient(flight.v_ned[:, 2]) * flight.rate_hz) < 1e-3)
    turning = (np.abs(bank) > np.radians(20)) & level
    assert turning.sum() > 1000
    np.testing.assert_allclose(-flight.f_b[turning, 2], g[turning] / np.cos(bank[turning]) * np.cos(np.radians(2.0)),
                               rtol=2e-3)
    # straight, level strips: the gyros sense the earth rate only
    s = flight.strips[0]
    k = (flight.t > s.t_start + 1) & (flight.t < s.t_end - 1)
    w_earth = np.einsum("nji,j->ni", flight.R_body_to_ecef[k], OMEGA_IE_E)
    assert np.abs(flight.omega_ib_b[k] - w_earth).max() < 1e-9


def test_at_matches_samples_and_velocity_is_position_rate(flight):
    k = np.arange(50, len(flight.t) - 1, 977)
    b = flight.at(flight.t[k][::-1])
    b_p = b.p_ecef[::-1]
    np.testing.assert_allclose(b_p, flight.p_ecef[k], atol=1e-6)
    np.testing.assert_allclose(b.rph[::-1], flight.rph[k], atol=1e-9)
    h = 0.05  # GPS seconds ~1.4e9 carry 0.24 us rounding; a 4th-order difference over +-0.1 s is exact enough
    p = [flight.at(flight.t[k] + m * h).p_ecef for m in (-2, -1, 1, 2)]
    fd = (p[0] - 8 * p[1] + 8 * p[2] - p[3]) / (12 * h)
    np.testing.assert_allclose(fd, flight.v_ecef[k], atol=1e-3)


def test_as_trajectory_csv_round_trip(flight, tmp_path):
    from dgcal.fields.io.formats import read_trajectory, write_trajectory
    write_trajectory(tmp_path / "truth.csv", flight.as_trajectory(step=100))
    back = read_trajectory(tmp_path / "truth.csv")
    np.testing.assert_allclose(back.t, flight.t[::100], atol=1e-6)
    np.testing.assert_allclose(back.lat, flight.lat[::100], atol=1e-10)
    np.testing.assert_allclose(back.v_ned, flight.v_ned[::100], atol=1e-4)


def test_camera_events_on_strips_with_delay(flight):
    ev = camera_events(flight, distance_m=100.0, delay_s=-0.14)
    t_exp = ev.t - 0.14
    assert len(ev.t) == 6 * 9
    inside = np.zeros(len(ev.t), bool)
    for s in flight.strips:
        inside |= (t_exp >= s.t_start - 1e-6) & (t_exp <= s.t_end + 1e-6)
    assert inside.all()
    d = np.linalg.norm(np.diff(flight.at(t_exp[:9]).p_l, axis=0), axis=1)
    np.testing.assert_allclose(d, 100.0, rtol=1e-6)
    assert len(set(ev.image)) == len(ev.image)


def test_multirotor_preset_and_duration():
    tr = simulate_true_trajectory(kind="multirotor", heights_agl=(80.0,), n_strips=2, strip_length_m=200.0,
                                  strip_spacing_m=40.0, rate_hz=50.0, duration_s=200.0)
    assert tr.t[-1] - tr.t[0] == pytest.approx(200.0)
    assert np.median(np.linalg.norm(tr.v_ned[:, :2], axis=1)) == pytest.approx(10.0, abs=0.1)
    assert tr.h.max() == pytest.approx(110.0, abs=0.5)
