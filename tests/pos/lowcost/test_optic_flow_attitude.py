"""GNSS / optic-flow attitude (seed 001 eq. 9-12): FOE geometry, de-rotation, depth/AGL, and Table 2 on a
simulated 300 s flight with a rendered forward camera and OpenCV pyramidal Lucas-Kanade."""
import numpy as np
import pytest

from dgcal.fields.frames import R_body_to_ned_from_rph
from dgcal.pos.lowcost.optic_flow import (R_CAM_TO_BODY_FORWARD, depth_from_flow, focus_of_expansion, ground_homography,
                            height_above_ground, pitch_yaw_from_velocity)
from dgcal.sim.forward_camera import flow_attitude_study, format_table2, forward_camera, make_forward_camera_sim
from dgcal.fields.pose import so3_exp


def test_pitch_yaw_from_velocity_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        r, p, y = rng.uniform(-40, 40), rng.uniform(-20, 20), rng.uniform(0, 360)
        v_b = np.array([1.0, rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1)])
        v_ned = R_body_to_ned_from_rph(r, p, y) @ v_b * 25.0
        p2, y2 = pitch_yaw_from_velocity(v_b, v_ned, r)
        assert abs(p2 - p) < 1e-8 and abs((y2 - y + 180) % 360 - 180) < 1e-8


def _synthetic_pair(rng, rot_err=None, n=300, agl=60.0, noise_rad=0.0):
    """Rays of ground points in two forward-camera frames and the exact camera motion."""
    if rot_err is None:
        rot_err = np.zeros(3)
    R_c1 = R_body_to_ned_from_rph(5.0, 3.0, 40.0) @ R_CAM_TO_BODY_FORWARD
    dR = so3_exp(np.radians([0.3, -0.5, 1.0]))  # cam2 -> cam1
    T_ned = np.array([9.0, 8.0, -0.3])
    t_c = R_c1.T @ T_ned
    # ground points seen at depressions 10..45 deg
    d = np.column_stack([rng.uniform(-0.9, 0.9, n), rng.uniform(0.2, 0.95, n), np.ones(n)])
    d_ned = d @ R_c1.T
    keep = d_ned[:, 2] > np.sin(np.radians(10))
    d, d_ned = d[keep], d_ned[keep]
    P1 = d * (agl / d_ned[:, 2])[:, None]
    P2 = (P1 - t_c) @ dR  # in cam-2 axes: dR^T (P1 - t)
    d1 = P1 / np.linalg.norm(P1, axis=1, keepdims=True)
    d2 = P2 / np.linalg.norm(P2, axis=1, keepdims=True)
    d2 = d2 + rng.standard_normal(d2.shape) * noise_rad
    d2r = d2 @ (so3_exp(rot_err) @ dR).T  # de-rotated with a slightly wrong rotation
    return R_c1, dR, t_c, d1, d2r / np.linalg.norm(d2r, axis=1, keepdims=True), P1


def test_foe_exact_and_residual_rotation_recovered():
    rng = np.random.default_rng(1)
    R_c1, dR, t_c, d1, d2, P1 = _synthetic_pair(rng, rot_err=np.radians([0.05, -0.04, 0.3]))
    foe = focus_of_expansion(d1, d2)
    assert np.allclose(foe.e, t_c[:2] / t_c[2], atol=1e-7)
    # without estimating the rotation the small de-rotation error moves the FOE a lot
    foe0 = focus_of_expansion(d1, d2, estimate_rotation="")
    assert np.linalg.norm(foe0.e - t_c[:2] / t_c[2]) > 1e-3


def test_foe_sigma_is_honest_under_tracking_noise():
    z = []
    for k in range(30):
        rng = np.random.default_rng(100 + k)
        R_c1, dR, t_c, d1, d2, _ = _synthetic_pair(rng, noise_rad=0.1 / 150)  # 0.1 px at f = 150 px
        foe = focus_of_expansion(d1, d2)
        e = foe.e - t_c[:2] / t_c[2]
        z.append(e @ np.linalg.solve(foe.cov, e) / 2)
    assert 0.5 < np.sqrt(np.mean(z)) < 1.6


def test_depth_and_height_from_flow_are_exact():
    rng = np.random.default_rng(2)
    R_c1, dR, t_c, d1, d2, P1 = _synthetic_pair(rng, agl=73.0)
    base = np.linalg.norm(t_c)
    D = depth_from_flow(d1, d2, t_c / base, base)
    assert np.allclose(D, np.linalg.norm(P1, axis=1), rtol=1e-9)
    assert np.allclose(height_above_ground(D, d1 @ R_c1.T), 73.0, rtol=1e-9)


def test_ground_homography_maps_ground_points():
    rng = np.random.default_rng(3)
    cam = forward_camera(240, 90.0)
    R_c1, dR, t_c, d1, d2, P1 = _synthetic_pair(rng, agl=50.0)
    n_c1 = R_c1.T @ np.array([0.0, 0.0, 1.0])
    H = ground_homography(cam.pinhole_K(), dR, t_c, n_c1, 50.0)
    uv1 = cam.project(P1)
    uv2 = cam.project((P1 - t_c) @ dR)
    p = np.column_stack([uv1, np.ones(len(uv1))]) @ H.T
    assert np.abs(p[:, :2] / p[:, 2:3] - uv2).max() < 1e-6


@pytest.fixture(scope="module")
def table2():
    sim = make_forward_camera_sim(duration_s=300.0, image_px=240, seed=0)
    rep = flow_attitude_study(sim, pair_every_s=10.0, frame_dt=0.5, seed=0)
    print("\n" + format_table2(rep))
    return rep


def test_table2_attitude_errors(table2):
    t = table2["table2"]
    assert table2["n_pairs"] >= 20 and table2["duration_s"] >= 299.0
    for k in ("roll", "pitch", "yaw"):
        assert t[k]["std_deg"] <= 0.5, k
        assert abs(t[k]["mean_deg"]) < 0.25, k
    # the FOE removes the angle-of-attack and crab offsets of the pseudo attitude (3 deg and 4 deg here)
    assert abs(table2["pseudo_only"]["pitch_mean_deg"]) > 2.0 and abs(table2["pseudo_only"]["yaw_mean_deg"]) > 2.0
    # the FOE-only sigmas miss the pseudo-input errors and spatially correlated tracking errors; within 3x
    assert table2["normalised_error_rms"]["pitch"] < 3.0 and table2["normalised_error_rms"]["yaw"] < 3.0


def test_table2_height_above_ground(table2):
    a = table2["agl"]
    assert a["median_rel_error"] < 0.03 and abs(a["mean_error_m"]) < 2.0
