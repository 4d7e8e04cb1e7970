"""Target refinement (free network with minimal datum, weighted by CSV sigmas) and non-planar fields."""
import numpy as np

from dgcal.calib.selfcal.diagnostics import projection_difference
from dgcal.calib.selfcal.adjustment import adjust
from dgcal.fields.targets.plate import TargetField, nonplanar_field
from dgcal.sim.camera_field import calibration_field_camera, plan_shots
from test_camera_ba_simulated import SIZE, simulate_measurements


def helmert_residual(a, b):
    """RMS (m) of b - (s R a + t) after the best similarity transform."""
    ca, cb = a.mean(0), b.mean(0)
    A, B = a - ca, b - cb
    U, S, Vt = np.linalg.svd(B.T @ A)
    D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / np.sum(A * A)
    return float(np.sqrt(np.mean(np.sum((B - s * A @ R.T) ** 2, axis=1))))


def warped_field_scene(seed=21):
    rng = np.random.default_rng(seed)
    tf = TargetField(square_m=0.16, marker_m=0.12)
    pts = tf.points()
    true_xyz = pts.xyz.copy()
    true_xyz[:, 2] += 0.004 * (true_xyz[:, 0] ** 2 + true_xyz[:, 1] ** 2) / 1.44   # 4 mm sag at the rim
    truth = calibration_field_camera(SIZE)
    shots = plan_shots(30, truth, tf, rng)
    img, idx, xy = simulate_measurements(truth, true_xyz, shots, 0.1, rng)
    nominal = pts.xyz * 1.002                                                    # printed 0.2 % large, flat
    return truth, pts.ids, nominal, true_xyz, img, pts.ids[idx], xy


def test_free_network_recovers_a_warped_plate():
    truth, ids, nominal, true_xyz, img, mid, xy = warped_field_scene()
    fixed_run = adjust(ids, nominal, img, mid, xy, SIZE, "fraser7")
    free_run = adjust(ids, nominal, img, mid, xy, SIZE, "fraser7", refine_targets="free")
    assert fixed_run.sigma0 > 2 * free_run.sigma0
    assert abs(free_run.sigma0 - 0.1) < 0.015
    rms_fixed, _, _ = projection_difference(truth, fixed_run.camera)
    rms_free, mx_free, _ = projection_difference(truth, free_run.camera)
    assert rms_free < 0.05 and rms_free < rms_fixed, (rms_free, rms_fixed)
    seen = np.isin(ids, mid)
    assert helmert_residual(free_run.points_xyz[seen], true_xyz[seen]) < 1e-4   # 0.1 mm after similarity
    # the datum: exactly 7 coordinates of observed targets held, every other one adjusted with a sigma
    assert np.sum(~free_run.points_free[seen]) == 7
    assert np.all(free_run.points_sigma[free_run.points_free] > 0)
    err = (free_run.camera.params - truth.params) / free_run.camera.sigmas
    assert np.all(np.abs(err) < 3.5), err


def test_weighted_targets_follow_their_sigmas():
    truth, ids, nominal, true_xyz, img, mid, xy = warped_field_scene(22)
    sig = np.tile([0.005, 0.005, 0.005], (len(ids), 1))   # 5 mm: loose enough to let the plate bend
    res = adjust(ids, nominal, img, mid, xy, SIZE, "fraser7", field_sigma=sig, refine_targets="weighted")
    assert abs(res.sigma0 - 0.1) < 0.015
    assert np.all(res.points_sigma[res.points_sigma > 0] < 0.005)
    assert helmert_residual(res.points_xyz, true_xyz) < 1e-4
    # refining targets costs precision: judge the camera by its own sigmas
    err = (res.camera.params - truth.params) / res.camera.sigmas
    assert np.all(np.abs(err) < 3.5), err
    tight = adjust(ids, nominal, img, mid, xy, SIZE, "fraser7", field_sigma=sig / 10, refine_targets="weighted")
    assert tight.sigma0 > 1.5 * res.sigma0  # 0.5 mm priors cannot absorb a 4 mm sag


def test_nonplanar_field_initialises_and_calibrates():
    rng = np.random.default_rng(31)
    tf = nonplanar_field(square_m=0.16, marker_m=0.12)
    pts = tf.points()
    assert np.ptp(pts.xyz[:, 2]) > 0.15
    truth = calibration_field_camera(SIZE)
    shots = plan_shots(30, truth, tf, rng)
    img, idx, xy = simulate_measurements(truth, pts.xyz, shots, 0.1, rng)
    res = adjust(pts.ids, pts.xyz, img, pts.ids[idx], xy, SIZE, "fraser7")
    rms, mx, _ = projection_difference(truth, res.camera)
    assert rms < 0.04 and mx < 0.12, (rms, mx)
    err = (res.camera.params - truth.params) / res.camera.sigmas
    assert np.all(np.abs(err) < 3.5), err
