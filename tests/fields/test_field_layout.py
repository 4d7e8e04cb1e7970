"""The rotating-plate field: layout, ids, files, printable outputs and their detectability."""
import json
import re

import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.targets.printing import print_raster
from dgcal.fields.targets.texture import field_texture
from dgcal.fields.io.formats import read_points
from dgcal.fields.targets.plate import TargetField, load_layout, nonplanar_field, write_field


def test_default_field_has_enough_unique_targets_on_the_plate():
    tf = TargetField()
    ids, num, xyz = tf.targets()
    assert len(ids) >= 200 and tf.n_printed_markers() >= 200
    assert len(set(ids)) == len(ids) and len(set(num)) == len(num)
    assert all(re.fullmatch(r"C\d{4}", i) for i in ids)
    # every target's four squares lie on the plate: their far corners are within the radius
    far = np.hypot(np.abs(xyz[:, 0]) + tf.square_m, np.abs(xyz[:, 1]) + tf.square_m)
    assert np.all(far <= tf.diameter_m / 2 + 1e-9)
    assert np.all(xyz[:, 2] == 0)
    # id C<rr><cc> <-> plate coordinates (origin at the centre, y up)
    rr = np.array([int(i[1:3]) for i in ids])
    cc = np.array([int(i[3:5]) for i in ids])
    half = tf.board_size_m / 2
    assert np.allclose(xyz[:, 0], (cc + 1) * tf.square_m - half)
    assert np.allclose(xyz[:, 1], half - (rr + 1) * tf.square_m)
    assert np.array_equal(num, rr * (tf.n_squares - 1) + cc)


def test_ids_are_stable_for_the_same_board():
    a, b = TargetField(), TargetField(diameter_m=2.4, square_m=0.08, marker_m=0.05)
    assert list(a.targets()[0]) == list(b.targets()[0])


def test_texture_matches_opencv_board_image():
    tf = TargetField(diameter_m=0.3, square_m=0.029, marker_m=0.021)  # 29 px squares, 3 px marker cells
    grey, alpha = field_texture(tf, 0.001)
    ref = tf.board().generateImage((grey.shape[1], grey.shape[0]), marginSize=0, borderBits=1) / 255.0
    printed = np.kron(tf.square_printed(), np.ones((29, 29), bool))
    assert printed.sum() > 0.4 * printed.size
    assert np.abs(grey - ref)[printed].max() < 1e-3
    assert np.all(grey[~printed] == 1.0)
    assert alpha[grey.shape[0] // 2, grey.shape[1] // 2] == 1.0 and alpha[0, 0] == 0.0


def test_nonplanar_field_levels_and_block_edges():
    tf = nonplanar_field()
    ids, _, xyz = tf.targets()
    assert set(np.round(xyz[:, 2], 6)) == {0.0, 0.1, 0.2}
    assert len(ids) >= 200
    h = tf.square_height()
    n = tf.n_squares
    for i in ids:
        r, c = int(i[1:3]), int(i[3:5])
        assert len({h[r, c], h[r, c + 1], h[r + 1, c], h[r + 1, c + 1]}) == 1  # no target straddles an edge
    assert len(ids) < len(TargetField().targets()[0]) and n == TargetField().n_squares


def test_field_csv_and_layout_round_trip(tmp_path):
    tf = nonplanar_field(square_m=0.1, marker_m=0.07, dictionary="DICT_4X4_1000")
    pts = write_field(tmp_path / "field.csv", tf)
    back = read_points(tmp_path / "field.csv")
    assert list(back.ids) == list(pts.ids)
    assert np.allclose(back.xyz, pts.xyz, atol=1e-6) and np.allclose(back.sigma, pts.sigma)
    lay = load_layout(tmp_path / "field.csv")
    assert lay == tf
    (tmp_path / "field.json").write_text("{not json")
    with pytest.raises(InputError, match="field.json"):
        load_layout(tmp_path / "field.csv")


@pytest.mark.parametrize("kw", [dict(marker_m=0.09), dict(square_m=-1.0), dict(dictionary="DICT_9X9"),
                                dict(dictionary="DICT_4X4_50")])
def test_bad_field_parameters_raise(kw):
    with pytest.raises(InputError):
        TargetField(**kw)


def test_field_command_writes_true_scale_outputs(tmp_path):
    from PIL import Image

    from dgcal.cli import main
    out = tmp_path / "f"
    assert main(["field", "--out", str(out), "--diameter", "0.8", "--dpi", "50"]) == 0
    pts = read_points(out / "field.csv")
    assert len(pts.ids) == len(TargetField(diameter_m=0.8).targets()[0])
    im = Image.open(out / "field.png")
    side_px = TargetField(diameter_m=0.8).board_size_m / 0.0254 * 50
    assert abs(im.size[0] - side_px) <= 1 and abs(im.info["dpi"][0] - 50) < 0.02  # PNG stores pixels per metre
    media = re.search(rb"MediaBox \[ 0 0 ([\d.]+) ([\d.]+) \]", (out / "field.pdf").read_bytes())
    assert abs(float(media.group(1)) - 0.8 / 0.0254 * 72) < 0.01  # page = the 0.8 m board square
    assert json.loads((out / "field.json").read_text())["diameter_m"] == 0.8
    bad = tmp_path / "bad"
    assert main(["field", "--out", str(bad), "--marker", "0.2"]) == 2
    assert not bad.exists() or not any(bad.iterdir())


def test_printed_raster_is_detected_at_the_right_places():
    from dgcal.calib.selfcal.detection import detect_image
    tf = TargetField(diameter_m=0.9, square_m=0.08, marker_m=0.06)
    img = print_raster(tf, 25.4)  # 1 mm pixels: square edges fall on pixel edges
    det = detect_image(img, tf)
    ids, _, xyz = tf.targets()
    assert set(det.ids) == set(ids)
    want = {i: ((p[0] + tf.board_size_m / 2) * 1000 - 0.5, (tf.board_size_m / 2 - p[1]) * 1000 - 0.5)
            for i, p in zip(ids, xyz)}
    err = np.array([det.xy[k] - want[i] for k, i in enumerate(det.ids)])
    assert np.abs(err).max() < 0.05


def test_tiled_print_matches_the_plate():
    import io

    from PIL import Image

    from dgcal.fields.targets.printing import tile_figure, tile_grid
    tf = TargetField(diameter_m=0.9)
    tiles = tile_grid(tf, "A4")
    ref = print_raster(tf, 25.4)
    S = ref.shape[0]
    # the tiles cover the plate: every target lies in some tile, away from its edge by half the overlap
    _, _, xyz = tf.targets()
    bx, by = xyz[:, 0] + tf.board_size_m / 2, tf.board_size_m / 2 - xyz[:, 1]
    inside = np.zeros(len(bx), bool)
    for _, _, x0, y0, x1, y1 in tiles:
        inside |= (bx >= x0 + 0.005) & (bx <= x1 - 0.005) & (by >= y0 + 0.005) & (by <= y1 - 0.005)
    assert inside.all()
    r, c, x0, y0, x1, y1 = tiles[len(tiles) // 2]
    buf = io.BytesIO()
    tile_figure(tf, tiles[len(tiles) // 2], "A4").savefig(buf, format="png", dpi=25.4)  # 1 mm pixels
    sheet = np.array(Image.open(buf).convert("L"))
    assert sheet.shape == (210, 297)  # landscape A4 at true scale
    X0, Y0 = round((x0 - 0.01) * 1000), round((y0 - 0.01) * 1000)
    a0, a1 = max(0, round(y0 * 1000) + 2), min(S, round(y1 * 1000) - 2)
    b0, b1 = max(0, round(x0 * 1000) + 2), min(S, round(x1 * 1000) - 2)
    sub, want = sheet[a0 - Y0:a1 - Y0, b0 - X0:b1 - X0].astype(int), ref[a0:a1, b0:b1].astype(int)
    assert (want < 128).mean() > 0.2
    assert np.mean(np.abs(sub - want) > 100) < 0.005
