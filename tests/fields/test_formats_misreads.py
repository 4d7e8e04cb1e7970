"""Regression tests for real files that dgcal misread (issue 13), each built in the exact shape the other
software writes: every one of them failed before the fix."""
from __future__ import annotations

import numpy as np
import pytest

from dgcal.calib.camera.files import read_camera
from dgcal.fields.crs import MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.io.gcp_files import is_odm_gcp_list, read_any_measurements, read_odm_gcp_list
from dgcal.fields.io.formats import EOP
from dgcal.fields.frames import R_photo_to_map_from_opk
from dgcal.reports.exports.eop import PIX4D_HEADER, read_odm_geo, write_odm_geo, write_pix4d

# A Metashape "Export Cameras" XML (version 1.4.0 document layout): one sensor whose initial calibration
# (from EXIF) is followed by the adjusted one (after Align Photos / Optimize); the shape EasyIDP and Metashape
# users parse (sensor > resolution, property, bands, data_type, calibration class=..., covariance).
METASHAPE_CAMERAS_XML = """<?xml version="1.0" encoding="UTF-8"?>
<document version="1.4.0">
  <chunk label="Chunk 1" enabled="true">
    <sensors next_id="1">
      <sensor id="0" label="FC6310S (8.8mm)" type="frame">
        <resolution width="5472" height="3648"/>
        <property name="pixel_width" value="0.0024107142857142856"/>
        <property name="pixel_height" value="0.0024107142857142856"/>
        <property name="focal_length" value="8.8000000000000007"/>
        <property name="layer_index" value="0"/>
        <bands>
          <band label="Red"/>
          <band label="Green"/>
          <band label="Blue"/>
        </bands>
        <data_type>uint8</data_type>
        <calibration type="frame" class="initial">
          <resolution width="5472" height="3648"/>
          <f>3650.3703703703704</f>
        </calibration>
        <calibration type="frame" class="adjusted">
          <resolution width="5472" height="3648"/>
          <f>3655.9521435127</f>
          <cx>-11.6327198715</cx>
          <cy>17.4431029437</cy>
          <b1>-2.1840127836</b1>
          <b2>-0.8812365712</b2>
          <k1>0.0045811349</k1>
          <k2>-0.0296731287</k2>
          <k3>0.0343317718</k3>
          <p1>-0.0004179981</p1>
          <p2>0.0007829817</p2>
        </calibration>
        <covariance>
          <params>f cx cy b1 b2 k1 k2 k3 p1 p2</params>
          <coeffs>1 0 0 0 0 0 0 0 0 0</coeffs>
        </covariance>
      </sensor>
    </sensors>
    <cameras next_id="1" next_group_id="0">
      <camera id="0" sensor_id="0" label="DJI_0001">
        <transform>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</transform>
      </camera>
    </cameras>
  </chunk>
</document>
"""


def test_metashape_cameras_xml_loads_the_adjusted_calibration(tmp_path):
    p = tmp_path / "cameras.xml"
    p.write_text(METASHAPE_CAMERAS_XML)
    cam = read_camera(p)
    d = cam.as_dict()
    assert abs(d["f"] - 3655.9521435127) < 1e-9          # not the initial 3650.37
    # Metashape cx, cy are offsets from the image centre ((W-1)/2 in dgcal's pixel-centre convention)
    assert abs(d["cx"] - (5471 / 2 - 11.6327198715)) < 1e-6
    assert abs(d["cy"] - (3647 / 2 + 17.4431029437)) < 1e-6


def test_metashape_with_two_sensors_asks_which(tmp_path):
    two = METASHAPE_CAMERAS_XML.replace("</sensors>", METASHAPE_CAMERAS_XML.split("<sensors next_id=\"1\">")[1]
                                        .split("</sensors>")[0].replace('id="0" label="FC6310S',
                                                                        'id="1" label="Zenmuse X7') + "</sensors>")
    p = tmp_path / "cameras.xml"
    p.write_text(two)
    with pytest.raises(InputError) as e:
        read_camera(p)
    assert "2 calibrated sensors" in str(e.value) and "FILE#ID" in str(e.value)
    assert abs(read_camera(f"{p}#1").as_dict()["f"] - 3655.9521435127) < 1e-9


# ROS camera_calibration_parsers output (as `rosrun camera_calibration cameracalibrator.py` saves ost.yaml)
ROS_CAMERA_INFO = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [628.10364, 0.0, 321.47227, 0.0, 627.95812, 239.21094, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.091235, 0.123458, 0.001129, -0.000734, 0.0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
projection_matrix:
  rows: 3
  cols: 4
  data: [620.51, 0.0, 320.86, 0.0, 0.0, 625.33, 239.05, 0.0, 0.0, 0.0, 1.0, 0.0]
"""


def test_ros_camera_info_yaml(tmp_path):
    import cv2
    p = tmp_path / "ost.yaml"
    p.write_text(ROS_CAMERA_INFO)
    cam = read_camera(p)
    K = np.array([[628.10364, 0, 321.47227], [0, 627.95812, 239.21094], [0, 0, 1]])
    D = np.array([-0.091235, 0.123458, 0.001129, -0.000734, 0.0])
    rays = np.array([[0.1, -0.2, 1.0], [-0.3, 0.25, 1.0], [0.0, 0.0, 1.0]])
    ref, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, D)
    assert np.max(np.abs(cam.project(rays) - ref.reshape(-1, 2))) < 1e-6
    bad = tmp_path / "bad.yaml"
    k_row = "data: [628.10364, 0.0, 321.47227, 0.0, 627.95812, 239.21094, 0.0, 0.0, 1.0]"
    bad.write_text(ROS_CAMERA_INFO.replace(k_row, "data: [628.1, 0.0]"))
    with pytest.raises(InputError) as e:
        read_camera(bad)
    assert "bad.yaml:4" in str(e.value) and "camera_matrix" in str(e.value)


COLMAP_TWO_CAMERAS = """# Camera list with one line of data per camera:
#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]
# Number of cameras: 2
1 SIMPLE_RADIAL 3072 2304 2559.81 1536 1152 -0.0204997
2 PINHOLE 3072 2304 2560.56 2560.56 1536 1152
"""


def test_colmap_multi_camera_is_not_silently_the_first(tmp_path):
    p = tmp_path / "cameras.txt"
    p.write_text(COLMAP_TWO_CAMERAS)
    with pytest.raises(InputError) as e:
        read_camera(p)
    assert "2 different cameras" in str(e.value) and "cameras.txt:5" in str(e.value)
    assert abs(read_camera(f"{p}#2").as_dict()["f"] - 2560.56) < 1e-9
    same = tmp_path / "same.txt"
    same.write_text("1 PINHOLE 100 80 90 90 50 40\n2 PINHOLE 100 80 90 90 50 40\n")
    assert read_camera(same).image_size == (100, 80)


# ODM gcp_list.txt in geographic coordinates (lon lat h) without gcp names, as ODM's docs show it
ODM_GCP_4326 = """EPSG:4326
-91.9942096 46.8425076 198.609 3044 2622 IMG_0525.jpg
-91.9942096 46.8425076 198.609 4193 1552 IMG_0585.jpg
-91.9938293 46.8424973 199.103 2275 2290 IMG_0524.jpg
-91.9938290 46.8424970 199.100 1230 1960 IMG_0586.jpg
"""


def test_odm_gcp_list_geographic_without_names(tmp_path):
    p = tmp_path / "gcp_list.txt"
    p.write_text(ODM_GCP_4326)
    crs, pts, meas = read_odm_gcp_list(p)
    assert crs == "EPSG:4326"
    # two points 0.04 m apart get different names; the same coordinates share one
    assert len(pts.ids) == 3 and list(meas.id) == ["gcp_1", "gcp_1", "gcp_2", "gcp_3"]
    named = tmp_path / "named.txt"
    named.write_text(ODM_GCP_4326.replace("IMG_0586.jpg", "IMG_0586.jpg gcp_1"))
    _, pts2, meas2 = read_odm_gcp_list(named)
    assert "gcp_1" in set(meas2.id) and len(set(meas2.id)) == 3 and meas2.id[0] != "gcp_1"


def test_odm_wgs84_longlat_header_and_leading_comments(tmp_path):
    p = tmp_path / "gcp_list.txt"
    p.write_text("# exported by a GCP editor\n# lon lat ellipsoidal height\nWGS84 longlat\n"
                 + ODM_GCP_4326.split("\n", 1)[1])
    assert is_odm_gcp_list(p)
    meas, crs, pts = read_any_measurements(p)
    assert crs == "EPSG:4326" and len(meas) == 4


def test_heights_in_a_feet_crs_are_feet():
    """A 2-D State Plane grid in US survey feet: heights in the same unit (before: taken as metres)."""
    g = MapGrid("EPSG:2272")
    xyz = g.from_geodetic(40.0, -75.5, 100.0)
    assert abs(xyz[2] - 100.0 / 0.3048006096012192) < 1e-6
    assert abs(g.to_geodetic(xyz)[2] - 100.0) < 1e-6
    assert MapGrid("EPSG:32618").from_geodetic(40.0, -75.5, 100.0)[2] == pytest.approx(100.0)


def test_pix4d_header_is_pix4ds_own(tmp_path):
    p = tmp_path / "ext.txt"
    write_pix4d(p, EOP(np.array(["a.jpg"], dtype=object), np.array([[1.0, 2.0, 3.0]]), np.zeros((1, 3))))
    assert p.read_text().splitlines()[0] == "imageName X Y Z Omega Phi Kappa" == PIX4D_HEADER


def _odm_compute_opk(lat, lon, alt, yaw, pitch, roll):
    """opendm/photo.py Photo.compute_opk (ODM 3.x), line for line, with pyproj's ECEF for ecef_from_lla."""
    import math
    from dgcal.fields.crs import geodetic_to_ecef
    y, p, r = math.radians(yaw), math.radians(pitch), math.radians(roll)
    cnb = np.array([[math.cos(y) * math.cos(p), math.cos(y) * math.sin(p) * math.sin(r) - math.sin(y) * math.cos(r),
                     math.cos(y) * math.sin(p) * math.cos(r) + math.sin(y) * math.sin(r)],
                    [math.sin(y) * math.cos(p), math.sin(y) * math.sin(p) * math.sin(r) + math.cos(y) * math.cos(r),
                     math.sin(y) * math.sin(p) * math.cos(r) - math.cos(y) * math.sin(r)],
                    [-math.sin(p), math.cos(p) * math.sin(r), math.cos(p) * math.cos(r)]])
    cbb = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    delta = 1e-7
    p1 = np.array(geodetic_to_ecef(lat + delta, lon, alt))
    p2 = np.array(geodetic_to_ecef(lat - delta, lon, alt))
    xnp = p1 - p2
    xnp /= np.linalg.norm(xnp)
    znp = np.array([0, 0, -1]).T
    ynp = np.cross(znp, xnp)
    cen = np.array([xnp, ynp, znp]).T
    ceb = cen.dot(cnb).dot(cbb)
    return (math.degrees(math.atan2(-ceb[1][2], ceb[2][2])), math.degrees(math.asin(ceb[0][2])),
            math.degrees(math.atan2(-ceb[0][1], ceb[0][0])))


def _opensfm_rotation_from_opk(omega, phi, kappa):
    """opensfm/geometry.py rotation_from_opk (radians): world (E, N, U) -> camera (x right, y down, z forward)."""
    from scipy.spatial.transform import Rotation
    Rw = Rotation.from_rotvec([-omega, 0, 0]).as_matrix()
    Rp = Rotation.from_rotvec([0, -phi, 0]).as_matrix()
    Rk = Rotation.from_rotvec([0, 0, -kappa]).as_matrix()
    return np.diag([1, -1, -1]) @ Rk @ Rp @ Rw


def test_odm_geo_txt_read_as_odm_reads_it(tmp_path):
    """geo.txt holds ODM's yaw/pitch/roll (it held omega/phi/kappa, up to 170 deg off as ODM reads it): parsed as
    opendm/geo.py GeoFile does and turned into a rotation by ODM's own compute_opk + OpenSfM's rotation_from_opk,
    every camera gets eop.csv's rotation (in the local East/North/Up frame at the camera) to 1e-6 deg."""
    g = MapGrid("EPSG:32613")
    rng = np.random.default_rng(4)
    n = 12
    xyz = np.column_stack([rng.uniform(478000, 482000, n), rng.uniform(4437000, 4441000, n),
                           rng.uniform(1700, 1900, n)])
    opk = np.column_stack([rng.normal(0, 3, n), rng.normal(0, 3, n), rng.uniform(-180, 180, n)])
    opk[0] = [0.0, 0.0, 0.0]
    opk[1] = [12.0, -25.0, 170.0]
    eop = EOP(np.array([f"IMG_{k:04d}.JPG" for k in range(n)], dtype=object), xyz, opk)
    p = tmp_path / "geo.txt"
    write_odm_geo(p, eop, g)
    lines = p.read_text().splitlines()
    assert lines[0] == "EPSG:32613"
    worst = 0.0
    for k, line in enumerate(lines[1:]):
        parts = line.split()                                   # opendm/geo.py GeoFile
        x, y, z = (float(v) for v in parts[1:4])
        yaw, pitch, roll = (float(v) for v in parts[4:7])
        lat, lon, h = g.to_geodetic(np.array([x, y, z]))        # location.transform3(srs, EPSG:4326, ...)
        om, ph, ka = np.radians(_odm_compute_opk(lat, lon, h, yaw, pitch, roll))
        R_enu_to_cam = _opensfm_rotation_from_opk(om, ph, ka)
        # eop.csv's rotation in the same frame: grid axes at the camera -> local ENU
        R_photo_to_grid = R_photo_to_map_from_opk(*opk[k])
        R_photo_to_enu = g.R_enu_to_grid_at(xyz[k]).T @ R_photo_to_grid
        R_enu_to_cam_eop = np.diag([1.0, -1.0, -1.0]) @ R_photo_to_enu.T
        dR = R_enu_to_cam.T @ R_enu_to_cam_eop
        skew = (dR - dR.T) / 2                                  # small-angle: sin(theta) * axis
        worst = max(worst, np.degrees(np.linalg.norm([skew[2, 1], skew[0, 2], skew[1, 0]])))
    assert worst < 1e-6, worst
    back, _ = read_odm_geo(p)
    assert np.max(np.abs((back.opk - opk + 180) % 360 - 180)) < 1e-6
