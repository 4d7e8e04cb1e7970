"""dgcal mount / check / export / compare on a simulated campaign written to files."""
import json

import numpy as np
import pytest

from dgcal.cli import main
from dgcal.sim.mounting import simulate_mounting, write_mounting_sim


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("mountsim")
    write_mounting_sim(simulate_mounting(5), d)
    return d


def _mount(files, out, method="proposed", extra=()):
    c = files / "calibration"
    return main(["mount", "--eop", str(c / "eop.csv"), "--crs", "EPSG:32651", "--trajectory",
                 str(c / "trajectory.csv"), "--events", str(c / "events.csv"), "--method", method,
                 "--out", str(out), *extra])


def test_mount_writes_interface_json_and_report(files, tmp_path):
    assert _mount(files, tmp_path / "m") == 0
    j = json.loads((tmp_path / "m" / "mounting.json").read_text())
    truth = json.loads((files / "truth.json").read_text())
    for k in ("method", "lever_arm_m", "boresight_R_cam_to_body", "delay_s", "lever_arm_sigma_m",
              "boresight_sigma_deg", "delay_sigma_s"):
        assert k in j
    assert j["method"] == "proposed"
    assert np.array(j["boresight_R_cam_to_body"]).shape == (3, 3)
    assert abs(j["delay_s"] - truth["delay_s"]) < 3 * j["delay_sigma_s"] + 1e-4
    assert np.all(np.abs(np.array(j["lever_arm_m"]) - truth["lever_arm_m"]) < 0.03)
    html = (tmp_path / "m" / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 3 and "Correlations" in html


def test_mount_check_export_compare_chain(files, tmp_path):
    assert _mount(files, tmp_path / "trad", "traditional") == 0
    assert _mount(files, tmp_path / "prop") == 0
    m = files / "mapping"
    rc = main(["check", "--mounting", str(tmp_path / "trad" / "mounting.json"),
               str(tmp_path / "prop" / "mounting.json"),
               "--trajectory", str(m / "trajectory.csv"), "--events", str(m / "events.csv"),
               "--measurements", str(m / "measurements.csv"), "--gcp", str(files / "ground.csv"),
               "--camera", str(files / "camera.json"), "--crs", "EPSG:32651", "--out", str(tmp_path / "check")])
    assert rc == 0
    ck = json.loads((tmp_path / "check" / "check.json").read_text())
    rms = {k: v["stats"]["rms"]["3D"] for k, v in ck["checks"].items()}
    assert rms["proposed"] < 0.3 * rms["traditional"]
    assert (tmp_path / "check" / "check.html").stat().st_size > 10000
    rc = main(["export", "--mounting", str(tmp_path / "prop" / "mounting.json"), "--trajectory",
               str(m / "trajectory.csv"), "--events", str(m / "events.csv"), "--crs", "EPSG:32651",
               "--camera", str(files / "camera.json"), "--out", str(tmp_path / "exp")])
    assert rc == 0
    for f in ("colmap/images.txt", "colmap/cameras.txt", "geo.txt", "pix4d_external_orientation.txt",
              "metashape_opk.csv", "eop.csv"):
        assert (tmp_path / "exp" / f).is_file()
    assert main(["compare", str(tmp_path / "prop" / "mounting.json"), str(tmp_path / "prop" / "mounting.json"),
                 "--fail-on-change"]) == 0
    assert main(["compare", str(tmp_path / "trad" / "mounting.json"), str(tmp_path / "prop" / "mounting.json"),
                 "--fail-on-change"]) == 1


def test_bad_input_names_the_file_and_leaves_nothing(files, tmp_path, capsys):
    bad = tmp_path / "eop.csv"
    text = (files / "calibration" / "eop.csv").read_text().splitlines()
    cols = text[3].split(",")
    cols[2] = "north"
    text[3] = ",".join(cols)
    bad.write_text("\n".join(text) + "\n")
    c = files / "calibration"
    rc = main(["mount", "--eop", str(bad), "--crs", "EPSG:32651", "--trajectory", str(c / "trajectory.csv"),
               "--events", str(c / "events.csv"), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and "eop.csv:4" in err and "'y'" in err.lower()
    assert not (tmp_path / "out" / "mounting.json").exists()
    rc = _mount(files, tmp_path / "iso", "iso")
    assert rc == 2 and "--measurements" in capsys.readouterr().err


def test_errors_name_the_bad_input(files, tmp_path, capsys):
    bad = tmp_path / "mounting.json"
    bad.write_text('{"method": "x", "lever_arm_m": [0, 0]}')
    assert main(["compare", str(bad), str(bad)]) == 2
    assert "mounting.json" in capsys.readouterr().err
    m = files / "mapping"
    good = tmp_path / "good.json"
    good.write_text('{"method": "proposed", "lever_arm_m": [0, 0, 0], "delay_s": 0.0, '
                    '"boresight_R_cam_to_body": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}')
    rc = main(["export", "--mounting", str(good), "--trajectory", str(m / "trajectory.csv"), "--events",
               str(m / "events.csv"), "--crs", "EPSG:32651", "--formats", "pix4d,kml", "--out", str(tmp_path / "e")])
    assert rc == 2 and "kml" in capsys.readouterr().err
    # an event outside the trajectory is named
    ev = (m / "events.csv").read_text().splitlines()
    ev.append("LATE.JPG,2200,600000.0")   # a valid time after the trajectory ends
    (tmp_path / "events.csv").write_text("\n".join(ev) + "\n")
    rc = main(["export", "--mounting", str(good), "--trajectory", str(m / "trajectory.csv"), "--events",
               str(tmp_path / "events.csv"), "--crs", "EPSG:32651", "--formats", "eop", "--out", str(tmp_path / "e2")])
    err = capsys.readouterr().err
    assert rc == 2 and "LATE.JPG" in err
    assert not (tmp_path / "e2" / "eop.csv").exists()
    rot = tmp_path / "rot.json"
    rot.write_text(good.read_text().replace("[0, 0, 1]]", "[0, 0, 2]]"))
    assert main(["compare", str(good), str(rot)]) == 2
    assert "rotation" in capsys.readouterr().err


def test_check_rejects_a_negative_correlation_time(files, tmp_path, capsys):
    m = files / "mapping"
    with pytest.raises(SystemExit) as exc:           # refused where argparse reads it (dgcal.arg_types)
        main(["check", "--mounting", str(tmp_path / "none.json"), "--trajectory", str(m / "trajectory.csv"),
              "--events", str(m / "events.csv"), "--measurements", str(m / "measurements.csv"),
              "--gcp", str(files / "ground.csv"), "--camera", str(files / "camera.json"), "--crs", "EPSG:32651",
              "--pos-correlation-time", "-5", "--out", str(tmp_path / "check")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--pos-correlation-time: must be >= 0" in err
    assert not (tmp_path / "check").exists()
