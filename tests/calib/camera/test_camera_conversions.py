"""Round trips and independent cross-checks of every camera-model conversion."""
import numpy as np
import pytest

from dgcal.calib.camera import conversions as cc
from dgcal.calib.camera.models import Fraser7, OpenCV8
from dgcal.fields.errors import InputError

rng = np.random.default_rng(11)
SIZE = (6000, 4000)


def fraser(b2=0.8):
    return Fraser7(SIZE, [4000.0, 3010.0, 1985.0, -0.08, 0.05, -0.01, 2e-4, -1e-4, 1.5, b2])


def opencv8():
    return OpenCV8((6016, 4016), [2073.9, 2077.4, 3004.7, 1997.4, 0.8, 0.2, 1e-4, -2e-4, 0.01, 1.1, 0.35, 0.03])


def frame_points(cam, n=300):
    """Camera-frame points whose images fill the whole frame."""
    uv = np.column_stack([rng.uniform(0, cam.image_size[0] - 1, n), rng.uniform(0, cam.image_size[1] - 1, n)])
    return uv, cam.ray(uv) * rng.uniform(2, 20, (n, 1))


def test_fraser7_to_opencv_exact_without_skew_checked_by_cv2():
    import cv2
    cam = fraser(b2=0.0)
    d, err = cc.to_opencv(cam)
    assert err == 0.0
    uv, X = frame_points(cam)
    K, dist = cc.opencv_K_dist(d)
    uv_cv = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, dist)[0][:, 0]
    np.testing.assert_allclose(uv_cv, uv, atol=1e-6)
    back = cc.from_opencv(d, SIZE)
    np.testing.assert_allclose(back.params, cam.params, rtol=0, atol=1e-12)


def test_fraser7_with_skew_is_fitted_and_the_reported_error_is_honest():
    import cv2
    cam = fraser(b2=0.8)
    d, err = cc.to_opencv(cam)
    assert 0.05 < err < 1.0  # a 0.8 px skew cannot be held by OpenCV's model
    uv, X = frame_points(cam, 2000)
    K, dist = cc.opencv_K_dist(d)
    uv_cv = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, dist)[0][:, 0]
    actual = np.linalg.norm(uv_cv - uv, axis=1).max()
    assert actual <= err * 1.05 + 1e-6       # never worse than reported
    assert actual >= err * 0.7               # and the report is not wildly pessimistic


def test_opencv8_round_trip_exact():
    cam = opencv8()
    d, err = cc.to_opencv(cam)
    assert err == 0.0 and set(d) == set(cc.OPENCV8_KEYS)
    back = cc.from_opencv(d, cam.image_size)
    assert back.NAME == "opencv8"
    np.testing.assert_array_equal(back.params, cam.params)
    with pytest.raises(InputError, match="k4"):
        cc.from_opencv(d, cam.image_size, "fraser7")
    with pytest.raises(InputError, match="fy"):
        cc.from_opencv({"fx": 1.0, "cx": 0, "cy": 0}, (10, 10))


@pytest.mark.parametrize("cam", [fraser(b2=0.0), opencv8(),
                                 Fraser7(SIZE, [4000.0, 3010.0, 1985.0, -0.08, 0.05, 0.0, 2e-4, -1e-4, 1.5, 0])],
                         ids=["fraser7", "opencv8", "fraser7-noK3"])
def test_colmap_matches_pycolmap_with_half_pixel_shift(cam):
    import pycolmap
    name, params, err = cc.to_colmap(cam)
    assert err == 0.0
    assert name == ("OPENCV" if cam.NAME == "fraser7" and cam["K3"] == 0 else "FULL_OPENCV")
    pc = pycolmap.Camera(model=name, width=cam.image_size[0], height=cam.image_size[1], params=params)
    uv, X = frame_points(cam)
    uv_colmap = pc.img_from_cam(X)
    np.testing.assert_allclose(uv_colmap - 0.5, uv, atol=1e-6)  # COLMAP's pixel centres sit at +0.5
    back = cc.from_colmap(name, cam.image_size[0], cam.image_size[1], params, cam.NAME)
    np.testing.assert_allclose(back.project(X), uv, atol=1e-6)


def test_colmap_simple_models_and_errors():
    cam = cc.from_colmap("SIMPLE_RADIAL", 100, 80, [90.0, 50.0, 40.0, -0.1])
    assert cam.NAME == "fraser7" and cam["cx"] == 49.5 and cam["K1"] == -0.1 and cam["B1"] == 0
    with pytest.raises(InputError, match="not supported"):
        cc.from_colmap("FISHEYE", 100, 80, [1, 2, 3])
    with pytest.raises(InputError, match="needs 4 params"):
        cc.from_colmap("PINHOLE", 100, 80, [1, 2, 3])


def metashape_reference(values, size, X):
    """Metashape's documented frame model (manual, appendix C), pixel origin at the top-left corner."""
    g = {k: values.get(k, 0.0) for k in cc.METASHAPE_KEYS}
    x, y = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2]
    r2 = x * x + y * y
    rad = 1 + g["k1"] * r2 + g["k2"] * r2**2 + g["k3"] * r2**3 + g["k4"] * r2**4
    xd = x * rad + (g["p1"] * (r2 + 2 * x * x) + 2 * g["p2"] * x * y) * (1 + g["p3"] * r2 + g["p4"] * r2**2)
    yd = y * rad + (g["p2"] * (r2 + 2 * y * y) + 2 * g["p1"] * x * y) * (1 + g["p3"] * r2 + g["p4"] * r2**2)
    u = size[0] * 0.5 + g["cx"] + xd * g["f"] + xd * g["b1"] + yd * g["b2"]
    v = size[1] * 0.5 + g["cy"] + yd * g["f"]
    return np.column_stack([u, v]) - 0.5  # to dgcal's pixel-centre origin


def test_metashape_exact_round_trip_with_p1_p2_swap():
    cam = fraser(b2=0.8)
    d, err = cc.to_metashape(cam)
    assert err == 0.0
    assert d["p1"] == cam["P2"] and d["p2"] == cam["P1"]
    assert d["cx"] == pytest.approx(cam["cx"] - 2999.5) and d["cy"] == pytest.approx(cam["cy"] - 1999.5)
    uv, X = frame_points(cam)
    np.testing.assert_allclose(metashape_reference(d, SIZE, X), uv, atol=1e-6)
    back, err = cc.from_metashape(d, SIZE)
    assert err == 0.0
    np.testing.assert_allclose(back.params, cam.params, rtol=1e-13, atol=1e-13)


def test_metashape_with_k4_p3_is_fitted():
    d = dict(cc.to_metashape(fraser())[0], k4=0.003, p3=0.5)
    cam, err = cc.from_metashape(d, SIZE)
    uv, X = frame_points(cam, 1000)
    actual = np.linalg.norm(cam.project(X) - metashape_reference(d, SIZE, X), axis=1).max()
    assert err < 2.0 and actual <= err * 1.05 + 1e-6


def test_opencv8_to_metashape_is_a_reported_fit():
    d, err = cc.to_metashape(opencv8())
    assert err > 20  # a 110 degree lens does not fit the polynomial model: say so, do not hide it


@pytest.mark.parametrize("pixel_size", [None, 0.0039])
def test_australis_both_directions(pixel_size):
    cam = fraser(b2=0.8)
    aus, err = cc.to_australis(cam, pixel_size_mm=pixel_size)
    assert err < 0.5
    uv, X = frame_points(cam, 1000)
    # the correction model maps measured pixels to ideal rays directly
    ideal = X[:, :2] / X[:, 2:3]
    f = cam["f"]
    assert np.abs(aus.correct(uv) - ideal).max() * f < 1.5 * err + 1e-6
    np.testing.assert_allclose(aus.project(X), cam.project(X), atol=err * 1.05 + 1e-6)
    if pixel_size is not None:
        assert aus["c"] == pytest.approx(cam["f"] * pixel_size, rel=1e-3)  # principal distance in mm
        assert cc.max_projection_difference(aus, aus.with_pixel_size(None)) < 1e-6
    back, err2 = cc.from_australis(aus)
    np.testing.assert_allclose(back.project(X), aus.project(X), atol=err2 * 1.05 + 1e-6)
    assert cc.max_projection_difference(cam, back) < err + err2 + 1e-6
    # parameters survive the double trip to within the fit residual
    assert back["f"] == pytest.approx(cam["f"], abs=1.0) and back["K1"] == pytest.approx(cam["K1"], rel=0.02)


def test_australis_sign_conventions_on_a_mild_lens():
    """Small pure radial distortion: Australis' inverse K1 is about -K1/c^2 and y points up."""
    cam = Fraser7((4000, 3000), [3000.0, 2010.0, 1489.5, -0.02, 0, 0, 0, 0, 0, 0])
    aus, err = cc.to_australis(cam)
    assert err < 0.02
    assert aus["K1"] == pytest.approx(0.02 / 3000.0**2, rel=0.05)
    # principal point 10.5 px right of and 10 px above the centre (photogrammetric y points up)
    assert aus["xp"] == pytest.approx(10.5, abs=0.05) and aus["yp"] == pytest.approx(10.0, abs=0.05)
