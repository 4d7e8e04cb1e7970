"""Each export against an independent implementation of its program's convention (issue 30), not a round trip
through dgcal's own reader. Every test also checks that a convention error (a sign, a transposed rotation, an axis
order) would be caught: the same comparison with the error made must fail by far more than the tolerance.

- Metashape camera orientation offset: Metashape's yaw/pitch/roll matrix written from scratch (`ypr2mat`:
  R = Rz(-yaw) Rx(pitch) Ry(roll) acting on a level, north-facing frame x east/right, y north/forward, z up; the
  camera of angles 0 looks down with the image top forward, Metashape's camera axes x right, y down, z forward),
  composed as Metashape composes the offset with the platform's angles: R_cam = ypr2mat(platform) ypr2mat(offset)
  diag(1, -1, -1). Physical checks: yaw +90 turns the image top to the aircraft's right (clockwise, as a heading),
  pitch +90 makes the camera look forward, roll +10 tilts the view to the left (right wing down).
- Pix4D external orientation: Pix4D's "How are the internal and external camera parameters defined?"
  (support.pix4d.com article 202559089): R = Rx(omega) Ry(phi) Rz(kappa), X' = R^T (X - T) with the camera axes
  x right, y up, z back, world X east, Y north, Z up (the map grid); pixels projected with that and compared with
  the simulator's noise-free measurements.
- COLMAP: pycolmap reads the exported model and projects ground points with its own Rigid3d/camera code; the
  pixels are compared with the simulator's noise-free measurements (not with dgcal's projection of the same EOPs).
ODM geo.txt is tested against a line-by-line copy of ODM's compute_opk in tests/fields/test_formats_misreads.py.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dgcal.calib.camera.files import read_camera
from dgcal.calib.mounting.common import MountingResult
from dgcal.fields.crs import MapGrid
from dgcal.fields.io.formats import read_eop, read_measurements
from dgcal.reports.exports.calibration import calibration_values
from dgcal.reports.exports.eop import export_all
from dgcal.sim.flight import simulate_block_flight

R_NED_FROM_RFU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])   # x right/east, y fwd/north, z up


def _rx(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def metashape_ypr2mat(yaw, pitch, roll):
    """Metashape's yaw/pitch/roll matrix (Metashape.Utils.ypr2mat as users reproduce it), degrees."""
    return _rz(-yaw) @ _rx(pitch) @ _ry(roll)


def metashape_R_cam_to_body(ypr_offset):
    """The camera (x right, y down, z forward) in the body FRD frame of a platform at yaw = pitch = roll = 0, as
    Metashape composes the offset: ypr2mat(0, 0, 0) ypr2mat(offset) diag(1, -1, -1), in x east/right, y
    north/forward, z up, turned to FRD."""
    return R_NED_FROM_RFU @ metashape_ypr2mat(*ypr_offset) @ np.diag([1.0, -1.0, -1.0])


def _mount(R):
    return MountingResult("joint", np.array([0.1, -0.05, 0.2]), np.asarray(R, float), -0.01, np.zeros((7, 7)))


def _angle(Ra, Rb):
    return float(np.degrees(Rotation.from_matrix(Ra.T @ Rb).magnitude()))


def test_metashape_offset_physical_meaning():
    R_nadir = metashape_R_cam_to_body((0, 0, 0))
    view = R_nadir @ [0, 0, 1.0]
    top = R_nadir @ [0, -1.0, 0]
    assert np.allclose(view, [0, 0, 1]) and np.allclose(top, [1, 0, 0])          # looks down, image top forward
    assert np.allclose(metashape_R_cam_to_body((90, 0, 0)) @ [0, -1.0, 0], [0, 1, 0])   # yaw +90: top to the right
    assert np.allclose(metashape_R_cam_to_body((0, 90, 0)) @ [0, 0, 1.0], [1, 0, 0])    # pitch +90: looks forward
    assert metashape_R_cam_to_body((0, 0, 10)) @ [0, 0, 1.0] @ [0, 1, 0] < -0.17        # roll +10: view to the left
    for ypr in ([90, 0, 0], [0, 0, 10], [0, 10, 0]):   # dgcal's export gives these angles back for these mounts
        got = calibration_values(_mount(metashape_R_cam_to_body(ypr)), "metashape")
        assert np.allclose(got["camera_orientation_offset_yaw_pitch_roll_deg"], ypr, atol=1e-9), (ypr, got)


@pytest.mark.parametrize("seed", range(4))
def test_metashape_offset_against_ypr2mat(seed):
    rng = np.random.default_rng(seed)
    ypr = rng.normal(0, 3, 3) + [rng.choice([0.0, 90.0, 180.0, -90.0]), 0, 0]
    R = metashape_R_cam_to_body(ypr)
    got = np.array(calibration_values(_mount(R), "metashape")["camera_orientation_offset_yaw_pitch_roll_deg"])
    assert _angle(metashape_R_cam_to_body(got), R) < 1e-9
    # the error this catches: the yaw or roll counted the other way round
    for flipped in ([-got[0], got[1], got[2]], [got[0], got[1], -got[2]]):
        assert _angle(metashape_R_cam_to_body(flipped), R) > 0.5


def test_pospac_boresight_applanix_example():
    """Applanix's mounting-angle example (POS MV V4 User Guide 2009, sec. 2-50): a frame turned 3 deg clockwise, bow
    edge 2 deg higher, port edge 5 deg lower than the reference frame (x fore, y starboard, z down) has mounting
    angles z +3, y +2, x -5, reached by the Tait-Bryan sequence about z, the new y, the new x (LVX manual 4.6.11).
    The camera's sensor frame (x image top, y right, z view) mounted that way gets (tx, ty, tz) = (-5, 2, 3)."""
    R_sensor_to_vehicle = Rotation.from_euler("ZYX", [3.0, 2.0, -5.0], degrees=True).as_matrix()
    x_s, y_s = R_sensor_to_vehicle[:, 0], R_sensor_to_vehicle[:, 1]
    assert x_s[1] > 0.05 and x_s[2] < -0.03 and y_s[2] < -0.08    # clockwise, bow higher, starboard higher
    R_cv_to_sensor = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])    # CV x right -> sensor y, CV y down -> -x
    got = calibration_values(_mount(R_sensor_to_vehicle @ R_cv_to_sensor), "pospac")["boresight_tx_ty_tz_deg"]
    assert np.allclose(got, [-5, 2, 3], atol=1e-9)


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    d = tmp_path_factory.mktemp("flight")
    simulate_block_flight(d, seed=2, render=False)
    return d


def _pix4d_rows(path):
    """Pix4D's external orientation file read by hand: imageName X Y Z Omega Phi Kappa."""
    lines = path.read_text().splitlines()
    assert lines[0].split() == ["imageName", "X", "Y", "Z", "Omega", "Phi", "Kappa"]
    return {t[0]: np.array(t[1:7], float) for t in (ln.split() for ln in lines[1:])}


def _ground_truth(d):
    truth = json.loads((d / "truth.json").read_text())
    gp = truth["ground_points"]
    return {str(k): np.array(v, float) for k, v in (gp.items() if isinstance(gp, dict) else
                                                   ((p["id"], p["xyz"]) for p in gp))}


def test_pix4d_opk_projects_to_the_true_pixels(flight, tmp_path):
    cam = read_camera(flight / "camera.json")
    eop = read_eop(flight / "truth_eop.csv")
    paths = export_all(tmp_path, eop, MapGrid("EPSG:32651"), cam, formats=("pix4d",))
    rows = _pix4d_rows(paths["pix4d"])
    ground = _ground_truth(flight)
    meas = read_measurements(flight / "measurements_exact.csv")

    def worst(convention):
        err = []
        for k in range(len(meas)):
            im, pid = str(meas.image[k]), str(meas.id[k])
            if pid not in ground:
                continue
            X, T, (om, ph, ka) = ground[pid], rows[im][:3], rows[im][3:]
            R = convention(om, ph, ka)
            Xp = R.T @ (X - T)                               # Pix4D camera frame: x right, y up, z back
            X_cv = np.array([Xp[0], -Xp[1], -Xp[2]])          # dgcal's camera model takes x right, y down, z fwd
            err.append(np.abs(cam.project(X_cv[None])[0] - meas.xy[k]).max())
        assert len(err) > 50
        return max(err)
    assert worst(lambda om, ph, ka: _rx(om) @ _ry(ph) @ _rz(ka)) < 0.05        # grid as Cartesian: scale 4e-5
    assert worst(lambda om, ph, ka: (_rx(om) @ _ry(ph) @ _rz(ka)).T) > 5          # world-to-camera read instead
    assert worst(lambda om, ph, ka: _rz(ka) @ _ry(ph) @ _rx(om)) > 5              # Z-Y-X order instead


def test_colmap_model_projects_to_the_true_pixels_with_pycolmap(flight, tmp_path):
    import pycolmap
    cam = read_camera(flight / "camera.json")
    eop = read_eop(flight / "truth_eop.csv")
    export_all(tmp_path, eop, MapGrid("EPSG:32651"), cam, formats=("colmap",))
    geo = json.loads((tmp_path / "colmap" / "georef.json").read_text())
    rec = pycolmap.Reconstruction(str(tmp_path / "colmap"))
    # ground points into the model's local ENU frame with pyproj alone (not dgcal's World)
    from pyproj import Transformer
    lat0, lon0, h0 = geo["origin_lat_lon_h"]
    to_geo = Transformer.from_crs("EPSG:32651", "EPSG:4979", always_xy=True)
    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    o = np.array(to_ecef.transform(lon0, lat0, h0))
    la, lo = np.radians(lat0), np.radians(lon0)
    R_ecef_to_enu = np.array([[-np.sin(lo), np.cos(lo), 0],
                              [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
                              [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]])
    ground = _ground_truth(flight)
    enu = {}
    for pid, X in ground.items():
        lon, lat, h = to_geo.transform(*X)
        enu[pid] = R_ecef_to_enu @ (np.array(to_ecef.transform(lon, lat, h)) - o)
    meas = read_measurements(flight / "measurements_exact.csv")
    images = {img.name: img for img in rec.images.values()}
    camera = rec.cameras[1]
    worst, worst_conj, n = 0.0, 0.0, 0
    for k in range(len(meas)):
        im, pid = str(meas.image[k]), str(meas.id[k])
        if pid not in enu:
            continue
        img = images[im]
        uv = np.asarray(img.project_point(enu[pid])) - 0.5               # COLMAP pixel origin: the corner
        worst = max(worst, float(np.abs(uv - meas.xy[k]).max()))
        # the error this catches: the quaternion taken as camera-to-world (COLMAP wants cam_from_world)
        p = img.cam_from_world().rotation.inverse() * enu[pid] + img.cam_from_world().translation
        uv_conj = np.asarray(camera.img_from_cam(p)) - 0.5
        worst_conj = max(worst_conj, float(np.abs(uv_conj - meas.xy[k]).max()))
        n += 1
    # the camera's fraser7 B1/B2 are fitted into COLMAP's OPENCV model, to within the error georef.json states
    assert n > 50 and worst < geo["camera_conversion_max_error_px"] + 0.02, worst
    assert worst_conj > 5


def test_inertial_explorer_lever_arm_and_stated_axes(tmp_path):
    """IE's body frame x right, y forward, z up with attitude R_body_to_ENU = Rz(-heading) Rx(pitch) Ry(roll)
    (Waypoint manual sec. 3.8.2.4): the camera IE places from dgcal's lever arm is where dgcal's FRD lever arm with
    R_body_to_NED = Rz(heading) Ry(pitch) Rx(roll) puts it; the file names the Axes setting it assumes."""
    from dgcal.reports.exports.calibration import write_calibration_export
    m = _mount(Rotation.from_rotvec([0.01, -0.02, 0.03]).as_matrix() @ metashape_R_cam_to_body((0, 0, 0)))
    v = write_calibration_export(tmp_path / "ie.txt", m, "inertial-explorer")
    text = (tmp_path / "ie.txt").read_text()
    assert "Axes" in text and "x right, y forward, z up" in text and "x forward, y left, z up" in text
    rng = np.random.default_rng(3)
    for _ in range(5):
        roll, pitch, heading = rng.normal(0, 10), rng.normal(0, 10), rng.uniform(0, 360)
        enu_ie = _rz(-heading) @ _rx(pitch) @ _ry(roll) @ np.array(v["lever_arm_xyz_m"])
        ned = _rz(heading) @ _ry(pitch) @ _rx(roll) @ m.lever_arm_m
        assert np.allclose(enu_ie, [ned[1], ned[0], -ned[2]], atol=1e-9)


def test_odm_geo_yaw_is_not_a_heading(tmp_path):
    """What docs/formats.md says of geo.txt: for a level camera the yaw ODM's compute_opk needs is the heading of the
    image top + the longitude + 90 deg (- 90 deg south of the equator), pitch and roll 0."""
    from dgcal.reports.exports.eop import odm_ypr_for_opk
    for lat, lon, heading in ((40.0, -105.0, 0.0), (24.0, 121.3, 75.0), (-33.9, 151.2, 200.0), (-5.0, -60.0, 310.0)):
        ypr = odm_ypr_for_opk(lat, lon, 100.0, np.array([[0.0, 0.0, -heading]]))[0]   # kappa = -heading (PATB)
        expected = heading + lon + (90.0 if lat > 0 else -90.0)
        assert abs((ypr[0] - expected + 180) % 360 - 180) < 1e-4 and np.allclose(ypr[1:], 0, atol=1e-6), ypr
