import numpy as np
import pytest

from dgcal.calib.camera.models import Fraser7, OpenCV8

rng = np.random.default_rng(7)


def models():
    return [
        Fraser7((6000, 4000), [4000.0, 3010.0, 1985.0, -0.08, 0.05, -0.01, 2e-4, -1e-4, 1.5, 0.8]),
        OpenCV8((6016, 4016), [2073.9, 2077.4, 3004.7, 1997.4, 0.8, 0.2, 1e-4, -2e-4, 0.01, 1.1, 0.35, 0.03]),
    ]


def points(n=40):
    return np.column_stack([rng.uniform(-1.2, 1.2, n), rng.uniform(-0.8, 0.8, n), rng.uniform(1.5, 4, n)])


@pytest.mark.parametrize("cam", models(), ids=lambda c: c.NAME)
def test_project_with_jacobians_matches_finite_differences(cam):
    X = points()
    uv, J_p, J_X = cam.project_with_jacobians(X)
    P = len(cam.PARAMS)
    assert uv.shape == (40, 2) and J_p.shape == (40, 2, P) and J_X.shape == (40, 2, 3)
    np.testing.assert_allclose(uv, cam.project(X), atol=1e-12)
    for j in range(P):
        h = 1e-6 * max(1.0, abs(cam.params[j]))
        cp, cm = cam.copy(), cam.copy()
        cp.params[j] += h
        cm.params[j] -= h
        num = (cp.project(X) - cm.project(X)) / (2 * h)
        np.testing.assert_allclose(J_p[:, :, j], num, rtol=1e-5, atol=1e-5 * np.abs(num).max() + 1e-9,
                                   err_msg=cam.PARAMS[j])
    for j in range(3):
        d = np.zeros(3)
        d[j] = 1e-6
        num = (cam.project(X + d) - cam.project(X - d)) / 2e-6
        np.testing.assert_allclose(J_X[:, :, j], num, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("cam", models(), ids=lambda c: c.NAME)
def test_undistortion_maps_invert_undistort_points(cam):
    K_new = cam.pinhole_K() * np.array([[0.8, 1, 1], [1, 0.8, 1], [1, 1, 1]])
    map_x, map_y = cam.undistortion_maps(K_new, size=(300, 200))
    assert map_x.shape == (200, 300) and map_x.dtype == np.float32
    # the ideal image pixel (c, r) maps to distorted (map_x, map_y); undistorting that must give (c, r)
    r, c = rng.integers(0, 200, 30), rng.integers(0, 300, 30)
    uvd = np.column_stack([map_x[r, c], map_y[r, c]]).astype(float)
    back = cam.undistort_points(uvd, K_new)
    np.testing.assert_allclose(back, np.column_stack([c, r]), atol=2e-3)  # float32 map precision


def test_undistort_image_straightens_a_line():
    cam = Fraser7((400, 300), [300.0, 199.5, 149.5, -0.25, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0])
    # draw an ideal straight horizontal line at v=40 into a distorted image by forward projection
    u = np.linspace(20, 380, 2000)
    ideal = np.column_stack([u, np.full_like(u, 40.0)])
    xy = (ideal - cam.pinhole_K()[:2, 2]) / 300.0
    uvd = cam.to_pixels(cam.distort(xy))
    img = np.zeros((300, 400), np.uint8)
    ij = np.round(uvd).astype(int)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < 400) & (ij[:, 1] >= 0) & (ij[:, 1] < 300)
    img[ij[ok, 1], ij[ok, 0]] = 255
    assert np.ptp(ij[ok, 1]) > 5  # visibly curved before
    out = cam.undistort_image(img)
    rows = np.nonzero(out[:, 60:340].max(axis=1) > 60)[0]
    assert rows.min() >= 38 and rows.max() <= 42


def test_undistortion_maps_opencv_path_equals_numpy_path():
    cam = Fraser7((600, 400), [400.0, 301.0, 198.5, -0.08, 0.05, -0.01, 2e-4, -1e-4, 1.5, 0.0])
    K_new = np.array([[350.0, 0, 300], [0, 350, 200], [0, 0, 1]])
    fast = cam.undistortion_maps(K_new)          # exactly OpenCV's model: cv2.initUndistortRectifyMap
    cam.opencv_K_dist = lambda: None              # force the NumPy path used for skewed cameras
    slow = cam.undistortion_maps(K_new, rows_per_block=37)
    np.testing.assert_allclose(fast[0], slow[0], atol=1e-3)
    np.testing.assert_allclose(fast[1], slow[1], atol=1e-3)
