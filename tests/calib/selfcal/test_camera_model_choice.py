"""Model comparison (`--model auto`) and the fisheye (Kannala-Brandt / OpenCV fisheye) model: on mrcal's real wide-angle
corners fraser7 is rejected and a model with RMS <= 1.36 px chosen, with the uncertainty map in the report; on a
simulated fisheye lens the choice follows the lens; the fisheye model against cv2.fisheye and COLMAP."""
import json
import re

import cv2
import numpy as np
import pycolmap

from dgcal.calib.camera.conversions import from_colmap, to_colmap
from dgcal.calib.camera.files import load_camera, write_colmap_cameras_txt
from dgcal.calib.camera.models import Fisheye
from dgcal.calib.selfcal.diagnostics import projection_difference
from dgcal.calib.selfcal.model_choice import compare_models
from dgcal.cli import main
from dgcal.fields.targets.plate import TargetField
from dgcal.sim.camera_field import plan_shots
from test_camera_ba_simulated import simulate_measurements

FISH = Fisheye((1200, 900), [520.0, 521.0, 603.0, 447.0, 0.02, -0.015, 0.004, -0.001])


def test_auto_on_mrcal_corners(shared_data, tmp_path, capsys):
    d = shared_data / "mrcal-figueroa"
    out = tmp_path / "auto"
    rc = main(["camera", "--field", str(d / "field.csv"), "--measurements", str(d / "measurements.csv"),
               "--image-size", "6016", "4016", "--model", "auto", "--out", str(out)])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    cj = json.loads((out / "camera.json").read_text())
    choice = cj["model_choice"]
    rows = {r["model"]: r for r in choice["models"]}
    assert set(rows) == {"fraser7", "opencv8", "fisheye"}
    assert rows["fraser7"]["rejected"] and "does not follow the lens" in rows["fraser7"]["rejected"]
    assert choice["chosen"] != "fraser7" and cj["model"] == choice["chosen"]
    assert cj["rms_px"] <= 1.36, cj["rms_px"]
    assert any(r.startswith("chose ") for r in choice["reasons"]) and "model choice: chose" in cap.out
    assert np.isfinite(rows[choice["chosen"]]["cv_rms_px"])
    # the uncertainty map: in camera.json as a grid, in the report as a figure
    u = cj["projection_uncertainty"]["model"]
    assert np.array(u["sigma_px_at_infinity"]).shape == (len(u["v_px"]), len(u["u_px"]))
    assert cj["projection_uncertainty"]["valid_region_sigma_px_at_infinity"]["median"] < 1.0
    html = (out / "report.html").read_text()
    assert "Projection uncertainty and valid region" in html and "Model comparison" in html
    section = html[html.index("Projection uncertainty and valid region"):]
    assert re.search(r"data:image/png;base64,", section[:200000])


def test_auto_follows_a_fisheye_lens():
    tf = TargetField(diameter_m=1.6, square_m=0.1, marker_m=0.075)
    pts = tf.points()
    rng = np.random.default_rng(21)
    shots = plan_shots(24, FISH, tf, rng)
    img, idx, xy = simulate_measurements(FISH, pts.xyz, shots, 0.2, rng)
    c = compare_models(pts.ids, pts.xyz, img, pts.ids[idx], xy, FISH.image_size)
    assert c.fits["fraser7"].rejected, c.reasons
    assert c.chosen in ("fisheye", "opencv8")
    chosen = c.fits[c.chosen]
    rms, _, _ = projection_difference(FISH, chosen.ba.camera, uv=chosen.region.grid((41, 31)))
    assert rms < 0.1, rms
    assert 0.3 < c.fits["fisheye"].cv_ratio < 3.0         # the true model reproduces itself about as noise predicts


def test_fisheye_model_is_opencv_fisheye():
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-2, 2, (300, 2)), rng.uniform(0.3, 2, 300)])
    ref, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), FISH.pinhole_K(),
                                       FISH.params[4:])
    assert np.abs(ref.reshape(-1, 2) - FISH.project(X)).max() < 1e-9
    uv, Jp, JX = FISH.project_with_jacobians(X)
    h = 1e-6
    for j in range(8):
        a, b = FISH.copy(), FISH.copy()
        a.params[j] += h
        b.params[j] -= h
        num = (a.project(X) - b.project(X)) / (2 * h)
        assert np.abs(num - Jp[:, :, j]).max() < 1e-5 * max(1.0, np.abs(num).max())
    assert np.abs(FISH.undistort_normalized(uv) - X[:, :2] / X[:, 2:]).max() < 1e-10
    assert np.allclose(FISH.project(np.array([[0.0, 0.0, 1.0]])), [[603.0, 447.0]])


def test_fisheye_in_colmap_and_camera_json(tmp_path):
    name, params, err = to_colmap(FISH)
    assert name == "OPENCV_FISHEYE" and err == 0.0
    back = from_colmap(name, 1200, 900, params)
    assert isinstance(back, Fisheye) and np.allclose(back.params, FISH.params)
    cam = pycolmap.Camera(model="OPENCV_FISHEYE", width=1200, height=900, params=params)
    X = np.array([[0.3, -0.2, 1.0], [-0.9, 0.6, 1.0]])
    assert np.allclose(cam.img_from_cam(X) - 0.5, FISH.project(X), atol=1e-9)
    write_colmap_cameras_txt(tmp_path / "cameras.txt", FISH)
    assert np.allclose(load_camera(tmp_path / "cameras.txt").params, FISH.params)
