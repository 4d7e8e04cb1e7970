"""Ground-control file formats: ODM gcp_list.txt round trip and errors, MicMac XML readers."""
import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import Measurements, Points
from dgcal.fields.io.gcp_files import (is_odm_gcp_list, odm_crs_to_pyproj, read_any_measurements,
                                       read_micmac_measurements, read_micmac_orientation, read_micmac_points,
                                       read_odm_gcp_list, write_odm_gcp_list)


def _sample():
    pts = Points(np.array(["A", "B"], dtype=object), np.array([[327000.123456, 2655000.5, 101.25],
                                                               [327050.0, 2655020.75, 99.5]]),
                 np.full((2, 3), np.nan), np.array(["control", "control"], dtype=object))
    meas = Measurements(np.array(["i1.jpg", "i2.jpg", "i1.jpg"], dtype=object), np.array(["A", "A", "B"], dtype=object),
                        np.array([[10.25, 20.5], [300.125, 400.0], [5.0, 6.0]]), np.full((3, 2), np.nan))
    return pts, meas


def test_odm_round_trip(tmp_path):
    pts, meas = _sample()
    p = tmp_path / "gcp_list.txt"
    write_odm_gcp_list(p, "EPSG:32651", pts, meas)
    assert is_odm_gcp_list(p)
    crs, pts2, meas2 = read_odm_gcp_list(p)
    assert crs == "EPSG:32651"
    assert list(pts2.ids) == ["A", "B"]
    np.testing.assert_allclose(pts2.xyz, pts.xyz, atol=1e-6)
    np.testing.assert_allclose(meas2.xy, meas.xy, atol=1e-4)
    assert list(meas2.image) == list(meas.image) and list(meas2.id) == list(meas.id)
    m3, crs3, p3 = read_any_measurements(p)
    assert crs3 == "EPSG:32651" and len(m3) == 3 and len(p3.ids) == 2


def test_odm_variants_and_errors(tmp_path):
    assert odm_crs_to_pyproj("WGS84 UTM 51N") == "EPSG:32651"
    assert odm_crs_to_pyproj("WGS84 UTM 33S") == "EPSG:32733"
    p = tmp_path / "gcp_list.txt"
    p.write_text("+proj=utm +zone=51 +datum=WGS84\n1 2 3 10 20 a.jpg\n1 2 3 11 21 b.jpg\n")
    crs, pts, meas = read_odm_gcp_list(p)
    assert crs.startswith("+proj=utm") and len(pts.ids) == 1 and len(meas) == 2   # unnamed: named by coordinates
    p.write_text("EPSG:32651\n1 2 3 10 x a.jpg P1\n")
    with pytest.raises(InputError, match=r"gcp_list.txt:2: field 'im_y': not a number"):
        read_odm_gcp_list(p)
    p.write_text("EPSG:32651\n1 2 3 10 20\n")
    with pytest.raises(InputError, match=r"gcp_list.txt:2: expected"):
        read_odm_gcp_list(p)
    p.write_text("EPSG:32651\n1 2 3 10 20 a.jpg P1\n1 2 4 10 20 b.jpg P1\n")
    with pytest.raises(InputError, match=r"gcp_list.txt:3: .*other coordinates than on line 2"):
        read_odm_gcp_list(p)
    p.write_text("EPSG:32651\n1 2 3 10 20 a.jpg P1\n1 2 3 11 20 a.jpg P1\n")
    with pytest.raises(InputError, match=r"measured twice"):
        read_odm_gcp_list(p)


def test_micmac_readers_real(shared_data):
    d = shared_data / "micmac-saisies"
    pts = read_micmac_points(d / "Ground-Pts3D.xml")
    assert list(pts.ids[:3]) == ["Stone-1", "Stone-2", "Stone-3"]
    np.testing.assert_allclose(pts.xyz[0], [0.182895665614618341, -3.78002060469805157, 2.56022810571964277])
    meas = read_micmac_measurements(d / "GroundMeasure.xml")
    assert len(meas) == 19 and "u-of-You" in set(meas.id)
    i = list(zip(meas.image, meas.id)).index(("IMGP4168.JPG", "Grille"))
    np.testing.assert_allclose(meas.xy[i], [362.602015084684353, 1078.96450589692108])
    R, C = read_micmac_orientation(d / "Ori-Ground_mm3d" / "Orientation-IMGP4167.JPG.xml")
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    np.testing.assert_allclose(C, [5.20448828567060851, 1.49496779535545343, 2.11770763380631921])


def test_micmac_errors_name_line_and_field(tmp_path):
    p = tmp_path / "g.xml"
    p.write_text("<DicoAppuisFlottant>\n <OneAppuisDAF>\n  <Pt>1 2</Pt>\n  <NamePt>A</NamePt>\n </OneAppuisDAF>\n"
                 "</DicoAppuisFlottant>\n")
    with pytest.raises(InputError, match=r"g.xml:2: field 'Pt': expected 3 numbers"):
        read_micmac_points(p)
    p.write_text("<SetOfMesureAppuisFlottants><MesureAppuiFlottant1Im><NameIm>a</NameIm>\n"
                 "<OneMesureAF1I><NamePt>A</NamePt><PtIm>1 x</PtIm></OneMesureAF1I>\n"
                 "</MesureAppuiFlottant1Im></SetOfMesureAppuisFlottants>")
    with pytest.raises(InputError, match=r"g.xml:2: field 'PtIm': not a number"):
        read_micmac_measurements(p)
    p.write_text("<Other/>")
    with pytest.raises(InputError, match="expected a <DicoAppuisFlottant>"):
        read_micmac_points(p)
    p.write_text("<DicoAppuisFlottant><broken>")
    with pytest.raises(InputError, match="invalid XML"):
        read_micmac_points(p)
