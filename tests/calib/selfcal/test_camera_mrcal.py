"""Real wide-angle data (mrcal's figueroa set, 186 frames, 18,597 corners): opencv8 matches mrcal's
reference, fraser7 is reported as not fitting the lens."""
import json

from dgcal.cli import main


def _run(shared_data, tmp_path, model, capsys, *extra):
    d = shared_data / "mrcal-figueroa"
    out = tmp_path / model
    rc = main(["camera", "--field", str(d / "field.csv"), "--measurements", str(d / "measurements.csv"),
               "--image-size", "6016", "4016", "--model", model, "--out", str(out), *extra])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    return json.loads((out / "camera.json").read_text()), cap.err, out


def test_opencv8_matches_mrcal_reference(shared_data, tmp_path, capsys):
    cj, err, out = _run(shared_data, tmp_path, "opencv8", capsys)
    ref = json.loads((shared_data / "mrcal-figueroa" / "reference.json").read_text())
    assert cj["model"] == "opencv8" and cj["image_size"] == [6016, 4016]
    assert cj["rms_px"] <= 1.36, cj["rms_px"]  # OpenCV calibrateCamera leaves 1.36 px on the same data
    assert cj["n_observations"] + cj["n_rejected"] == 18597
    assert cj["n_rejected"] < 0.05 * 18597
    for k in ("fx", "fy"):
        assert abs(cj["opencv"][k] / ref[k] - 1) < 0.003, (k, cj["opencv"][k], ref[k])
    for k in ("cx", "cy"):
        assert abs(cj["opencv"][k] - ref[k]) < 10.0, (k, cj["opencv"][k], ref[k])
    assert cj["opencv_max_error_px"] == 0.0
    assert not cj["residual_pattern"]["lens_model_misfit"]
    assert not any("does not fit" in w for w in cj["warnings"])
    assert (out / "report.html").is_file()


def test_fraser7_reports_that_it_does_not_fit(shared_data, tmp_path, capsys):
    cj, err, _ = _run(shared_data, tmp_path, "fraser7", capsys, "--no-report")
    assert cj["residual_pattern"]["lens_model_misfit"]
    assert any("does not fit" in w and "opencv8" in w for w in cj["warnings"])
    assert "does not fit" in err and "--model opencv8" in err
    assert cj["rms_px"] > 5.0
