"""Projection uncertainty (mrcal's method) against the spread of re-calibrations over noise realisations, and the
same for a converted model."""
import numpy as np
import pytest

from dgcal.calib.camera.conversions import conversion_jacobian, fit_camera, to_opencv
from dgcal.calib.camera.models import Fraser7
from dgcal.calib.camera.region import ValidRegion
from dgcal.calib.selfcal.adjustment import adjust
from dgcal.calib.selfcal.uncertainty import (converted_uncertainty_map, mean_pose_covariance, projection_covariance,
                                             uncertainty_map, worst_sigma)
from dgcal.fields.targets.plate import TargetField
from dgcal.sim.camera_field import calibration_field_camera, plan_shots
from test_camera_ba_simulated import simulate_measurements

SIZE = (640, 480)
NOISE = 0.3
RANGE = 5.0


@pytest.fixture(scope="module")
def scene():
    truth = calibration_field_camera(SIZE)
    rng = np.random.default_rng(4)
    tf = TargetField(diameter_m=1.2, square_m=0.12, marker_m=0.09)
    pts = tf.points()
    shots = plan_shots(12, truth, tf, rng)
    return truth, pts, shots, rng


def nine_points():
    w, h = SIZE
    return np.array([[x, y] for y in (0.1 * h, 0.5 * h, 0.9 * h) for x in (0.1 * w, 0.5 * w, 0.9 * w)])


def test_sigma_agrees_with_the_spread_over_50_noise_realisations(scene):
    truth, pts, shots, rng = scene
    q = nine_points()
    d = truth.ray(q)
    by_name = {s.image: s for s in shots}
    pred = {"range": [], "inf": []}
    got = {"range": [], "inf": []}
    for _ in range(50):
        img, idx, xy = simulate_measurements(truth, pts.xyz, shots, NOISE, rng)
        r = adjust(pts.ids, pts.xyz, img, pts.ids[idx], xy, SIZE, "fraser7", initial=truth, reject_k=0)
        S = mean_pose_covariance(r)
        pred["range"].append(worst_sigma(projection_covariance(r.camera, S, q, RANGE)))
        pred["inf"].append(worst_sigma(projection_covariance(r.camera, S, q, None)))
        # the re-projection of the same world points through this solution's mean pose (mrcal's definition)
        pr, pi = np.zeros((9, 3)), np.zeros((9, 3))
        for i, name in enumerate(r.image_names):
            s = by_name[name]
            R_i, C_i = r.poses.R_world_to_cam[i], r.poses.C_world[i]
            pr += ((d * RANGE - s.t_field_to_cam) @ s.R_field_to_cam - C_i) @ R_i.T
            pi += (d @ s.R_field_to_cam) @ R_i.T
        got["range"].append(r.camera.project(pr / len(r.image_names)))
        got["inf"].append(r.camera.project(pi / len(r.image_names)))
    for k in ("range", "inf"):
        Q = np.array(got[k])                                          # (50, 9, 2)
        spread = np.array([worst_sigma(np.cov(Q[:, j].T)[None])[0] for j in range(9)])
        ratio = np.mean(pred[k], axis=0) / spread
        assert np.all((ratio > 0.8) & (ratio < 1.25)), (k, ratio)


def test_uncertainty_grows_outside_the_observed_region(scene):
    truth, pts, shots, rng = scene
    img, idx, xy = simulate_measurements(truth, pts.xyz, shots, NOISE, rng)
    keep = xy[:, 0] < 0.45 * SIZE[0]                     # observations only in the left 45 % of the frame
    r = adjust(pts.ids, pts.xyz, img[keep], pts.ids[idx][keep], xy[keep], SIZE, "fraser7", fixed=("B2",))
    u = uncertainty_map(r, RANGE, nx=16)
    region = ValidRegion.of(r.camera, r.obs_xy[r.used])
    grid = np.column_stack([g.ravel() for g in np.meshgrid(u.u, u.v)])
    inside = np.median(u.sigma_infinity.ravel()[region.contains(grid)])
    right = np.median(u.sigma_infinity[:, u.u > 0.9 * SIZE[0]])
    # the mean pose's rotation (common to the whole frame) dominates with 12 images; the extrapolated part adds to it
    assert right > 1.2 * inside, (inside, right)
    d = u.to_dict()
    assert np.array(d["sigma_px_at_infinity"]).shape == (len(u.v), len(u.u)) and d["range_m"] == RANGE


def test_converted_model_uncertainty(scene):
    truth, pts, shots, rng = scene
    img, idx, xy = simulate_measurements(truth, pts.xyz, shots, NOISE, rng)
    r = adjust(pts.ids, pts.xyz, img, pts.ids[idx], xy, SIZE, "fraser7")
    region = ValidRegion.of(r.camera, r.obs_xy[r.used])
    base = uncertainty_map(r, RANGE, nx=12)
    # an exact conversion (B2 = 0 copy, all parameters free) has the Jacobian identity and the same map
    G = conversion_jacobian(r.camera, r.camera.copy(), region=region)
    assert np.allclose(G, np.eye(10), atol=1e-6)
    # the OpenCV block of a skewed fraser7 (fitted, B2 held at 0) is as uncertain as the model it approximates
    ocv, err = to_opencv(r.camera, region)
    start = r.camera.copy()
    start.params[9] = 0.0
    fit, _ = fit_camera(r.camera, start, [k for k in Fraser7.PARAMS if k != "B2"], region=region)
    conv = converted_uncertainty_map(r, fit, [k for k in Fraser7.PARAMS if k != "B2"], region, RANGE, nx=12)
    inside = region.contains(np.column_stack([g.ravel() for g in np.meshgrid(base.u, base.v)]))
    a, b = base.sigma_range.ravel()[inside], conv.sigma_range.ravel()[inside]
    assert np.all(np.abs(b / a - 1) < 0.15), np.abs(b / a - 1).max()
