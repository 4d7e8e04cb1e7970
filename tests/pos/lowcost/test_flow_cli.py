"""`dgcal flow` (issue 15): GNSS + optic-flow attitude of a forward camera from the command line on `dgcal simulate
forward-camera` data: seed 001's Table 2 with standard deviations <= 0.5 deg and honest sigmas."""
import csv
import json

import cv2
import numpy as np
import pytest

from dgcal.cli import main
from dgcal.fields.errors import InputError
from dgcal.pos.lowcost.flow import ROW_COLUMNS, read_gnss_velocity


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("fc")
    assert main(["simulate", "forward-camera", "--duration", "150", "--fps", "2", "--seed", "1",
                 "--out", str(d / "sim")]) == 0
    return d


@pytest.fixture(scope="module")
def flow(sim):
    rc = main(["flow", "--images", str(sim / "sim/frames"), "--gnss", str(sim / "sim/gnss_velocity.csv"),
               "--camera", str(sim / "sim/camera.json"), "--truth", str(sim / "sim/truth_trajectory.csv"),
               "--ground-height", str(json.loads((sim / "sim/truth.json").read_text())["h_ground"]),
               "--out", str(sim / "out"), "--no-progress"])
    assert rc == 0
    return sim / "out"


def test_table2_statistics_and_honest_sigmas(flow):
    t2 = json.loads((flow / "flow.json").read_text())["table2"]
    assert t2["n_pairs"] >= 50
    for k in ("roll", "pitch", "yaw"):
        assert t2[k]["std_deg"] <= 0.5, (k, t2[k])
        assert abs(t2[k]["mean_deg"]) < 0.15, (k, t2[k])
        assert 0.7 <= t2[k]["normalised_rms"] <= 1.4, (k, t2[k])
    # the FOE removes the angle of attack (3 deg) and the wind's drift angle (4 deg) of the pseudo attitude
    assert abs(t2["pseudo_only"]["pitch_mean_deg"]) > 2.5 and abs(t2["pseudo_only"]["yaw_mean_deg"]) > 3.0
    assert t2["agl"]["median_rel_error"] < 0.02


def test_flow_table_and_report(flow):
    rows = list(csv.DictReader(open(flow / "flow.csv")))
    assert set(ROW_COLUMNS) <= set(rows[0]) and "err_yaw" in rows[0]
    aoa = np.array([float(r["angle_of_attack"]) for r in rows])
    drift = np.array([float(r["drift_angle"]) for r in rows])
    assert abs(np.median(aoa) - 3.0) < 0.2 and abs(abs(np.median(drift)) - 4.0) < 0.4
    z = [(float(r["err_agl_m"]) / float(r["sigma_agl_m"])) for r in rows]
    assert 0.5 < np.sqrt(np.mean(np.square(z))) < 2.0  # the height's sigma too
    html = (flow / "report.html").read_text()
    assert "Seed 001 Table 2" in html and html.count("data:image/png;base64") >= 3


def test_flow_from_a_video(sim, tmp_path):
    frames = list(csv.DictReader(open(sim / "sim/frames.csv")))[60:110]  # 25 s of the straight leg
    w = cv2.VideoWriter(str(tmp_path / "v.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 2.0, (240, 240), isColor=False)
    for r in frames:
        w.write(cv2.imread(str(sim / "sim/frames" / r["image"]), cv2.IMREAD_GRAYSCALE))
    w.release()
    rc = main(["flow", "--video", str(tmp_path / "v.avi"), "--video-start", frames[0]["t_gps"],
               "--gnss", str(sim / "sim/gnss_velocity.csv"), "--camera", str(sim / "sim/camera.json"),
               "--truth", str(sim / "sim/truth_trajectory.csv"), "--out", str(tmp_path / "out"), "--no-progress"])
    assert rc == 0
    t2 = json.loads((tmp_path / "out/flow.json").read_text())["table2"]
    assert t2["n_pairs"] >= 10 and t2["pitch"]["std_deg"] < 0.5 and t2["yaw"]["std_deg"] < 0.5


def test_flow_input_errors(sim, tmp_path, capsys):
    (tmp_path / "frames").mkdir()
    (tmp_path / "frames/a.png").write_bytes((sim / "sim/frames/frame_00000.png").read_bytes())
    rc = main(["flow", "--images", str(tmp_path / "frames"), "--gnss", str(sim / "sim/gnss_velocity.csv"),
               "--camera", str(sim / "sim/camera.json"), "--out", str(tmp_path / "out"), "--no-progress"])
    assert rc == 2 and "no frame times" in capsys.readouterr().err
    (tmp_path / "v.csv").write_text("t_gps,vn,ve,vd\n" + "".join(f"{i},1,0,x\n" for i in range(12)))
    with pytest.raises(InputError, match=r"v.csv:2: field 'vd': not a number"):
        read_gnss_velocity(tmp_path / "v.csv")
