"""camera.json, OpenCV YAML, COLMAP cameras.txt and Metashape XML: write, read back, same projections."""
import json

import numpy as np
import pytest

from dgcal.calib.camera import conversions as cc
from dgcal.calib.camera import files as cf
from dgcal.calib.camera.models import Fraser7, OpenCV8
from dgcal.fields.errors import InputError

rng = np.random.default_rng(5)


def fraser(b2=0.0):
    return Fraser7((6000, 4000), [4000.0, 3010.0, 1985.0, -0.08, 0.05, -0.01, 2e-4, -1e-4, 1.5, b2])


def opencv8():
    return OpenCV8((6016, 4016), [2073.9, 2077.4, 3004.7, 1997.4, 0.8, 0.2, 1e-4, -2e-4, 0.01, 1.1, 0.35, 0.03])


def points(cam, n=200):
    uv = np.column_stack([rng.uniform(0, cam.image_size[0] - 1, n), rng.uniform(0, cam.image_size[1] - 1, n)])
    return cam.ray(uv) * 5.0


def same_projection(a, b, atol=1e-6):
    X = points(a)
    np.testing.assert_allclose(b.project(X), a.project(X), atol=atol)


@pytest.mark.parametrize("cam", [fraser(), fraser(0.8), opencv8()], ids=["fraser7", "fraser7-skew", "opencv8"])
def test_camera_json_round_trip(tmp_path, cam):
    sig = np.abs(cam.params) * 1e-3 + 1e-6
    d = cf.write_camera_json(tmp_path / "camera.json", cam, sig,
                             {"rms_px": 0.11, "n_observations": np.int64(4000), "n_rejected": 3})
    on_disk = json.loads((tmp_path / "camera.json").read_text())
    assert on_disk == d
    for key in ("model", "image_size", "rms_px", "n_observations", "n_rejected", "parameters", "sigmas",
                "opencv", "opencv_max_error_px"):
        assert key in on_disk
    assert on_disk["image_size"] == list(cam.image_size)
    assert (on_disk["opencv_max_error_px"] == 0.0) == (cam.NAME == "opencv8" or cam["B2"] == 0)
    assert set(on_disk["opencv"]) == set(cc.OPENCV8_KEYS if cam.NAME == "opencv8" else cc.OPENCV5_KEYS)
    back = cf.load_camera(tmp_path / "camera.json")
    assert back.NAME == cam.NAME
    np.testing.assert_array_equal(back.params, cam.params)
    np.testing.assert_array_equal(back.sigmas, sig)
    # the opencv block alone reproduces the projection to within the reported error
    ocv = cc.from_opencv(on_disk["opencv"], cam.image_size)
    assert cc.max_projection_difference(cam, ocv) <= on_disk["opencv_max_error_px"] * 1.05 + 1e-6


@pytest.mark.parametrize("cam", [fraser(), opencv8()], ids=["fraser7", "opencv8"])
def test_opencv_yaml_round_trip_readable_by_cv2(tmp_path, cam):
    import cv2
    assert cf.write_opencv_yaml(tmp_path / "opencv.yaml", cam) == 0.0
    fs = cv2.FileStorage(str(tmp_path / "opencv.yaml"), cv2.FILE_STORAGE_READ)
    K, dist = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat().ravel()
    assert int(fs.getNode("image_width").real()) == cam.image_size[0]
    fs.release()
    X = points(cam)
    np.testing.assert_allclose(cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, dist)[0][:, 0], cam.project(X),
                               atol=1e-6)
    back = cf.load_camera(tmp_path / "opencv.yaml")
    assert back.NAME == cam.NAME
    same_projection(cam, back)


def test_opencv_yaml_written_by_opencv_itself(tmp_path):
    import cv2
    p = tmp_path / "calib.yml"
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", np.array([[500.0, 0, 320], [0, 505, 240], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[-0.1, 0.01, 0.001, 0.002, 0.0]]))
    fs.release()
    cam = cf.load_camera(p)
    assert cam.NAME == "fraser7" and cam["f"] == 505 and cam["B1"] == -5 and cam["P2"] == 0.002
    cam8 = cf.load_camera(p, model="opencv8")
    assert cam8.NAME == "opencv8"
    same_projection(cam, cam8)
    # OpenCV's XML flavour of FileStorage too
    fs = cv2.FileStorage(str(tmp_path / "calib.xml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", np.array([[500.0, 0, 320], [0, 505, 240], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[-0.1, 0.01, 0.001, 0.002, 0.0]]))
    fs.release()
    np.testing.assert_array_equal(cf.load_camera(tmp_path / "calib.xml").params, cam.params)


@pytest.mark.parametrize("cam", [fraser(), fraser(0.8), opencv8()], ids=["fraser7", "fraser7-skew", "opencv8"])
def test_colmap_cameras_txt_round_trip(tmp_path, cam):
    import pycolmap
    err = cf.write_colmap_cameras_txt(tmp_path / "cameras.txt", cam)
    back = cf.load_camera(tmp_path / "cameras.txt")
    if err == 0.0:
        same_projection(cam, back)
    else:
        assert cc.max_projection_difference(cam, back) <= err * 1.05
    # COLMAP's own reader gets the same camera
    rec = pycolmap.Reconstruction()
    (tmp_path / "images.txt").write_text("")
    (tmp_path / "points3D.txt").write_text("")
    rec.read_text(str(tmp_path))
    pc = rec.cameras[1]
    X = points(cam)
    np.testing.assert_allclose(pc.img_from_cam(X) - 0.5, back.project(X), atol=1e-6)


def test_metashape_xml_round_trip(tmp_path):
    cam = fraser(0.8)
    assert cf.write_metashape_xml(tmp_path / "cal.xml", cam) == 0.0
    text = (tmp_path / "cal.xml").read_text()
    assert "<projection>frame</projection>" in text and "<p1>" in text
    back = cf.load_camera(tmp_path / "cal.xml")
    np.testing.assert_allclose(back.params, cam.params, rtol=1e-14, atol=1e-14)
    # a whole Metashape camera export (sensor with <resolution>) is read too
    (tmp_path / "cams.xml").write_text(
        '<document version="2.0.0"><chunk><sensors><sensor id="0" type="frame"><resolution width="6000" '
        'height="4000"/><calibration type="frame" class="adjusted"><resolution width="6000" height="4000"/>'
        '<f>4000</f><cx>10.5</cx><cy>-14.5</cy><k1>-0.08</k1><p1>-1e-4</p1><p2>2e-4</p2></calibration>'
        '</sensor></sensors></chunk></document>')
    cam2 = cf.load_camera(tmp_path / "cams.xml")
    assert cam2["cx"] == 3010.0 and cam2["cy"] == 1985.0 and cam2["P1"] == 2e-4 and cam2["P2"] == -1e-4


def test_loaders_name_file_and_field(tmp_path):
    p = tmp_path / "camera.json"
    p.write_text(json.dumps({"model": "fraser7", "image_size": [10, 10], "parameters": {"f": 1.0}}))
    with pytest.raises(InputError, match=r"camera.json.*parameters.cx"):
        cf.load_camera(p)
    p.write_text(json.dumps({"model": ["x"], "image_size": [10, 10]}))
    with pytest.raises(InputError, match=r"camera.json.*field 'model'.*unknown camera model"):
        cf.load_camera(p)
    p.write_text("{not json")
    with pytest.raises(InputError, match=r"camera.json:1.*invalid JSON"):
        cf.load_camera(p)
    p = tmp_path / "cameras.txt"
    p.write_text("# c\n1 OPENCV 100 80 90 90 50 40 0.1\n")
    with pytest.raises(InputError, match=r"cameras.txt:2.*needs 8 params"):
        cf.load_camera(p)
    p = tmp_path / "cal.xml"
    p.write_text("<calibration><projection>frame</projection><width>10</width><height>8</height></calibration>")
    with pytest.raises(InputError, match=r"cal.xml.*field 'f'"):
        cf.load_camera(p)
    p = tmp_path / "x.txt"
    p.write_text("hello\n")
    with pytest.raises(InputError, match="unrecognised camera file"):
        cf.load_camera(p)
    with pytest.raises(InputError, match="missing.json: file not found"):
        cf.load_camera(tmp_path / "missing.json")


def test_writers_are_atomic(tmp_path, monkeypatch):
    target = tmp_path / "cameras.txt"
    target.write_text("old\n")
    # fail in the middle of writing: the old file stays, no temporary file is left behind
    monkeypatch.setattr(cf, "colmap_cameras_txt_string", lambda *a, **k: (b"not text", 0.0))
    with pytest.raises(TypeError):
        cf.write_colmap_cameras_txt(target, fraser())
    assert target.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["cameras.txt"]
