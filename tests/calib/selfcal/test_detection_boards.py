"""Standard-board detection on rendered images against the simulator's truth: ChArUco (inverted print, back face),
chessboard, ArUco grid; video files with the frame choice listed; one-line errors for bad input."""
import json

import cv2
import numpy as np
import pytest

from dgcal.calib.selfcal.board_detection import BoardDetector
from dgcal.calib.selfcal.calibration import calibrate_camera
from dgcal.calib.selfcal.frames import Candidate, choose_frames
from dgcal.calib.selfcal.detection import Detection
from dgcal.cli import main
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import read_measurements
from dgcal.fields.targets.boards import Board
from dgcal.sim.camera_field import simulate_board_views

SIZE = (640, 480)
CHARUCO = Board("charuco", 7, 5, 0.04, 0.03, "DICT_4X4_100", inverted=True)


def corner_errors(out, meas):
    """Detected minus true pixel of every detected corner (px), and the number of true corners."""
    tm = read_measurements(out / "truth_measurements.csv")
    key = {(a, i): p for a, i, p in zip(tm.image, tm.id, tm.xy)}
    e = [p - key[(a, i)] for a, i, p in zip(meas.image, meas.id, meas.xy) if (a, i) in key]
    missing = sum((a, i) not in key for a, i in zip(meas.image, meas.id))
    return np.array(e), len(tm), missing


@pytest.fixture(scope="module")
def charuco_views(tmp_path_factory):
    out = tmp_path_factory.mktemp("charuco")
    simulate_board_views(out, CHARUCO, seed=3, n_images=8, image_size=SIZE)
    return out


@pytest.mark.parametrize("board", [CHARUCO, Board("chessboard", 9, 6, 0.03),
                                   Board("aruco-grid", 5, 4, 0.05, 0.04, "DICT_5X5_250", first_id=5)],
                         ids=["charuco-inverted", "chessboard", "aruco-grid"])
def test_detected_corners_match_truth(board, tmp_path):
    out = tmp_path / "v"
    simulate_board_views(out, board, seed=3, n_images=8, image_size=SIZE)
    det = BoardDetector(board)
    img, ids, xy = [], [], []
    for f in sorted((out / "images").iterdir()):
        d = det.detect(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE))
        img += [f.name] * len(d.ids)
        ids += list(d.ids)
        xy.append(d.xy)
    from dgcal.fields.io.formats import Measurements
    m = Measurements(np.array(img, dtype=object), np.array(ids, dtype=object), np.vstack(xy),
                     np.full((len(ids), 2), np.nan))
    e, n_true, wrong = corner_errors(out, m)
    assert wrong == 0                           # no corner reported that is not in view (ids are the board's own)
    assert len(e) >= 0.6 * n_true, (len(e), n_true)
    rms = float(np.sqrt(np.mean(e ** 2)))
    assert rms < 0.08, rms
    assert np.median(np.abs(e)) < 0.035


def test_back_face_is_recognised_without_an_option(tmp_path):
    front, back = tmp_path / "front", tmp_path / "back"
    simulate_board_views(front, CHARUCO, seed=4, n_images=4, image_size=SIZE)
    simulate_board_views(back, CHARUCO, seed=4, n_images=4, image_size=SIZE, mirrored=True)
    det = BoardDetector(CHARUCO)
    errs = []
    for f in sorted((back / "images").iterdir()):
        d = det.detect(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE))
        d_front = det.detect(cv2.imread(str(front / "images" / f.name), cv2.IMREAD_GRAYSCALE))
        assert d.stats["mirrored"] and not d_front.stats["mirrored"]
        assert len(d.ids) == len(d_front.ids) > 0 and set(d.ids) == set(d_front.ids)
        # the back-face image is the front one flipped: the same physical corners, at x' = W - 1 - x
        o, of = np.argsort(d.ids.astype(int)), np.argsort(d_front.ids.astype(int))
        assert np.allclose(d.xy[o, 0], SIZE[0] - 1 - d_front.xy[of, 0], atol=1e-6)
        assert np.allclose(d.xy[o, 1], d_front.xy[of, 1], atol=1e-6)
        tm = read_measurements(back / "truth_measurements.csv")
        key = {i: p for a, i, p in zip(tm.image, tm.id, tm.xy) if a == f.name}
        errs.append(np.array([p - key[i] for i, p in zip(d.ids, d.xy)]))
    assert np.median(np.abs(np.vstack(errs))) < 0.05
    never = BoardDetector(Board(**{**CHARUCO.to_dict(), "mirrored": False}))
    img = cv2.imread(str(sorted((back / "images").iterdir())[0]), cv2.IMREAD_GRAYSCALE)
    assert len(never.detect(img).ids) == 0


def write_video(path, frames, fps=5):
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (frames[0].shape[1], frames[0].shape[0]),
                        False)
    for f in frames:
        w.write(f)
    w.release()


def test_video_frames_are_chosen_and_listed(charuco_views, tmp_path, capsys):
    imgs = [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in sorted((charuco_views / "images").iterdir())]
    blurred = cv2.GaussianBlur(imgs[0], (0, 0), 3.0)
    # a still board (repeated frames), a blurred frame and an empty frame among the views
    frames = [imgs[0], imgs[0], blurred] + imgs[1:] + [np.full_like(imgs[0], 90)]
    video = tmp_path / "board.mp4"
    write_video(video, frames)
    board_toml = tmp_path / "board.toml"
    board_toml.write_text(CHARUCO.to_toml())
    out = tmp_path / "out"
    rc = main(["camera", "--board", str(board_toml), "--images", str(video), "--out", str(out), "--no-report"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    rows = (out / "frames.csv").read_text().splitlines()
    assert rows[0] == "label,source,frame,time_s,corners,sharpness,status"
    status = {r.split(",")[0]: r.split(",")[-1] for r in rows[1:]}
    assert len(status) == len(frames)
    assert status["board.mp4#000000"] == "chosen"
    assert status["board.mp4#000001"].startswith("repeat of board.mp4#000000")
    assert status[f"board.mp4#{len(frames) - 1:06d}"].startswith("too few corners")
    assert status["board.mp4#000002"].startswith(("blurred", "too few corners"))
    cj = json.loads((out / "camera.json").read_text())
    assert cj["frames"]["chosen"] == [k for k, v in status.items() if v == "chosen"]
    assert cj["board"]["type"] == "charuco"
    # every chosen frame is in the adjustment or listed as left out (a few corners of a board's edge: no pose)
    assert cj["n_images"] + len(cj["dropped_images"]) == len(cj["frames"]["chosen"]) and cj["n_images"] >= 3
    meas = read_measurements(out / "measurements.csv")
    assert set(meas.image) == set(cj["frames"]["chosen"])
    assert "frames:" in cap.out


def test_coverage_rule_keeps_the_frames_that_add_coverage():
    # 3 frames in the same corner of the frame, one in another: with 2 frames allowed, the other is kept
    def cand(label, x0, sharp):
        xy = np.array([[x0 + i * 10.0, 100 + j * 10.0] for j in range(3) for i in range(3)])
        return Candidate(label, None, 0, 0.0, Detection(np.array([str(k) for k in range(9)], dtype=object), xy,
                                                         np.full((9, 2), np.nan), {}), sharp)
    cands = [cand("a", 10, 1.0), cand("b", 12, 1.1), cand("c", 14, 1.05), cand("d", 500, 0.9)]
    choose_frames(cands, (640, 480), lambda ids: np.column_stack([np.arange(len(ids)) % 3, np.arange(len(ids)) // 3])
                  * 0.01, max_frames=2)
    st = {c.label: c.status for c in cands}
    assert st["b"] == "chosen" and st["d"] == "chosen"       # the sharpest, then the one adding coverage
    assert st["a"].startswith("not needed") and st["c"].startswith("not needed")


def _fails_cleanly(args, capsys, out, *names):
    rc = main(["camera", *map(str, args)])
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if ln]
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith("dgcal camera: error:") and all(n in err[0] for n in names), err[0]
    assert not out.exists() or not any(out.iterdir())
    return err[0]


def test_bad_input_is_a_one_line_error(charuco_views, tmp_path, capsys):
    out = tmp_path / "out"
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"not a video" * 50)
    good = tmp_path / "board.toml"
    good.write_text(CHARUCO.to_toml())
    _fails_cleanly(["--board", good, "--images", bad, "--out", out], capsys, out, "broken.mp4", "cannot open")
    # an unknown dictionary
    unk = tmp_path / "unknown.toml"
    unk.write_text(CHARUCO.to_toml().replace("DICT_4X4_100", "DICT_4X4_123"))
    _fails_cleanly(["--board", unk, "--images", charuco_views / "images", "--out", out], capsys, out,
                   "unknown.toml:6", "dictionary")
    # a board that matches no marker (another dictionary), and one printed the other way round
    other = tmp_path / "other.toml"
    other.write_text(CHARUCO.to_toml().replace("DICT_4X4_100", "DICT_6X6_250"))
    _fails_cleanly(["--board", other, "--images", charuco_views / "images", "--out", out], capsys, out,
                   "other.toml", "no targets", "dictionary")
    pol = tmp_path / "polarity.toml"
    pol.write_text(CHARUCO.to_toml().replace("inverted = true", "inverted = false"))
    msg = _fails_cleanly(["--board", pol, "--images", charuco_views / "images", "--out", out], capsys, out,
                         "polarity.toml", "inverted = true")
    assert "corners are found" in msg
    _fails_cleanly(["--board", good, "--images", tmp_path / "nope.mp4", "--out", out], capsys, out, "nope.mp4")


def test_field_json_of_a_board_detects_that_board(charuco_views):
    # dgcal field --board writes field.csv + field.json (kind dgcal-board): --field alone then finds the board
    cal = calibrate_camera(charuco_views / "field.csv", images=charuco_views / "images", progress=False)
    assert cal.board == CHARUCO and cal.ba.n_observations > 50
    with pytest.raises(InputError, match="give a target field"):
        calibrate_camera(None, images=charuco_views / "images")
