"""Real webcam videos of a printed (inverted) ChArUco board (../shared/data/charuco-webcam): dgcal finds the corners
OpenCV's own ChArUco detector finds, its OpenCV-equivalent model (fraser7 with B2 held) leaves OpenCV
calibrateCamera's RMS, and no converted camera is written without its error inside the valid region, or a
warning in the file and on the console when that error exceeds 1 px."""
import json

import cv2
import numpy as np
import pytest

from dgcal.calib.camera.conversions import from_opencv
from dgcal.calib.camera.files import camera_from_json_dict
from dgcal.calib.camera.region import ValidRegion
from dgcal.cli import main
from dgcal.fields.io.formats import read_measurements
from dgcal.fields.targets.boards import read_board

RUNS = {"fixB2": ["--fix", "B2"], "fixB2_keep_all": ["--fix", "B2", "--reject", "0"], "fraser7": [],
        "fisheye": ["--model", "fisheye"]}


def run(shared_data, tmp, cam, name, capsys):
    d = shared_data / "charuco-webcam"
    out = tmp / f"{cam}_{name}"
    rc = main(["camera", "--board", str(d / "charuco.toml"), "--images", str(d / f"{cam}.mp4"), "--out", str(out),
               "--no-report", *RUNS[name]])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    return {"out": out, "json": json.loads((out / "camera.json").read_text()), "err": cap.err}


def opencv_frames(video):
    """OpenCV's ChArUco detector on every (inverted) frame: {frame number: (ids, corners)}."""
    board = read_board(video.parent / "charuco.toml")
    det = cv2.aruco.CharucoDetector(cv2.aruco.CharucoBoard((board.columns, board.rows), board.square_m,
                                                           board.marker_m, board.cv_dictionary()))
    cap = cv2.VideoCapture(str(video))
    out, k = {}, 0
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        cc, ci, _, _ = det.detectBoard(255 - cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
        out[k] = (np.zeros(0, int), np.zeros((0, 2))) if ci is None else (ci.ravel(), cc.reshape(-1, 2))
        k += 1
    return out, board


def calibrate_opencv(board, frames):
    objs = [board.corner_xyz()[ids].astype(np.float32) for ids, _ in frames]
    imgs = [xy.astype(np.float32) for _, xy in frames]
    rms, K, dist, _, _ = cv2.calibrateCamera(objs, imgs, (1280, 720), None, None)
    return rms, K


@pytest.mark.parametrize("cam", ["cam_0", "cam_2"])
def test_detection_and_rms_equal_opencv(shared_data, tmp_path, cam, capsys):
    video = shared_data / "charuco-webcam" / f"{cam}.mp4"
    ref, board = opencv_frames(video)
    a = run(shared_data, tmp_path, cam, "fixB2", capsys)
    b = run(shared_data, tmp_path, cam, "fixB2_keep_all", capsys)
    meas = read_measurements(a["out"] / "measurements.csv")
    chosen = a["json"]["frames"]["chosen"]
    frame_no = {lab: int(lab.split("#")[1]) for lab in chosen}
    # detection: >= 98 % of the corners OpenCV's ChArUco detector finds on the same frames, at the same pixels
    n_cv = sum(len(ref[frame_no[lab]][0]) for lab in chosen)
    assert len(meas) >= 0.98 * n_cv, (len(meas), n_cv)
    for lab in chosen:
        ids, xy = ref[frame_no[lab]]
        m = meas.image == lab
        got = dict(zip(meas.id[m].astype(int), meas.xy[m]))
        assert all(np.allclose(got[i], p, atol=1e-3) for i, p in zip(ids, xy) if i in got)
    # every frame where OpenCV finds 6 corners or more is chosen (a hand-held board: no repeats, none blurred)
    assert set(chosen) == {f"{cam}.mp4#{k:06d}" for k, (ids, _) in ref.items() if len(ids) >= 6}
    # RMS: OpenCV's 5-coefficient model (B2 held) on every observation = calibrateCamera on OpenCV's own corners
    cv_rms, K = calibrate_opencv(board, [ref[frame_no[lab]] for lab in chosen])
    assert b["json"]["n_rejected"] == 0
    assert abs(b["json"]["rms_px"] / cv_rms - 1) < 0.02, (b["json"]["rms_px"], cv_rms)
    assert b["json"]["rms_px"] <= cv_rms * 1.0005       # never a worse minimum than OpenCV's
    # the same focal length within its sigma (a board covering 5-8 % of the frame leaves a flat valley)
    s_f = b["json"]["sigmas"]["f"] + b["json"]["sigmas"]["B1"]
    assert abs(b["json"]["opencv"]["fx"] - K[0, 0]) < 2 * s_f, (b["json"]["opencv"]["fx"], K[0, 0], s_f)
    # with outlier rejection: the same RMS as calibrateCamera given the observations dgcal kept
    rejected = {(r["image"], r["id"]) for r in a["json"]["rejected"]}
    kept = []
    for lab in chosen:
        if lab in a["json"]["dropped_images"]:
            continue
        m = (meas.image == lab) & np.array([(lab, i) not in rejected for i in meas.id])
        kept.append((meas.id[m].astype(int), meas.xy[m]))
    kept_rms, _ = calibrate_opencv(board, kept)
    assert abs(a["json"]["rms_px"] / kept_rms - 1) < 0.02, (a["json"]["rms_px"], kept_rms)
    assert a["json"]["n_rejected"] < 0.02 * len(meas)


def check_export(r):
    """The OpenCV block's claimed error holds inside the valid region; above 1 px the file and console say so."""
    cj = r["json"]
    cam = camera_from_json_dict(cj)
    region = ValidRegion.from_dict(cj["valid_region"], cam.image_size)
    block = from_opencv(cj["opencv"], cam.image_size, "opencv8" if "k4" in cj["opencv"] else None)
    uv = region.grid((81, 61))
    assert len(uv) > 50
    err = float(np.max(np.linalg.norm(block.project(cam.ray(uv)) - uv, axis=1)))
    claimed = cj["opencv_max_error_px"]
    assert err <= claimed + 0.05 + 0.05 * claimed, (err, claimed)
    yaml = (r["out"] / "opencv.yaml").read_text()
    assert "valid region:" in yaml and "valid_region_px" in yaml      # the export carries the valid region
    if claimed > 1.0:
        assert "WARNING" in yaml and "approximation" in cj["opencv_warning"]
        assert any("approximation" in w and "OpenCV" in w for w in cj["warnings"])
        assert "approximation" in r["err"] and "OpenCV" in r["err"]
    else:
        assert "WARNING" not in yaml and "opencv_warning" not in cj
    return claimed


@pytest.mark.parametrize("cam, name", [("cam_0", "fraser7"), ("cam_2", "fisheye")])
def test_every_opencv_block_is_good_inside_the_valid_region_or_says_so(shared_data, tmp_path, cam, name, capsys):
    r = run(shared_data, tmp_path, cam, name, capsys)
    claimed = check_export(r)
    cj = r["json"]
    # the board covers a small part of these frames: the model is trusted only there, and that is said
    assert cj["valid_region"]["valid_fraction"] < 0.2
    assert any("valid over only" in w for w in cj["warnings"]) and "valid over only" in r["err"]
    # never a garbage block: a converted focal length near OpenCV's own (876 / 665 px)
    fx = {"cam_0": 876.0, "cam_2": 665.0}[cam]
    assert abs(cj["opencv"]["fx"] / fx - 1) < 0.03, cj["opencv"]["fx"]
    if name == "fraser7":
        # B2 free: the OpenCV block is a fit, inside the valid region it is far below 1 px
        assert 0 < claimed < 1.0
        assert cj["opencv_max_error_frame_px"] > claimed      # outside it the polynomials part ways
    else:
        assert "opencv_fisheye" in cj and (r["out"] / "cameras.txt").read_text().count("OPENCV_FISHEYE") == 1
