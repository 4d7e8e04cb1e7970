"""MRK rows paired with P1 image files (`DJI_<yyyymmddhhmmss>_<index>.JPG`) by index pattern or time order."""
import numpy as np
import pytest
from test_pos_io_sbet_marks import MRK

from dgcal.fields.errors import InputError
from dgcal.pos.events import (index_pattern, pair_by_index, pair_by_time_order, read_any_events, read_mrk)

P1_NAMES = ["DJI_20230712132737_0001.JPG", "DJI_20230712132739_0002.JPG", "DJI_20230712132741_0003.JPG"]


@pytest.fixture
def mrk(tmp_path):
    p = tmp_path / "DJI_202307121327_001_Timestamp.MRK"
    p.write_text(MRK)
    return p


def test_pair_p1_names_by_index(mrk):
    rec = read_mrk(mrk)
    ev = rec.events("DJI_{any}_{index}.JPG", image_names=P1_NAMES[::-1])
    assert list(ev.image) == P1_NAMES and np.array_equal(ev.t, rec.t)
    ev2 = read_any_events(mrk, image_names=[n.lower() for n in P1_NAMES], name_pattern="re:.*_(?P<index>\\d{4})\\.jpg")
    assert list(ev2.t) == list(rec.t)
    # extra files that do not match the pattern are left alone; a subset of images pairs with its rows
    ev3 = pair_by_index(rec, P1_NAMES[1:] + ["notes.txt"], "DJI_{any}_{index}.JPG")
    assert list(ev3.image) == P1_NAMES[1:] and list(ev3.t) == list(rec.t[1:])


def test_pair_by_time_order(mrk):
    rec = read_mrk(mrk)
    ev = read_any_events(mrk, image_names=P1_NAMES[::-1], pairing="time")
    assert list(ev.image) == P1_NAMES and np.array_equal(ev.t, rec.t)
    with pytest.raises(InputError, match="3 events but 2 images"):
        pair_by_time_order(rec, P1_NAMES[:2])


def test_pairing_errors(mrk):
    rec = read_mrk(mrk)
    with pytest.raises(InputError, match=r"1 image\(s\) have no MRK row, e.g. 'DJI_20230712132743_0004.JPG'"):
        pair_by_index(rec, P1_NAMES + ["DJI_20230712132743_0004.JPG"])
    with pytest.raises(InputError, match="both carry photo index 2"):
        pair_by_index(rec, P1_NAMES + ["DJI_20230712139999_0002.JPG"])
    with pytest.raises(InputError, match="no image name matches"):
        pair_by_index(rec, ["IMG_1.JPG"])
    with pytest.raises(InputError, match="field 'name_pattern'"):
        rec.events("DJI_{any}_{index}.JPG")          # {any} cannot make names
    with pytest.raises(InputError, match="exactly one"):
        index_pattern("DJI_{any}.JPG")
    with pytest.raises(InputError, match="needs the image folder"):
        read_any_events(mrk, pairing="time")
    # the default names stay DJI_0001.JPG ...
    assert list(read_any_events(mrk).image) == ["DJI_0001.JPG", "DJI_0002.JPG", "DJI_0003.JPG"]


def test_mrk_centres_are_the_rows_positions_in_the_map_crs(mrk):
    import pyproj
    from dgcal.pos.events import mrk_centres
    rec = read_mrk(mrk)
    ev = pair_by_index(rec, P1_NAMES[1:], "DJI_{any}_{index}.JPG")
    c = mrk_centres(rec, "EPSG:32650", ev)
    assert list(c.image) == P1_NAMES[1:] and list(c.lines) == [2, 4]
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32650", always_xy=True).transform(rec.lon[1:], rec.lat[1:])
    np.testing.assert_allclose(c.xyz, np.column_stack([x, y, rec.h[1:]]), atol=1e-6)
    np.testing.assert_allclose(c.sigma[:, :3], rec.sigma_nev_m[1:][:, [1, 0, 2]])
    assert np.isnan(c.opk).all() and list(mrk_centres(rec, "EPSG:32650").image)[0] == "DJI_0001.JPG"
    with pytest.raises(InputError, match="projected CRS"):
        mrk_centres(rec, "EPSG:4326")


def test_pos_cli_pairs_mrk_rows_with_an_image_folder(mrk, tmp_path, capsys):
    """`dgcal pos --events X.MRK --event-images DIR --mrk-names PATTERN`: the options reach the events reader
    (the library call `dgcal pos` makes) and pair the P1's files; a missing folder names its flag."""
    from dgcal.cli import build_parser, main
    from dgcal.commands.pos import pos_options
    from dgcal.fields.io.image_folders import list_image_names
    folder = tmp_path / "images"
    folder.mkdir()
    for n in P1_NAMES:
        (folder / n).write_bytes(b"\xff\xd8")
    argv = ["pos", "--mode", "lc", "--imu", "imu.txt", "--gnss", "g.csv", "--out", str(tmp_path / "o"),
            "--events", str(mrk), "--event-images", str(folder), "--mrk-names", "DJI_{any}_{index}.JPG"]
    opts = pos_options(build_parser(argv).parse_args(argv))
    names = list_image_names(opts.event_images, "event_images", raw=True)
    ev = read_any_events(opts.events, opts.events_format, opts.mrk_names, names, opts.mrk_pairing)
    assert list(ev.image) == P1_NAMES
    argv[argv.index("--event-images") + 1] = str(tmp_path / "nowhere")
    assert main(argv) == 2
    assert "--event-images" in capsys.readouterr().err
