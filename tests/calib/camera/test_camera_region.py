"""The valid region of a camera model (monotonic and observed) and conversions fitted only inside it: the webcam
case of issue 14 (a polynomial folding in frame corners no observation reached) gives a sane OpenCV block, its
error is honest, and exports carry the region and, above 1 px, a warning."""
import json

import numpy as np

from dgcal.calib.camera.conversions import from_opencv, max_projection_difference, to_opencv
from dgcal.calib.camera.files import (camera_json_dict, load_camera, opencv_yaml_string,
                                      write_camera_json, write_colmap_cameras_txt, write_metashape_xml,
                                      write_opencv_yaml)
from dgcal.calib.camera.models import Fraser7
from dgcal.calib.camera.region import ValidRegion, convex_hull

# fraser7 fitted to a small board in a webcam frame (issue 14): strong K3, skew, a fold inside the frame
WEBCAM = Fraser7((1280, 720), [882.8, 635.4, 377.7, -0.373, 0.132, -0.56, 6e-5, -0.0102, -6.6, -1.9])


def observed_patch(cam, n=200, seed=0):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(230, 640, n), rng.uniform(230, 650, n)])


def test_monotonic_region_stops_at_the_fold():
    reg = ValidRegion.of(WEBCAM)
    assert not reg.whole_frame_monotonic
    frac = reg.fractions()["monotonic"]
    assert 0.2 < frac < 0.99, frac
    # along rays from the principal point the distorted radius grows up to the boundary and turns back beyond
    c = WEBCAM.pinhole_K()[:2, 2]
    for p in reg.monotonic[::15]:
        e = (p - c) / np.linalg.norm(p - c)
        r_px = np.linalg.norm(p - c)
        rays = [WEBCAM.ray((c + e * k * r_px)[None])[0] for k in (0.3, 0.6, 0.9)]
        radii = [np.hypot(*(r[:2] / r[2])) for r in rays]
        assert radii[0] < radii[1] < radii[2]          # inside: one ray per pixel, in order
    assert reg.in_monotonic(c[None])[0] and not reg.in_monotonic(np.array([[0.0, 0.0]]))[0]


def test_conversion_inside_the_valid_region_is_sane_and_honest():
    region = ValidRegion.of(WEBCAM, observed_patch(WEBCAM))
    assert region.fractions()["valid"] < 0.3
    whole, err_whole = to_opencv(WEBCAM)
    inside, err = to_opencv(WEBCAM, region)
    # over the whole frame the fit runs through the fold (the garbage of the issue); inside the region it is exact
    assert err_whole > 100 * err and err < 1.0
    assert abs(inside["fx"] / (882.8 - 6.6) - 1) < 0.01 and abs(inside["cx"] - 635.4) < 3
    block = from_opencv(inside, WEBCAM.image_size)
    rng = np.random.default_rng(5)
    uv = np.column_stack([rng.uniform(0, 1279, 20000), rng.uniform(0, 719, 20000)])
    uv = uv[region.contains(uv)]
    real = np.max(np.linalg.norm(block.project(WEBCAM.ray(uv)) - uv, axis=1))
    assert real <= 1.05 * err + 0.005, (real, err)          # the reported error is not exceeded inside
    assert max_projection_difference(WEBCAM, block, region=region) <= err + 1e-9


def test_region_json_round_trip_and_hull():
    uv = observed_patch(WEBCAM)
    hull = convex_hull(uv)
    assert len(hull) >= 4 and np.all(ValidRegion(WEBCAM.image_size, np.zeros(2), hull, True, hull).in_observed(uv,
                                                                                                                1e-9))
    reg = ValidRegion.of(WEBCAM, uv)
    back = ValidRegion.from_dict(json.loads(json.dumps(reg.to_dict())), WEBCAM.image_size)
    probe = np.random.default_rng(2).uniform(0, 700, (500, 2))
    assert np.array_equal(back.contains(probe), reg.contains(probe))


def test_exports_carry_the_region_and_warn_above_1px(tmp_path):
    region = ValidRegion.of(WEBCAM, observed_patch(WEBCAM))
    d = camera_json_dict(WEBCAM, stats={"rms_px": 0.3}, region=region)
    assert d["valid_region"]["valid_fraction"] < 0.3 and d["opencv_max_error_px"] < 1.0
    assert d["opencv_max_error_frame_px"] > 10 and "opencv_warning" not in d
    text, _ = opencv_yaml_string(WEBCAM, region)
    assert "# valid region:" in text and "WARNING" not in text
    # a skew the 5-coefficient model cannot follow over a wide region: a warning in the file
    skewed = WEBCAM.copy()
    skewed.params[9] = 12.0
    wide = ValidRegion.of(skewed, np.array([[0, 0], [1279, 0], [1279, 719], [0, 719]], float))
    d2 = camera_json_dict(skewed, region=wide)
    assert d2["opencv_max_error_px"] > 1 and "approximation" in d2["opencv_warning"]
    text2, err2 = opencv_yaml_string(skewed, wide)
    assert "WARNING" in text2 and err2 > 1
    # every export reads back (comments do not disturb the readers)
    write_opencv_yaml(tmp_path / "o.yaml", WEBCAM, region)
    write_colmap_cameras_txt(tmp_path / "cameras.txt", WEBCAM, region=region)
    write_metashape_xml(tmp_path / "m.xml", WEBCAM, region)
    write_camera_json(tmp_path / "c.json", WEBCAM)
    for name in ("o.yaml", "cameras.txt"):
        cam = load_camera(tmp_path / name)
        assert max_projection_difference(WEBCAM, cam, region=region) < 1.0, name
    assert "valid region" in (tmp_path / "m.xml").read_text()
    assert np.allclose(load_camera(tmp_path / "m.xml").params, WEBCAM.params)
