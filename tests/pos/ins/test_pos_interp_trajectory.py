"""Trajectory interpolation at events: accuracy against the simulator's exact truth, sigmas, errors."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dgcal.fields.constants import OMEGA_IE_E
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import Events, Trajectory, read_trajectory, write_trajectory
from dgcal.pos.ins.interpolate import TrajectoryInterpolator, interpolate_trajectory, trajectory_at_events
from dgcal.sim.trajectory import camera_events, simulate_true_trajectory


@pytest.fixture(scope="module")
def truth():
    return simulate_true_trajectory(heights_agl=(250.0,), n_strips=2, strip_length_m=600.0, rate_hz=100.0,
                                    duration_s=300.0)


def _sampled(truth, hz, sigma=None):
    k = np.arange(0, len(truth.t), int(round(truth.rate_hz / hz)))
    return Trajectory(t=truth.t[k], lat=truth.lat[k], lon=truth.lon[k], h=truth.h[k], v_ned=truth.v_ned[k],
                      rph=truth.rph[k], sigma=None if sigma is None else sigma[k])


def _angle_deg(Ra, Rb):
    return np.degrees(np.linalg.norm(Rotation.from_matrix(np.swapaxes(Ra, -1, -2) @ Rb).as_rotvec(), axis=-1))


def test_interpolation_matches_truth_between_samples(truth):
    rng = np.random.default_rng(2)
    tq = np.sort(rng.uniform(truth.t[0], truth.t[-1], 400))
    ref = truth.at(tq)
    for hz, pos_tol, method, att_tol in ((50.0, 1e-4, "cubic", 2e-4), (50.0, 1e-4, "slerp", 1e-2),
                                         (10.0, 5e-3, "cubic", 0.02), (10.0, 5e-3, "slerp", 0.2)):
        st = interpolate_trajectory(_sampled(truth, hz), tq, attitude=method)
        assert np.linalg.norm(st.p_ecef - ref.p_ecef, axis=1).max() < pos_tol
        assert _angle_deg(st.R_body_to_ned, ref.R_body_to_ned).max() < att_tol
        assert np.abs(st.v_ned - ref.v_ned).max() < 50 * pos_tol
        # on the straight strips both methods are exact to well below DG needs
        on = np.zeros(len(tq), bool)
        for s in truth.strips:
            on |= (tq > s.t_start + 1) & (tq < s.t_end - 1)
        assert _angle_deg(st.R_body_to_ned[on], ref.R_body_to_ned[on]).max() < 1e-4
    st = interpolate_trajectory(_sampled(truth, 50.0), tq)
    w_eb = ref.omega_ib_b - np.einsum("nji,j->ni", ref.R_body_to_ecef, OMEGA_IE_E)
    assert np.abs(st.omega_eb_b - w_eb).max() < 2e-3


def test_samples_reproduced_exactly(truth):
    tr = _sampled(truth, 20.0)
    st = interpolate_trajectory(tr, tr.t[5:50])
    assert _angle_deg(interpolate_trajectory(tr, tr.t[5:50], attitude="slerp").R_body_to_ned,
                      st.R_body_to_ned).max() < 1e-9
    np.testing.assert_allclose(st.lat, tr.lat[5:50], atol=1e-11)
    np.testing.assert_allclose(st.h, tr.h[5:50], atol=1e-6)
    d = (st.rph - tr.rph[5:50] + 180.0) % 360.0 - 180.0
    assert np.abs(d).max() < 1e-8


def test_sigma_and_covariance_interpolated_in_variance(truth):
    n = len(truth.t)
    sig = np.tile([0.1, 0.1, 0.2, 0.01, 0.01, 0.05], (n, 1)) * (1 + np.arange(n) / n)[:, None]
    tr = _sampled(truth, 10.0, sigma=sig)
    cov = np.einsum("ni,ij->nij", tr.sigma ** 2, np.eye(6))
    itp = TrajectoryInterpolator(tr, cov=cov)
    tm = 0.5 * (tr.t[10] + tr.t[11])
    st = itp([tm])
    expect = np.sqrt(0.5 * (tr.sigma[10] ** 2 + tr.sigma[11] ** 2))
    np.testing.assert_allclose(st.sigma[0], expect, rtol=1e-12)
    np.testing.assert_allclose(np.sqrt(np.diag(st.cov[0])), expect, rtol=1e-12)


def test_events_round_trip_through_csv(truth, tmp_path):
    ev = camera_events(truth, interval_s=2.0, delay_s=-0.1)
    tr = _sampled(truth, 50.0)
    rows = trajectory_at_events(tr, ev, delay_s=-0.1)
    assert list(rows.image) == list(ev.image)
    write_trajectory(tmp_path / "events.csv", rows)
    back = read_trajectory(tmp_path / "events.csv")
    ref = truth.at(ev.t - 0.1)
    np.testing.assert_allclose(back.lat, ref.lat, atol=1e-9)
    np.testing.assert_allclose(back.h, ref.h, atol=1e-3)
    d = (back.rph - ref.rph + 180.0) % 360.0 - 180.0
    assert np.abs(d).max() < 2e-3


def test_out_of_range_and_gap_name_the_event(truth, tmp_path):
    tr = _sampled(truth, 10.0)
    with pytest.raises(InputError, match="event IMG_9 .*outside the trajectory"):
        interpolate_trajectory(tr, [tr.t[3], tr.t[-1] + 1.0], names=["IMG_1", "IMG_9"])
    ev = Events(image=np.array(["A", "B"], dtype=object), t=np.array([tr.t[2], tr.t[0] - 5.0]),
                lines=np.array([2, 3]), path=tmp_path / "events.csv")
    with pytest.raises(InputError, match=r"events.csv:3: .*event B"):
        trajectory_at_events(tr, ev)
    keep = np.r_[0:20, 40:len(tr.t)]
    holey = Trajectory(t=tr.t[keep], lat=tr.lat[keep], lon=tr.lon[keep], h=tr.h[keep], v_ned=tr.v_ned[keep],
                       rph=tr.rph[keep])
    with pytest.raises(InputError, match="event X .*gap of 2.1"):
        interpolate_trajectory(holey, [tr.t[30]], names=["X"])
