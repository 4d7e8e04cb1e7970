"""Board descriptions (TOML): dgcal's and caliscope's keys, one-line errors, OpenCV's corner ids and coordinates,
the printed texture against OpenCV's own board image, and `dgcal field --board`."""
import json

import cv2
import numpy as np
import pytest

from dgcal.cli import main
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import read_points
from dgcal.fields.targets.boards import Board, board_texture, load_board_layout, read_board


def test_caliscope_board_file_is_read(shared_data):
    b = read_board(shared_data / "charuco-webcam" / "charuco.toml")
    assert b.type == "charuco" and (b.columns, b.rows) == (4, 5)
    assert b.square_m == pytest.approx(0.054) and b.marker_m == pytest.approx(0.75 * 0.054)
    assert b.dictionary == "DICT_4X4_1000" and b.inverted and not b.legacy and b.first_id == 0
    assert b.n_corners == 12 and b.n_markers == 10


def test_dgcal_board_file_and_corner_ids(tmp_path):
    p = tmp_path / "b.toml"
    p.write_text('type = "aruco-grid"\ncolumns = 3\nrows = 2\nsquare_m = 0.05\nmarker_m = 0.04\n'
                 'dictionary = "DICT_5X5_250"\nfirst_id = 7\nmirrored = false\n')
    b = read_board(p)
    assert b.first_id == 7 and b.mirrored is False and b.n_corners == 24
    ref = cv2.aruco.GridBoard((3, 2), 0.04, 0.01, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_250),
                              np.arange(7, 13))
    # corner 4 i + k is corner k of the i-th marker (OpenCV's object points)
    assert np.allclose(b.corner_xyz(), np.asarray(ref.getObjPoints()).reshape(-1, 3))
    c = Board("charuco", 5, 4, 0.03, 0.02, "DICT_4X4_50")
    cv = cv2.aruco.CharucoBoard((5, 4), 0.03, 0.02, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    assert np.allclose(c.corner_xyz(), cv.getChessboardCorners())       # OpenCV's ChArUco corner ids
    assert list(c.corner_ids()[:3]) == ["0", "1", "2"]


@pytest.mark.parametrize("board", [Board("charuco", 5, 4, 0.03, 0.02, "DICT_4X4_50"),
                                   Board("charuco", 6, 6, 0.03, 0.022, "DICT_5X5_100", legacy=True),
                                   Board("charuco", 4, 5, 0.054, 0.0405, "DICT_4X4_1000", inverted=True),
                                   Board("aruco-grid", 4, 3, 0.05, 0.04, "DICT_6X6_250", first_id=11)])
def test_texture_matches_opencv_board_image(board):
    grey, _ = board_texture(board, board.square_m / 200, margin_m=0.0)
    ref = board.cv_board().generateImage((grey.shape[1], grey.shape[0]))
    if board.inverted:
        ref = 255 - ref
    # OpenCV snaps its marker cells to whole pixels: a few edge pixels differ at this resolution
    assert np.mean(np.abs(np.rint(grey * 255) - ref) > 128) < 0.012


@pytest.mark.parametrize("text, field, line", [
    ('type = "charuco"\ncolumns = 4\nrows = 5\nsquare_m = 0.05\nmarker_m = 0.04\ndictionary = "DICT_9X9_50"\n',
     "dictionary", 6),
    ('type = "circles"\ncolumns = 4\nrows = 5\nsquare_m = 0.05\n', "type", 1),
    ('type = "charuco"\ncolumns = 4\nrows = 5\nsquare_m = 0.05\nmarker_m = 0.06\ndictionary = "DICT_4X4_50"\n',
     "marker_m", 5),
    ('type = "chessboard"\ncolumns = 4\nrows = 5\nsquare_m = -1\n', "square_m", 4),
    ('type = "charuco"\ncolumns = 40\nrows = 50\nsquare_m = 0.05\nmarker_m = 0.04\ndictionary = "DICT_4X4_50"\n',
     "first_id", None),
])
def test_bad_board_files_are_one_line_errors(tmp_path, text, field, line):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        read_board(p)
    msg = str(e.value)
    assert "bad.toml" in msg and f"field '{field}'" in msg and "\n" not in msg
    if line is not None:
        assert f"bad.toml:{line}:" in msg


def test_not_toml_names_the_line(tmp_path):
    p = tmp_path / "x.toml"
    p.write_text("columns = 4\nrows = = 5\n")
    with pytest.raises(InputError, match=r"x.toml:2: not valid TOML"):
        read_board(p)


def test_field_command_writes_board_field_and_sheet(shared_data, tmp_path, capsys):
    out = tmp_path / "f"
    assert main(["field", "--board", str(shared_data / "charuco-webcam" / "charuco.toml"), "--out", str(out)]) == 0
    for name in ("field.csv", "field.json", "board.toml", "field.pdf", "field.png"):
        assert (out / name).is_file(), name
    pts = read_points(out / "field.csv")
    assert list(pts.ids) == [str(k) for k in range(12)]
    assert np.allclose(pts.xyz[4], [0.108, 0.108, 0.0])
    assert load_board_layout(out / "field.csv") == read_board(out / "board.toml")
    assert json.loads((out / "field.json").read_text())["kind"] == "dgcal-board"
    assert (out / "field.pdf").read_bytes()[:4] == b"%PDF"
    # the PNG raster is the inverted print: black where OpenCV's image is white
    png = cv2.imread(str(out / "field.png"), cv2.IMREAD_GRAYSCALE)
    assert png is not None and png.mean() < 200


def test_field_command_bad_dictionary_writes_nothing(tmp_path, capsys):
    p = tmp_path / "b.toml"
    p.write_text('columns = 4\nrows = 5\nsquare_m = 0.05\nmarker_m = 0.04\ndictionary = "DICT_4X4_9999"\n')
    out = tmp_path / "o"
    assert main(["field", "--board", str(p), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "b.toml:5" in err[0] and "dictionary" in err[0]
    assert not out.exists() or not any(out.iterdir())
