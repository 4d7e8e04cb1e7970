"""A flat board's bow (`--refine-targets warp`, `BoardWarp`): two unknowns, mrcal's model. Simulated bowed boards
give the bow and an honest camera back; on mrcal's own figueroa data with its outlier set dgcal reproduces mrcal's
solution (the bow to 0.1 %, focal length and principal point within a quarter of their sigmas, the projection to
0.05 px); the engine's warp Jacobian is the numerical one."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from dgcal.bundle.solver.blocks import BoardWarp, ImageObservations, State
from dgcal.calib.camera.files import load_camera
from dgcal.calib.selfcal.adjustment import adjust, board_warp
from dgcal.calib.selfcal.diagnostics import projection_difference
from dgcal.cli import main
from dgcal.fields.errors import InputError
from dgcal.fields.pose import Poses
from dgcal.fields.targets.plate import TargetField, nonplanar_field
from dgcal.sim.camera_field import calibration_field_camera, plan_shots
from test_camera_ba_simulated import SIZE, simulate_measurements

WARP_M = np.array([-0.0010, 0.0005])        # mrcal's figueroa board: 1.0 mm and 0.5 mm


def bowed_scene(seed: int):
    rng = np.random.default_rng(seed)
    tf = TargetField(square_m=0.16, marker_m=0.12)
    pts = tf.points()
    flat = pts.xyz.copy()
    R = np.eye(3)
    warp = board_warp(flat, R, 0)
    true_xyz = warp.points(flat, WARP_M)
    truth = calibration_field_camera(SIZE)
    shots = plan_shots(30, truth, tf, rng)
    img, idx, xy = simulate_measurements(truth, true_xyz, shots, 0.1, rng)
    return truth, pts.ids, flat, img, pts.ids[idx], xy


def test_bow_recovered_and_camera_sigmas_honest():
    z_cam, z_warp = [], []
    for seed in (31, 32, 33):
        truth, ids, flat, img, mid, xy = bowed_scene(seed)
        res = adjust(ids, flat, img, mid, xy, SIZE, "fraser7", refine_targets="warp")
        assert abs(res.sigma0 - 0.1) < 0.015, res.sigma0
        z_warp.append((res.board_warp_m - WARP_M) / res.board_warp_sigma_m)
        z_cam.append((res.camera.params - truth.params) / res.camera.sigmas)
        flat_run = adjust(ids, flat, img, mid, xy, SIZE, "fraser7")
        # the bow a flat model lacks: a worse fit and a camera farther from the truth than its sigmas allow
        assert flat_run.sigma0 > 1.5 * res.sigma0
        rms_warp = projection_difference(truth, res.camera)[0]
        rms_flat = projection_difference(truth, flat_run.camera)[0]
        assert rms_warp < 0.5 * rms_flat, (rms_warp, rms_flat)
        # the targets as bowed are the result's (a refit holds them there)
        np.testing.assert_allclose(res.points_xyz, board_warp(flat, np.eye(3), 0).points(flat, res.board_warp_m))
    z_cam, z_warp = np.array(z_cam), np.array(z_warp)
    assert np.all(np.abs(z_warp) < 3.5) and np.all(np.abs(z_cam) < 3.5), (z_warp, z_cam)
    assert 0.5 < np.sqrt(np.mean(np.r_[z_cam.ravel(), z_warp.ravel()] ** 2)) < 1.5


def test_warp_of_a_non_planar_field_is_refused():
    rng = np.random.default_rng(5)
    tf = nonplanar_field(square_m=0.16, marker_m=0.12)
    pts = tf.points()
    truth = calibration_field_camera(SIZE)
    shots = plan_shots(12, truth, tf, rng)
    img, idx, xy = simulate_measurements(truth, pts.xyz, shots, 0.1, rng)
    with pytest.raises(InputError, match="not planar"):
        adjust(pts.ids, pts.xyz, img, pts.ids[idx], xy, SIZE, "fraser7", refine_targets="warp")


def test_engine_warp_jacobian_is_the_numerical_one():
    rng = np.random.default_rng(2)
    truth = calibration_field_camera(SIZE)
    flat = np.c_[rng.uniform(-0.5, 0.5, (40, 2)), np.zeros(40)]
    P = len(truth.params)
    warp = BoardWarp(board_warp(flat, np.eye(3), 0).shape, np.array([0.0, 0.0, 1.0]), np.array([P, P + 1]))
    R = np.tile(np.diag([1.0, -1.0, -1.0]), (2, 1, 1))            # looking down at the board from 2 m
    C = np.array([[0.1, 0.0, 2.0], [-0.2, 0.1, 2.2]])
    pose, point = np.repeat([0, 1], 40), np.tile(np.arange(40), 2)
    g = np.r_[truth.params, 0.002, -0.001]
    state = State(Poses(R, C), flat.copy(), g)
    blk = ImageObservations(truth, pose, point, np.zeros((80, 2)), np.full((80, 2), 0.5), truth.PARAMS, 0,
                            points_fixed=True, warp=warp)
    ev = blk.evaluate(state, True)
    k = list(ev.glob).index(warp.glob[0])
    for j in range(2):
        h = 1e-6
        sp = State(state.poses, state.points, g.copy())
        sp.globals[warp.glob[j]] += h
        num = (blk.evaluate(sp, False).r - ev.r) / h
        np.testing.assert_allclose(ev.J_glob[:, :, k + j], num, rtol=1e-4, atol=1e-6)


def test_mrcal_figueroa_reproduced_with_its_outliers(shared_data, tmp_path, capsys):
    """Same data, same model (opencv8), same outlier set (`--reject 0`: mrcal's are already out of the file), the
    bow estimated: mrcal's answer to within a quarter of the sigmas."""
    d = shared_data / "mrcal-figueroa"
    out = tmp_path / "warp"
    assert main(["camera", "--field", str(d / "field.csv"), "--measurements", str(d / "measurements.csv"),
                 "--image-size", "6016", "4016", "--model", "opencv8", "--refine-targets", "warp", "--reject", "0",
                 "--no-report", "--out", str(out)]) == 0
    capsys.readouterr()
    cj = json.loads((out / "camera.json").read_text())
    ref = json.loads((d / "reference.json").read_text())
    bw = cj["board_warp"]
    np.testing.assert_allclose(bw["warp_m"], ref["board_warp"], rtol=1e-3)
    assert bw["significant"] and max(bw["sigma_m"]) < 1e-5
    for k in ("fx", "fy", "cx", "cy"):
        assert abs(cj["opencv"][k] - ref[k]) < 0.25 * cj["sigmas"][k], k
    # the rational coefficients trade with one another: compare what they do, the projection over the frame's
    # central 80 %, against dgcal's own projection sigma there
    cam = load_camera(out / "camera.json")
    u, v = np.meshgrid(np.linspace(0.1, 0.9, 17) * 6016, np.linspace(0.1, 0.9, 13) * 4016)
    uv = np.c_[u.ravel(), v.ravel()]
    K = np.array([[ref["fx"], 0, ref["cx"]], [0, ref["fy"], ref["cy"]], [0, 0, 1.0]])
    p, _ = cv2.projectPoints(cam.ray(uv).reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                             np.array(ref["dist_k1_k2_p1_p2_k3_k4_k5_k6"]))
    diff = np.linalg.norm(p.reshape(-1, 2) - uv, axis=1)
    sigma = cj["projection_uncertainty"]["model"]["sigma_px_at_infinity"]
    assert diff.max() < 0.05 and np.median(diff) < 0.5 * np.median(sigma), (diff.max(), np.median(sigma))
