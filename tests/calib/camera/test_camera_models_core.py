import numpy as np
import pytest

from dgcal.calib.camera.models import Fraser7, OpenCV8, model_class
from dgcal.fields.errors import InputError

rng = np.random.default_rng(2)


def fraser():
    return Fraser7((6000, 4000), [4000.0, 3010.0, 1985.0, -0.08, 0.05, -0.01, 2e-4, -1e-4, 1.5, 0.8])


def test_fraser7_project_unproject_round_trip():
    cam = fraser()
    uv = np.column_stack([rng.uniform(0, 6000, 500), rng.uniform(0, 4000, 500)])
    rays = cam.ray(uv)
    np.testing.assert_allclose(cam.project(rays * 7.0), uv, atol=1e-8)


def test_opencv8_matches_cv2():
    import cv2
    cam = OpenCV8((6016, 4016), [2073.9, 2077.4, 3004.7, 1997.4, 0.8, 0.2, 1e-4, -2e-4, 0.01, 1.1, 0.35, 0.03])
    X = np.column_stack([rng.uniform(-2, 2, 100), rng.uniform(-1.5, 1.5, 100), rng.uniform(1, 3, 100)])
    K = cam.pinhole_K()
    d = cam.params[4:]
    uv_cv, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, d)
    np.testing.assert_allclose(cam.project(X), uv_cv[:, 0], atol=1e-6)
    np.testing.assert_allclose(cam.project(cam.ray(cam.project(X))), cam.project(X), atol=1e-7)


def test_fraser7_equals_opencv5_when_b2_zero():
    import cv2
    p = fraser().params.copy()
    p[9] = 0.0
    cam = Fraser7((6000, 4000), p)
    f, cx, cy, k1, k2, k3, p1, p2, b1, _ = p
    K = np.array([[f + b1, 0, cx], [0, f, cy], [0, 0, 1]])
    X = np.column_stack([rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50), rng.uniform(1, 2, 50)])
    uv_cv, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, np.array([k1, k2, p1, p2, k3]))
    np.testing.assert_allclose(cam.project(X), uv_cv[:, 0], atol=1e-8)


def test_distort_jacobian_numeric():
    for cam in (fraser(), OpenCV8((100, 100), [1, 1, 0, 0, 0.1, -0.05, 0.01, -0.02, 0.003, 0.2, 0.01, 0.002])):
        xy = rng.uniform(-0.6, 0.6, (20, 2))
        J = cam.distort_jacobian(xy)
        h = 1e-7
        for j in range(2):
            d = np.zeros(2)
            d[j] = h
            num = (cam.distort(xy + d) - cam.distort(xy - d)) / (2 * h)
            np.testing.assert_allclose(J[:, :, j], num, atol=1e-6)


def test_bad_model_and_params():
    with pytest.raises(InputError, match="unknown camera model"):
        model_class("pinhole9")
    with pytest.raises(InputError, match="needs 10 parameters"):
        Fraser7((10, 10), [1.0, 2.0])
