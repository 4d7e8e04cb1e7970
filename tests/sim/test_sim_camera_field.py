"""The camera-field simulator: exact rendering geometry, truth files, frame coverage, non-planar plate."""
import json

import numpy as np
import pytest

from dgcal.calib.selfcal.detection import detect_folder
from dgcal.fields.io.csv_tables import read_table
from dgcal.fields.io.formats import read_points
from dgcal.fields.targets.plate import TargetField, nonplanar_field
from dgcal.sim.camera_field import calibration_field_camera, plan_shots, field_facets, truth_projections
from dgcal.sim.render import Facet, render


def _look_down(tilt_deg, dist):
    a = np.radians(tilt_deg)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]) @ np.diag([1.0, -1, -1])
    C = -dist * R[2]
    return R, -R @ C


@pytest.mark.parametrize("axis", [0, 1])
def test_render_is_exact_through_the_distortion_model(axis):
    cam = calibration_field_camera((300, 200))
    R, t = _look_down(25.0, 1.5)
    n, texel = 4000, 0.001
    ramp = np.linspace(0.0, 1.0, n, dtype=np.float32)
    grey = np.tile(ramp, (n, 1)) if axis == 0 else np.tile(ramp[:, None], (1, n))
    origin = np.array([-2.0, 2.0, 0.0])
    du, dv = np.array([texel, 0, 0]), np.array([0, -texel, 0])
    img = render(cam, R, t, [Facet(origin, du, dv, grey)], background=-1.0, supersample=2)
    # expected: texel coordinate where each pixel's ray (camera model inverse) meets the plane
    uu, vv = np.meshgrid(np.arange(300.0), np.arange(200.0))
    d_cam = cam.ray(np.column_stack([uu.ravel(), vv.ravel()]))
    d_w, C_w = d_cam @ R, -R.T @ t
    s = -C_w[2] / d_w[:, 2]
    P = C_w + s[:, None] * d_w
    coord = (P[:, 0] - origin[0]) / texel if axis == 0 else (origin[1] - P[:, 1]) / texel
    assert np.all(img > -0.5)  # the whole frame sees the plane
    err_texel = img.ravel() * (n - 1) - coord
    assert np.abs(err_texel).max() < 0.05  # cv2.remap resolves 1/32 texel; a texel is ~1/5 px here


def test_shots_cover_the_whole_frame_including_corners():
    cam = calibration_field_camera((3000, 2000))
    tf = TargetField()
    shots = plan_shots(48, cam, tf, np.random.default_rng(0))
    facets = field_facets(tf, 0.004)
    hits = np.zeros((4, 6), int)  # images with complete targets in each cell of a 6x4 grid over the frame
    tilts = set()
    for sh in shots:
        _, uv, complete = truth_projections(cam, tf, sh, facets)
        cells = set(zip((uv[complete, 1] // 500).astype(int), (uv[complete, 0] // 500).astype(int)))
        for r, c in cells:
            hits[r, c] += 1
        tilts.add(round(sh.tilt_deg / 15))
    assert hits.min() >= 10, hits
    assert tilts == {0, 2, 3}
    rots = {round(s.rotation_deg) for s in shots}
    assert len(rots) >= 24


def test_seed_makes_the_plan_reproducible():
    cam, tf = calibration_field_camera((600, 400)), TargetField()
    a = plan_shots(6, cam, tf, np.random.default_rng(7))
    b = plan_shots(6, cam, tf, np.random.default_rng(7))
    c = plan_shots(6, cam, tf, np.random.default_rng(8))
    assert all(np.array_equal(x.R_field_to_cam, y.R_field_to_cam) for x, y in zip(a, b))
    assert not np.allclose(a[0].t_field_to_cam, c[0].t_field_to_cam)


def test_cli_writes_images_and_consistent_truth(tmp_path):
    import cv2

    from dgcal.cli import main
    from dgcal.calib.camera.files import camera_from_json_dict
    out = tmp_path / "sim"
    assert main(["simulate", "camera-field", "--out", str(out), "--seed", "5", "--n-images", "2",
                 "--image-size", "480", "320", "--square", "0.2", "--marker", "0.15"]) == 0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["seed"] == 5 and len(truth["images"]) == 2
    cam = camera_from_json_dict(truth["camera"])
    assert np.allclose(cam.params, calibration_field_camera((480, 320)).params)
    pts = read_points(out / "field.csv")
    xyz = dict(zip(pts.ids, pts.xyz))
    tm = read_table(out / "truth_measurements.csv", ["image", "id", "x", "y", "complete"])
    assert len(tm) > 20
    for im in truth["images"]:
        img = cv2.imread(str(out / "images" / im["image"]), cv2.IMREAD_GRAYSCALE)
        assert img.shape == (320, 480)
        R, t = np.array(im["R_plate_to_cam"]), np.array(im["t_plate_to_cam"])
        assert np.allclose(R @ R.T, np.eye(3))
        sel = tm["image"] == im["image"]
        X = np.array([xyz[i] for i in tm["id"][sel]]) @ R.T + t
        uv = cam.project(X)
        assert np.abs(uv - np.column_stack([tm["x"][sel], tm["y"][sel]])).max() < 1e-4
    assert main(["simulate", "camera-field", "--out", str(tmp_path / "bad"), "--marker", "0.5"]) == 2
    assert not (tmp_path / "bad" / "truth.json").exists()


def test_nonplanar_plate_renders_blocks_and_hides_what_they_occlude(tmp_path):
    from dgcal.sim.camera_field import simulate_camera_field
    tf = nonplanar_field(square_m=0.12, marker_m=0.09)
    simulate_camera_field(tmp_path, seed=11, n_images=2, image_size=(1200, 800), field=tf, progress=False)
    meas, _ = detect_folder(tmp_path / "images", tmp_path / "field.csv", workers=1, progress=False)
    tm = read_table(tmp_path / "truth_measurements.csv", ["image", "id", "x", "y", "complete"])
    truth = {(a, b): np.array([x, y]) for a, b, x, y in zip(tm["image"], tm["id"], tm["x"], tm["y"])}
    z = dict(zip(*[getattr(read_points(tmp_path / "field.csv"), k) for k in ("ids", "xyz")]))
    assert all((a, b) in truth for a, b in zip(meas.image, meas.id))  # nothing hidden is "detected"
    err = np.array([xy - truth[(a, b)] for a, b, xy in zip(meas.image, meas.id, meas.xy)])
    levels = {round(z[i][2], 2) for i in meas.id}
    assert levels == {0.0, 0.1, 0.2}
    assert np.sqrt(np.mean(err ** 2)) < 0.08
    # the tilted views hide some plate targets behind the blocks (compare with the blocks' faces left out)
    cam = calibration_field_camera((1200, 800))
    shots = plan_shots(2, cam, tf, np.random.default_rng(11))
    with_blocks, plate_only = field_facets(tf, 0.004), field_facets(TargetField(square_m=0.12, marker_m=0.09), 0.004)
    hidden = sum(len(set(truth_projections(cam, tf, sh, plate_only)[0])
                     - set(truth_projections(cam, tf, sh, with_blocks)[0])) for sh in shots)
    assert hidden > 0


def test_cli_renders_a_standard_board_with_consistent_truth(tmp_path):
    import cv2

    from dgcal.calib.camera.files import camera_from_json_dict
    from dgcal.cli import main
    from dgcal.fields.targets.boards import read_board
    board = tmp_path / "b.toml"
    board.write_text('type = "aruco-grid"\ncolumns = 4\nrows = 3\nsquare_m = 0.05\nmarker_m = 0.04\n'
                     'dictionary = "DICT_5X5_250"\n')
    out = tmp_path / "sim"
    assert main(["simulate", "camera-field", "--board", str(board), "--out", str(out), "--seed", "2",
                 "--n-images", "3", "--image-size", "480", "360"]) == 0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["simulator"] == "board-views" and len(truth["images"]) == 3
    assert read_board(out / "board.toml") == read_board(board)
    cam = camera_from_json_dict(truth["camera"])
    pts = read_points(out / "field.csv")
    xyz = dict(zip(pts.ids, pts.xyz))
    tm = read_table(out / "truth_measurements.csv", ["image", "id", "x", "y"])
    for im in truth["images"]:
        assert cv2.imread(str(out / "images" / im["image"]), cv2.IMREAD_GRAYSCALE).shape == (360, 480)
        R, t = np.array(im["R_board_to_cam"]), np.array(im["t_board_to_cam"])
        sel = tm["image"] == im["image"]
        assert sel.sum() >= 0.4 * len(pts.ids)            # at least 40 % of the corners in view
        uv = cam.project(np.array([xyz[i] for i in tm["id"][sel]]) @ R.T + t)
        assert np.abs(uv - np.column_stack([tm["x"][sel], tm["y"][sel]])).max() < 1e-4
