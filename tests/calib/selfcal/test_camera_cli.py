"""`dgcal camera` end to end on simulated measurements, and its behaviour on bad input."""
import json
import re

import numpy as np
import pytest

from dgcal.calib.selfcal.diagnostics import projection_difference
from dgcal.calib.camera.files import load_camera
from dgcal.cli import main
from dgcal.fields.io.formats import Measurements, write_measurements
from dgcal.fields.targets.plate import TargetField, write_field
from dgcal.sim.camera_field import calibration_field_camera, plan_shots
from test_camera_ba_simulated import SIZE, simulate_measurements


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("camsim")
    rng = np.random.default_rng(5)
    tf = TargetField(square_m=0.16, marker_m=0.12)
    pts = write_field(d / "field.csv", tf)
    truth = calibration_field_camera(SIZE)
    shots = plan_shots(24, truth, tf, rng)
    img, idx, xy = simulate_measurements(truth, pts.xyz, shots, 0.1, rng)
    write_measurements(d / "measurements.csv", Measurements(img, pts.ids[idx], xy, np.full_like(xy, 0.1)))
    return d, truth


def run_cli(args, capsys):
    rc = main(["camera", *map(str, args)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_camera_cli_writes_every_output(sim_dir, tmp_path, capsys):
    d, truth = sim_dir
    out = tmp_path / "out"
    rc, stdout, err = run_cli(["--field", d / "field.csv", "--measurements", d / "measurements.csv",
                               "--image-size", *SIZE, "--out", out], capsys)
    assert rc == 0, err
    for name in ("camera.json", "report.html", "opencv.yaml", "cameras.txt", "metashape.xml", "poses.csv"):
        assert (out / name).is_file(), name
    cj = json.loads((out / "camera.json").read_text())
    assert cj["model"] == "fraser7" and cj["image_size"] == list(SIZE)
    assert cj["n_observations"] > 1000 and cj["n_rejected"] >= 0
    assert 0.1 < cj["rms_px"] < 0.2  # per-point norm of 0.1 px per coordinate noise
    assert set(cj["opencv"]) == {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"}
    assert cj["opencv_max_error_px"] > 0  # B2 != 0 has no exact OpenCV equivalent
    for k, v in cj["parameters"].items():
        assert abs(v - truth[k]) < 3.5 * cj["sigmas"][k], k
    assert abs(cj["sigma0"] - 1.0) < 0.1  # sigmas of 0.1 px in the file were honest
    assert len(cj["per_image_rms_px"]) == 24
    assert cj["correlation"]["parameters"][0] == "f" and len(cj["correlation"]["matrix"]) == 10
    cam = load_camera(out / "camera.json")
    assert projection_difference(truth, cam)[0] < 0.06
    html = (out / "report.html").read_text()
    assert len(re.findall(r"data:image/png;base64,", html)) >= 5
    assert "RMS" in stdout


def _assert_failed_cleanly(rc, err, out, must_name):
    assert rc == 2
    lines = [ln for ln in err.strip().splitlines() if ln]
    assert len(lines) == 1, err
    assert lines[0].startswith("dgcal camera: error:") and must_name in lines[0], lines[0]
    assert not out.exists() or not any(out.iterdir())


def test_missing_column(sim_dir, tmp_path, capsys):
    d, _ = sim_dir
    bad = tmp_path / "meas_noy.csv"
    rows = (d / "measurements.csv").read_text().splitlines()
    bad.write_text("\n".join(",".join(r.split(",")[:3]) for r in rows) + "\n")
    out = tmp_path / "out"
    rc, _, err = run_cli(["--field", d / "field.csv", "--measurements", bad, "--image-size", *SIZE, "--out", out],
                         capsys)
    _assert_failed_cleanly(rc, err, out, "meas_noy.csv")
    assert "missing column" in err and "y" in err


def test_unknown_target_id(sim_dir, tmp_path, capsys):
    d, _ = sim_dir
    bad = tmp_path / "meas_unknown.csv"
    text = (d / "measurements.csv").read_text().splitlines()
    first = text[1].split(",")
    first[1] = "NOPE42"
    text[1] = ",".join(first)
    bad.write_text("\n".join(text) + "\n")
    out = tmp_path / "out"
    rc, _, err = run_cli(["--field", d / "field.csv", "--measurements", bad, "--image-size", *SIZE, "--out", out],
                         capsys)
    _assert_failed_cleanly(rc, err, out, "meas_unknown.csv:2")
    assert "NOPE42" in err


def test_fewer_than_three_images(sim_dir, tmp_path, capsys):
    d, _ = sim_dir
    text = (d / "measurements.csv").read_text().splitlines()
    images = sorted({r.split(",")[0] for r in text[1:]})[:2]
    bad = tmp_path / "meas_two.csv"
    bad.write_text("\n".join([text[0]] + [r for r in text[1:] if r.split(",")[0] in images]) + "\n")
    out = tmp_path / "out"
    rc, _, err = run_cli(["--field", d / "field.csv", "--measurements", bad, "--image-size", *SIZE, "--out", out],
                         capsys)
    _assert_failed_cleanly(rc, err, out, "meas_two.csv")
    assert "need 3" in err


def test_wrong_image_size_and_missing_size(sim_dir, tmp_path, capsys):
    d, _ = sim_dir
    out = tmp_path / "out"
    rc, _, err = run_cli(["--field", d / "field.csv", "--measurements", d / "measurements.csv",
                          "--image-size", 3000, 2000, "--out", out], capsys)
    _assert_failed_cleanly(rc, err, out, "measurements.csv:")
    assert "outside the image" in err
    rc, _, err = run_cli(["--field", d / "field.csv", "--measurements", d / "measurements.csv", "--out", out],
                         capsys)
    _assert_failed_cleanly(rc, err, out, "--image-size")


def test_unreadable_images(sim_dir, tmp_path, capsys):
    d, _ = sim_dir
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    (imgs / "IMG_0001.jpg").write_bytes(b"this is not a jpeg" * 100)
    out = tmp_path / "out"
    rc, _, err = run_cli(["--field", d / "field.csv", "--images", imgs, "--workers", 1, "--out", out], capsys)
    _assert_failed_cleanly(rc, err, out, "IMG_0001.jpg")


def test_missing_field_file(sim_dir, tmp_path, capsys):
    d, _ = sim_dir
    out = tmp_path / "out"
    rc, _, err = run_cli(["--field", tmp_path / "nofield.csv", "--measurements", d / "measurements.csv",
                          "--image-size", *SIZE, "--out", out], capsys)
    _assert_failed_cleanly(rc, err, out, "nofield.csv")


def test_camera_cli_from_rendered_images(tmp_path, capsys):
    from dgcal.calib.camera.files import camera_from_json_dict
    from dgcal.fields.io.formats import read_measurements
    from dgcal.sim.camera_field import simulate_camera_field
    sim = tmp_path / "sim"
    truth = simulate_camera_field(sim, seed=3, n_images=12, image_size=(1200, 800),
                                  field=TargetField(square_m=0.16, marker_m=0.12), supersample=1, progress=False)
    out = tmp_path / "out"
    rc, _, err = run_cli(["--field", sim / "field.csv", "--images", sim / "images", "--workers", 1,
                          "--out", out], capsys)
    assert rc == 0, err
    meas = read_measurements(out / "measurements.csv")
    assert len(meas.images()) == 12 and len(meas) > 500
    cj = json.loads((out / "camera.json").read_text())
    assert cj["image_size"] == [1200, 800]
    rms, _, _ = projection_difference(camera_from_json_dict(truth["camera"]), load_camera(out / "camera.json"))
    assert rms < 0.1, rms


def test_camera_cli_options_refine_and_fix(sim_dir, tmp_path, capsys):
    from dgcal.fields.io.formats import read_points
    d, truth = sim_dir
    out = tmp_path / "out"
    rc, _, err = run_cli(["--field", d / "field.csv", "--measurements", d / "measurements.csv",
                          "--image-size", *SIZE, "--refine-targets", "free", "--fix", "K3", "--no-report",
                          "--out", out], capsys)
    assert rc == 0, err
    cj = json.loads((out / "camera.json").read_text())
    assert cj["fixed_parameters"] == ["K3"] and cj["sigmas"]["K3"] == 0.0
    assert cj["refine_targets"] == "free" and cj["targets_moved_max_m"] < 0.01
    refined = read_points(out / "field_refined.csv")
    assert len(refined.ids) == len(read_points(d / "field.csv").ids)
    assert not (out / "report.html").exists()
    rc, _, err = run_cli(["--field", d / "field.csv", "--measurements", d / "measurements.csv",
                          "--image-size", *SIZE, "--fix", "k9", "--out", tmp_path / "out2"], capsys)
    _assert_failed_cleanly(rc, err, tmp_path / "out2", "k9")


def test_initial_camera_of_another_size_is_refused(sim_dir, tmp_path, capsys):
    from dgcal.calib.camera.files import write_camera_json
    d, truth = sim_dir
    other = calibration_field_camera((3000, 2000))
    write_camera_json(tmp_path / "start.json", other)
    out = tmp_path / "out"
    rc, _, err = run_cli(["--field", d / "field.csv", "--measurements", d / "measurements.csv",
                          "--image-size", *SIZE, "--initial", tmp_path / "start.json", "--out", out], capsys)
    _assert_failed_cleanly(rc, err, out, "initial")
