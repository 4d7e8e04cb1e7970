"""gcp_datum_step: a block moved off its control points by a known similarity is moved back, with honest sigmas."""
import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.bundle.datum_check import gcp_datum_step
from dgcal.calib.camera.models import Fraser7


def _block(rng):
    cam = Fraser7((1200, 800), np.array([1000.0, 600, 400, -0.05, 0.01, 0, 0, 0, 0, 0]))
    C = np.array([[x, y, 30.0] for x in (-10.0, 0, 10) for y in (-5.0, 5)])
    R_cam_to_world = np.array([Rotation.from_euler("xyz", [180 + rng.normal(0, 2), rng.normal(0, 2), rng.normal(0, 5)],
                                              degrees=True).as_matrix() for _ in C])
    X = np.column_stack([rng.uniform(-15, 15, 12), rng.uniform(-10, 10, 12), rng.uniform(-1, 1, 12)])
    k, Xo, uv = [], [], []
    for i in range(len(C)):
        Xc = (X - C[i]) @ R_cam_to_world[i]
        p = cam.project(Xc)
        vis = (Xc[:, 2] > 0) & (p[:, 0] > 0) & (p[:, 0] < 1200) & (p[:, 1] > 0) & (p[:, 1] < 800)
        k += [i] * int(vis.sum())
        Xo.append(X[vis])
        uv.append(p[vis])
    return cam, R_cam_to_world, C, np.array(k), np.vstack(Xo), np.vstack(uv)


def test_known_similarity_is_undone():
    rng = np.random.default_rng(3)
    cam, R, C, k, X, uv = _block(rng)
    rv, t, ls = np.radians([0.3, -0.2, 0.4]), np.array([0.05, -0.03, 0.02]), 0.002
    R_s = Rotation.from_rotvec(rv).as_matrix()
    c = C.mean(0)
    C_off = c + np.exp(ls) * (C - c) @ R_s.T + t
    R_off = np.einsum("ij,njk->nik", R_s, R)
    step = gcp_datum_step(cam, R_off, C_off, k, X, uv)
    assert np.abs(step.C_world - C).max() < 1e-6
    for a, b in zip(step.R_cam_to_world, R):
        assert Rotation.from_matrix(a.T @ b).magnitude() < 1e-8
    assert step.rms_after_px < 1e-6 < step.rms_before_px
    assert gcp_datum_step(cam, R, C, k, X, uv).angle_deg < 1e-8


def test_step_sigmas_are_honest():
    rng = np.random.default_rng(5)
    cam, R, C, k, X, uv0 = _block(rng)
    chi2 = [gcp_datum_step(cam, R, C, k, X, uv0 + rng.normal(0, 0.5, uv0.shape), 0.5).chi2 for _ in range(40)]
    # a block at the true datum with 0.5 px noise: the step is noise, chi2(7) on average 7
    assert 4.5 < np.mean(chi2) < 10.0
