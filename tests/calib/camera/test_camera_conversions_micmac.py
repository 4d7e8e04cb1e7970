"""MicMac calibrations (V1 AutoCal and MMVII) read and converted, checked against MicMac's own real data."""
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from dgcal.calib.camera import conversions as cc
from dgcal.calib.camera.files import load_camera, parse_micmac, read_camera_with_error
from dgcal.fields.errors import InputError

IMAGES = ["IMGP4167.JPG", "IMGP4168.JPG", "IMGP4169.JPG", "IMGP4170.JPG"]


@pytest.fixture(scope="module")
def mm(shared_data):
    return shared_data / "micmac-saisies"


def v1_pose(path):
    """(centre, R_cam_to_world) of a MicMac V1 Orientation-*.xml: X_world = C + R X_cam."""
    r = ET.parse(path).getroot()
    C = np.array(r.find(".//Centre").text.split(), float)
    R = np.array([r.find(f".//CodageMatr/{k}").text.split() for k in ("L1", "L2", "L3")], float)
    return C, R, r


def mmvii_pose(path):
    """(centre, R_cam_to_world) of an MMVII Ori-PerspCentral-*.xml: AxeI..K are the camera axes in the world."""
    r = ET.parse(path).getroot()
    C = np.array(r.find(".//Center").text.split(), float)
    A = np.array([r.find(f".//RotMatrix/{k}").text.split() for k in ("AxeI", "AxeJ", "AxeK")], float)
    return C, A.T


def ground_data(mm):
    pts = {e.findtext("NamePt"): np.array(e.findtext("Pt").split(), float)
           for e in ET.parse(mm / "Ground-Pts3D.xml").getroot().iter("OneAppuisDAF")}
    meas = []
    for im in ET.parse(mm / "GroundMeasure.xml").getroot().iter("MesureAppuiFlottant1Im"):
        for m in im.iter("OneMesureAF1I"):
            meas.append((im.findtext("NameIm"), m.findtext("NamePt"), np.array(m.findtext("PtIm").split(), float)))
    return pts, meas


def test_v1_autocal_reproduces_micmac_check_points_and_fits_fraser7(mm):
    v1 = parse_micmac((mm / "Ori-Ground_mm3d/AutoCal_Foc-28000_Cam-PENTAX_K5.xml").read_text())
    assert v1.image_size == (1728, 1152) and len(v1.coeffs) == 4
    cam, err = cc.from_micmac(v1)
    assert cam.NAME == "fraser7" and err < 0.2  # MicMac's r^8 term is the only thing fraser7 lacks
    assert cc.max_projection_difference(v1, cam) == pytest.approx(err)
    for name in IMAGES:
        C, R, root = v1_pose(mm / f"Ori-Ground_mm3d/Orientation-{name}.xml")
        im = np.array([a.findtext("Im").split() for a in root.iter("Appuis")], float)
        ter = np.array([a.findtext("Ter").split() for a in root.iter("Appuis")], float)
        X_cam = (ter - C) @ R
        # MicMac's own <Verif> pairs: our reading of its model is exact, the fraser7 fit within err
        np.testing.assert_allclose(v1.project(X_cam), im, atol=1e-6)
        assert np.abs(cam.project(X_cam) - im).max() < err + 1e-9


def test_ground_measurements_reprojected_through_converted_calibrations(mm):
    pts, meas = ground_data(mm)
    cam_v1, _ = read_camera_with_error(mm / "Ori-Ground_mm3d/AutoCal_Foc-28000_Cam-PENTAX_K5.xml")
    cam_v2, err2 = read_camera_with_error(mm / "MMVII-PhgrProj/Ori/toto/Calib-PerspCentral-Foc-28000_Cam-PENTAX_K5.xml")
    assert err2 < 1e-3
    res_v1, res_v2 = [], []
    for image, pid, xy in meas:
        if pid not in pts:  # measured but without ground coordinates: a tie point
            continue
        C, R, _ = v1_pose(mm / f"Ori-Ground_mm3d/Orientation-{image}.xml")
        res_v1.append(cam_v1.project((pts[pid] - C) @ R)[0] - xy)
        C, R = mmvii_pose(mm / f"MMVII-PhgrProj/Ori/toto/Ori-PerspCentral-{image}.xml")
        res_v2.append(cam_v2.project((pts[pid] - C) @ R)[0] - xy)
    res_v1, res_v2 = np.array(res_v1), np.array(res_v2)
    assert len(res_v1) == 16  # 19 measurements, 3 of points without ground coordinates
    rms1 = np.sqrt(np.mean(np.sum(res_v1**2, axis=1)))
    assert rms1 < 1.6 and np.abs(res_v1).max() < 3.0  # MicMac's own adjustment leaves 1.43 px on these hand picks
    assert np.abs(res_v1.mean(axis=0)).max() < 0.5  # no systematic (origin) offset
    np.testing.assert_allclose(res_v2, res_v1, atol=0.2)  # V1 and MMVII files describe the same camera


def test_mmvii_decentric_terms_are_opencv_swapped():
    m = cc.MicMacMMVII((1000, 800), 900.0, np.array([499.5, 399.5]), np.array([0.0]), p1=1e-3, p2=-2e-3)
    cam, err = cc.from_micmac(m)
    assert err < 1e-6
    # MMVII p1 multiplies (3x^2 + y^2, 2xy): OpenCV's p2; MMVII p2 is OpenCV's p1
    assert cam["P2"] == pytest.approx(1e-3, rel=1e-6) and cam["P1"] == pytest.approx(-2e-3, rel=1e-6)


def test_micmac_bad_files(tmp_path):
    p = tmp_path / "AutoCal_bad.xml"
    p.write_text("<ExportAPERO><CalibrationInternConique><PP>1 2</PP><F>x</F></CalibrationInternConique>"
                 "</ExportAPERO>")
    with pytest.raises(InputError, match=r"AutoCal_bad.xml.*'F'.*not a number"):
        load_camera(p)
    p.write_text("<ExportAPERO><CalibrationInternConique><PP>1 2</PP><F>100</F><SzIm>10 10</SzIm>"
                 "<CalibDistortion><ModEbner/></CalibDistortion></CalibrationInternConique></ExportAPERO>")
    with pytest.raises(InputError, match="ModEbner is not supported"):
        load_camera(p)
