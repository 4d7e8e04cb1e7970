"""Pix4D's GCP file and marks file (the companions of its BINGO export), read alone and through read_any_*."""
import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.io.gcp_files import read_any_measurements, read_any_points
from dgcal.fields.io.pix4d_marks import is_pix4d_gcps, is_pix4d_marks, read_pix4d_gcps, read_pix4d_marks

GCPS = "GCP0,2532795.105,1152094.639,395.883,0.02,0.03\nGCP1,2532728.805,1152079.825,396.619,0.02,0.03\n"
GCPS4 = "GCP0,2532795.105,1152094.639,395.883\n"
MARKS = ("DJI_0001.JPG,GCP0,4096.5,2730.5\nDJI_0002.JPG,GCP0,100.25,50.75,2.0\n"
         "C:\\\\flight\\\\DJI_0003.JPG,GCP1,0.5,0.5\n")


def test_gcp_file(tmp_path):
    p = tmp_path / "gcps.txt"
    p.write_text("# label,X,Y,Z,acc_h,acc_v\n" + GCPS)
    assert is_pix4d_gcps(p) and not is_pix4d_marks(p)
    pts, crs = read_any_points(p)
    assert crs is None and list(pts.ids) == ["GCP0", "GCP1"] and np.allclose(pts.sigma[1], [0.02, 0.02, 0.03])
    assert np.allclose(pts.xyz[0], [2532795.105, 1152094.639, 395.883]) and set(pts.role) == {"control"}
    p.write_text(GCPS4)
    assert np.isnan(read_pix4d_gcps(p).sigma).all()


def test_marks_file_corner_origin(tmp_path):
    p = tmp_path / "marks.csv"
    p.write_text(MARKS)
    assert is_pix4d_marks(p) and not is_pix4d_gcps(p)
    m, crs, pts = read_any_measurements(p)
    assert list(m.image) == ["DJI_0001.JPG", "DJI_0002.JPG", "DJI_0003.JPG"] and list(m.id) == ["GCP0"] * 2 + ["GCP1"]
    assert np.allclose(m.xy, [[4096.0, 2730.0], [99.75, 50.25], [0.0, 0.0]]) and m.stated_sigma is None
    m2 = read_pix4d_marks(p, pixel_shift=0.0, fifth="sigma")
    assert np.allclose(m2.xy[2], [0.5, 0.5]) and m2.sigma[1].tolist() == [2.0, 2.0] and np.isnan(m2.sigma[0]).all()


@pytest.mark.parametrize("text, reader, line, field", [
    (GCPS.replace("395.883", "3e99"), read_pix4d_gcps, 1, "Z"),
    (GCPS.replace("0.02,0.03\nGCP1", "0.02,-1\nGCP1"), read_pix4d_gcps, 1, "accuracy_v"),
    (GCPS.replace("GCP1", "GCP0"), read_pix4d_gcps, 2, "label"),
    (MARKS.replace("100.25", "x"), read_pix4d_marks, 2, "x"),
    (MARKS.replace("GCP1", "GCP0").replace("DJI_0003", "DJI_0001"), read_pix4d_marks, 3, "label"),
])
def test_errors_name_line_and_field(tmp_path, text, reader, line, field):
    p = tmp_path / "f.txt"
    p.write_text(text)
    with pytest.raises(InputError) as exc:
        reader(p)
    assert f"f.txt:{line}:" in str(exc.value) and f"field '{field}'" in str(exc.value)
