"""read_any_points / read_any_measurements choose BINGO, Metashape markers and COLMAP models by content."""
import numpy as np
import pytest
from test_bingo_metashape import METASHAPE, PIX_MM, H, W, pix4d_bingo_text, truth
from test_colmap_tracks import write_text_model

from dgcal.fields.errors import InputError
from dgcal.fields.io.gcp_files import read_any_measurements, read_any_points


def test_bingo_by_content_whatever_its_name(tmp_path):
    rows = truth()
    p = tmp_path / "export.csv"             # the extension says nothing
    p.write_text(pix4d_bingo_text(rows))
    with pytest.raises(InputError, match="field 'pixel_size_mm'"):
        read_any_measurements(p)
    names = sorted({r[0] for r in rows})
    m, crs, pts = read_any_measurements(p, image_size=(W, H), pixel_size_mm=PIX_MM, image_names=names)
    assert crs is None and pts is None and set(m.image) == set(names)
    assert np.allclose(m.xy, [r[2:] for r in rows], atol=1e-3)


def test_metashape_by_content(tmp_path):
    p = tmp_path / "markers.txt"
    p.write_text(METASHAPE)
    m, crs, pts = read_any_measurements(p)
    assert len(m) == 4 and list(pts.role) == ["control", "check"] and "UTM zone 50N" in crs
    pts2, crs2 = read_any_points(p)
    assert list(pts2.ids) == ["GCP1", "CP1"] and crs2 == crs


def test_colmap_folder_or_its_images_file(tmp_path):
    write_text_model(tmp_path / "sparse", np.random.default_rng(2))
    m, crs, pts = read_any_measurements(tmp_path / "sparse")
    m2, _, _ = read_any_measurements(tmp_path / "sparse" / "images.txt")
    assert len(m) == len(m2) > 0 and crs is None and pts is None and m.id[0].startswith("colmap_")


def test_dgcal_csv_still_read(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text("image,id,x,y\na.jpg,1,10,20\n")
    m, crs, pts = read_any_measurements(p)
    assert m.xy.tolist() == [[10.0, 20.0]] and crs is None and pts is None
