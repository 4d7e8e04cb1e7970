"""Issue 16, one validation layer at the edge: the silent failures and tracebacks that bad input caused, each
now one InputError naming the file, line and field (dgcal.fields.io.validate, used by every reader)."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dgcal.calib.camera.files import read_camera
from dgcal.cli import main
from dgcal.fields.errors import InputError
from dgcal.fields.io import validate

OPENCV_YAML = """%YAML:1.0
---
image_width: 4000
image_height: 3000
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 3000., 0., 2000., 0., 3000., 1500., 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.1, 0.05, 1.0e-04, -1.0e-04, 0. ]
"""

OPENCV_XML = """<?xml version="1.0"?>
<opencv_storage>
<image_width>4000</image_width>
<image_height>3000</image_height>
<camera_matrix type_id="opencv-matrix">
  <rows>3</rows>
  <cols>3</cols>
  <dt>d</dt>
  <data>
    3000. 0. 2000. 0. 3000. 1500. 0. 0. 1.</data></camera_matrix>
<distortion_coefficients type_id="opencv-matrix">
  <rows>1</rows>
  <cols>5</cols>
  <dt>d</dt>
  <data>
    -0.1 0.05 1.0e-04 -1.0e-04 0.</data></distortion_coefficients>
</opencv_storage>
"""


def _raises(path: Path, *parts: str) -> str:
    with pytest.raises(InputError) as e:
        read_camera(path)
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg, msg
    for p in parts:
        assert p in msg, msg
    return msg


# ---------------------------------------------------------------------------------------------
# OpenCV camera files: parsed by PyYAML / ElementTree, never by cv2.FileStorage
# ---------------------------------------------------------------------------------------------
def test_opencv_yaml_without_cols_is_an_input_error_not_a_native_abort(tmp_path):
    """Before: cv2.FileStorage read the matrix without `cols:` and the interpreter died (double free) or raised
    cv2.error. The check runs in a child process so an abort would show as a signal, not kill the tests."""
    p = tmp_path / "nocols.yaml"
    p.write_text(OPENCV_YAML.replace("   cols: 3\n", "", 1))
    code = ("import sys\nfrom dgcal.calib.camera.files import read_camera\nfrom dgcal.fields.errors import InputError\n"
            f"try:\n    read_camera({str(p)!r})\nexcept InputError as e:\n    print(e)\n    sys.exit(2)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.returncode, r.stderr[-500:])
    assert r.stdout.strip() == f"{p}:5: field 'camera_matrix': an OpenCV matrix needs rows, cols and data " \
                               "(missing cols)"


@pytest.mark.parametrize("text, line", [
    ("%YAML:1.0\n---\ncamera_matrix: [1, 2\n", 4),                      # an unclosed flow sequence
    ("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n  rows: 3\n cols: 3\n", 5),
    ("%YAML:1.0\n---\nimage_width: 4000\n\tcamera_matrix: x\n", 4),     # a tab
    ("%YAML:1.0\n---\na: &x [*x]\ncamera_matrix: *y\n", 4),             # an undefined alias
])
def test_opencv_yaml_syntax_errors_name_the_line(tmp_path, text, line):
    """Before: every YAML syntax error was a SystemError out of cv2.FileStorage."""
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    _raises(p, f"bad.yaml:{line}", "invalid YAML")


def test_opencv_files_are_read_without_filestorage(tmp_path, monkeypatch):
    import cv2

    def no(*a, **kw):
        raise AssertionError("cv2.FileStorage must not read users' files")
    monkeypatch.setattr(cv2, "FileStorage", no)
    for name, text in (("old.yaml", OPENCV_YAML), ("new.yaml", OPENCV_YAML.replace("%YAML:1.0", "%YAML 1.2")),
                       ("cam.xml", OPENCV_XML)):
        p = tmp_path / name
        p.write_text(text)
        cam = read_camera(p)
        assert cam.NAME == "fraser7" and cam.image_size == (4000, 3000) and cam["f"] == 3000.0
        assert cam["K1"] == -0.1 and cam["P1"] == 1e-4


def test_opencv_special_values_and_wrong_shapes(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text(OPENCV_YAML.replace("-0.1,", ".Nan,"))
    _raises(p, "c.yaml:10", "distortion_coefficients.data", "not a finite number")
    p.write_text(OPENCV_YAML.replace("rows: 3\n   cols: 3", "rows: 2\n   cols: 3"))
    _raises(p, "c.yaml:5", "camera_matrix.data", "rows x cols = 2 x 3 needs 6")
    p.write_text(OPENCV_YAML.replace("0., 0., 1. ]", "0., 0., 2. ]"))
    _raises(p, "[fx 0 cx; 0 fy cy; 0 0 1]")
    p.write_text(OPENCV_XML.replace("<cols>3</cols>", ""))
    _raises(p, "missing cols")


# ---------------------------------------------------------------------------------------------
# focal lengths, image sizes, distortion: every camera format
# ---------------------------------------------------------------------------------------------
def _num(text: str):
    try:
        return int(text)
    except ValueError:
        return float(text)


def _camera_files(tmp_path: Path, f: str = "3000", w: str = "4000", k1: str = "-0.1") -> dict[str, Path]:
    """One camera in every format with focal length `f`, image width `w` and first radial term `k1` (text)."""
    cam_json = json.dumps({"model": "fraser7", "image_size": [_num(w), 3000], "parameters": {
        "f": _num(f), "cx": 2000, "cy": 1500, "K1": _num(k1), "K2": 0, "K3": 0, "P1": 0, "P2": 0, "B1": 0, "B2": 0}})
    files = {
        "camera.json": cam_json,
        "opencv.yaml": OPENCV_YAML.replace("4000", "__W__").replace("3000., 0., 2000.", "__F__, 0., 2000.")
                                  .replace("-0.1,", "__K1__,"),
        "opencv.xml": OPENCV_XML.replace(">4000<", ">__W__<").replace("3000. 0. 2000.", "__F__ 0. 2000.")
                                .replace("-0.1 ", "__K1__ "),
        "cameras.txt": "1 SIMPLE_RADIAL __W__ 3000 __F__ 2000 1500 __K1__\n",
        "metashape.xml": "<calibration><projection>frame</projection><width>__W__</width><height>3000</height>"
                         "<f>__F__</f><k1>__K1__</k1></calibration>",
        "ost.yaml": "image_width: __W__\nimage_height: 3000\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
                    "  data: [__F__, 0, 2000, 0, __F__, 1500, 0, 0, 1]\ndistortion_model: plumb_bob\n"
                    "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [__K1__, 0, 0, 0, 0]\n",
        # MicMac's radial coefficients are per px^2: -1e-9 is the -0.1 of the others
        "AutoCal.xml": "<ExportAPERO><CalibrationInternConique><KnownConv>eConvApero_DistM2C</KnownConv>"
                       "<PP>2000 1500</PP><F>__F__</F><SzIm>__W__ 3000</SzIm><CalibDistortion><ModRad>"
                       "<CDist>2000 1500</CDist><CoeffDist>__K1M__</CoeffDist></ModRad></CalibDistortion>"
                       "</CalibrationInternConique></ExportAPERO>",
    }
    out = {}
    for name, text in files.items():
        p = tmp_path / name
        p.write_text(text.replace("__W__", w).replace("__F__", f).replace("__K1__", k1)
                     .replace("__K1M__", "-1e-9" if k1 == "-0.1" else k1))
        out[name] = p
    return out


def test_valid_camera_files_read(tmp_path):
    for name, p in _camera_files(tmp_path).items():
        cam = read_camera(p)
        assert cam.image_size == (4000, 3000), name


@pytest.mark.parametrize("f", ["-3000", "0", "nan", "inf", "-inf", "1e308"])
def test_zero_negative_non_finite_focal_lengths_are_rejected(tmp_path, f):
    """Before: a negative focal length turned every kappa by 180 deg and the adjustment reported sigma0 1.00."""
    for name, p in _camera_files(tmp_path, f=f).items():
        msg = _raises(p)
        assert any(w in msg for w in ("focal length", "not a finite number", "not a number", "outside the "
                                      "plausible range")), (name, msg)
        assert "field '" in msg, (name, msg)


@pytest.mark.parametrize("w", ["0", "-640", "100001", "1e308", "640.5", "nan"])
def test_implausible_image_sizes_are_rejected(tmp_path, w):
    for name, p in _camera_files(tmp_path, w=w).items():
        msg = _raises(p)
        assert "image size" in msg or "not a finite number" in msg, (name, msg)


@pytest.mark.parametrize("k1", ["nan", "inf", "1e308"])
def test_non_finite_distortion_is_rejected(tmp_path, k1):
    for p in _camera_files(tmp_path, k1=k1).values():
        _raises(p, "field '")


def test_camera_json_names_the_parameter(tmp_path):
    p = _camera_files(tmp_path, f="-3000")["camera.json"]
    _raises(p, "camera.json: field 'parameters.f': the focal length must be positive, got -3000")
    d = json.loads(p.read_text())
    d["parameters"]["f"] = 3000
    d["parameters"]["B1"] = -3500                     # fx = f + B1 < 0
    p.write_text(json.dumps(d))
    _raises(p, "field 'parameters.f+B1'")
    d["parameters"]["B1"] = 0
    d["image_size"] = [True, 3000]
    p.write_text(json.dumps(d))
    _raises(p, "field 'image_size[0]'", "must be a number")
    p.write_text("{" * 100000)
    _raises(p, "invalid JSON")
    p.write_text('{"model": "fraser7", "image_size": [' + "9" * 5000 + ", 1]}")
    _raises(p, "invalid JSON")


def test_camera_image_size_option_is_checked(tmp_path, capsys):
    field = tmp_path / "field.csv"
    field.write_text("id,x,y,z\n1,0,0,0\n2,1,0,0\n3,0,1,0\n4,1,1,0\n")
    meas = tmp_path / "m.csv"
    meas.write_text("image,id,x,y\na,1,10,10\n")
    rc = main(["camera", "--field", str(field), "--measurements", str(meas), "--image-size", "200000", "800",
               "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "image_size[0]" in err and "implausible image size 200000" in err, err


# ---------------------------------------------------------------------------------------------
# mounting.json: non-finite numbers never reach a comparison or a DG check
# ---------------------------------------------------------------------------------------------
def _mounting(tmp_path: Path, **changes) -> Path:
    from dgcal.calib.mounting.common import MountingResult
    m = MountingResult("joint", np.array([0.3, -0.1, 0.2]), np.eye(3), -0.01,
                       np.diag([1e-6, 1e-4, 1e-4, 1e-4, 1e-8, 1e-8, 1e-8]), 12)
    d = m.to_json()
    d.update(changes)
    p = tmp_path / f"mounting_{len(list(tmp_path.glob('mounting_*')))}.json"
    p.write_text(json.dumps(d))
    return p


def test_compare_with_a_nan_lever_arm_is_an_input_error(tmp_path, capsys):
    """Before: `dgcal compare` with a NaN lever arm reported "no significant change"."""
    good, bad = _mounting(tmp_path), _mounting(tmp_path, lever_arm_m=[float("nan"), 0.0, 0.2])
    rc = main(["compare", str(good), str(bad)])
    cap = capsys.readouterr()
    assert rc == 2 and "no significant change" not in cap.out
    assert cap.err.strip() == f"dgcal compare: error: {bad}: field 'lever_arm_m': not a finite number: nan"


@pytest.mark.parametrize("changes, field", [
    ({"lever_arm_m": [1e308, 0, 0]}, "lever_arm_m"),
    ({"lever_arm_m": [0, 0]}, "lever_arm_m"),
    ({"delay_s": float("inf")}, "delay_s"),
    ({"delay_s": "fast"}, "delay_s"),
    ({"boresight_R_cam_to_body": [[1, 0, 0], [0, 1, 0], [0, 0, float("nan")]]}, "boresight_R_cam_to_body"),
    ({"boresight_R_cam_to_body": [[2, 0, 0], [0, 1, 0], [0, 0, 1]]}, "boresight_R_cam_to_body"),
    ({"covariance": [[float("inf")] * 7] * 7}, "covariance"),
    ({"covariance": (-np.eye(7)).tolist()}, "covariance"),
    ({"covariance": (np.eye(7) + np.triu(np.ones((7, 7)), 1)).tolist()}, "covariance"),
    ({"pos_common_fraction": 3.0}, "pos_common_fraction"),
    ({"n_epochs": "many"}, "n_epochs"),
    ({"rejected_epochs": 5}, "rejected_epochs"),
])
def test_mounting_json_values_are_checked(tmp_path, changes, field):
    from dgcal.calib.mounting.common import read_mounting_json
    p = _mounting(tmp_path, **changes)
    with pytest.raises(InputError) as e:
        read_mounting_json(p)
    assert str(e.value).startswith(f"{p}: field '{field}'"), str(e.value)


def test_mounting_json_without_covariance_checks_its_sigmas(tmp_path):
    from dgcal.calib.mounting.common import read_mounting_json
    p = tmp_path / "m.json"
    d = {"lever_arm_m": [0, 0, 0], "boresight_R_cam_to_body": np.eye(3).tolist(), "lever_arm_sigma_m": [-1, 0, 0]}
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"m.json: field 'lever_arm_sigma_m'"):
        read_mounting_json(p)
    p.write_bytes(b'{"lever_arm_m": "\xff"}')
    with pytest.raises(InputError, match=r"m.json:1: not utf-8 text"):
        read_mounting_json(p)


# ---------------------------------------------------------------------------------------------
# GPS weeks, EOPs, trajectories, lever arms: 1e308 / inf / nan end in one line, not deep in the numerics
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("text, where", [
    ("image,gps_week,gps_sow\na,1e308,1.0\n", "e.csv:2: field 'gps_week'"),
    ("image,gps_week,gps_sow\na,2200.5,1.0\n", "e.csv:2: field 'gps_week': must be a whole number"),
    ("image,gps_week,gps_sow\na,-1,1.0\n", "e.csv:2: field 'gps_week'"),
    ("image,gps_week,gps_sow\na,2200,inf\n", "e.csv:2: field 'gps_sow'"),
    ("image,gps_week,gps_sow\na,2200,604801\n", "e.csv:2: field 'gps_sow'"),
])
def test_events_gps_weeks_and_seconds(tmp_path, text, where):
    from dgcal.fields.io.formats import read_events
    p = tmp_path / "e.csv"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        read_events(p)
    assert where in str(e.value), str(e.value)


TRAJ_HEAD = "gps_week,gps_sow,lat,lon,h,vn,ve,vd,roll,pitch,heading,s_lat_m,s_lon_m,s_h_m,s_roll,s_pitch,s_heading\n"
TRAJ_ROW = "2200,300000.0,40.1,-105.1,1800,20,5,0.1,1,2,75,0.05,0.05,0.08,0.01,0.01,0.03\n"


@pytest.mark.parametrize("col, value, msg", [
    (0, "5001", "gps_week"), (2, "91", "lat"), (2, "nan", "lat"), (3, "1e308", "lon"), (4, "-1e308", "h"),
    (5, "inf", "vn"), (10, "1e308", "heading"), (11, "-0.1", "s_lat_m"), (16, "nan", "s_heading"),
])
def test_trajectory_values_are_checked(tmp_path, col, value, msg):
    from dgcal.fields.io.formats import read_trajectory
    row = TRAJ_ROW.strip().split(",")
    row[col] = value
    p = tmp_path / "t.csv"
    p.write_text(TRAJ_HEAD + TRAJ_ROW.replace("300000.0", "299999.0") + ",".join(row) + "\n")
    with pytest.raises(InputError) as e:
        read_trajectory(p)
    assert f"t.csv:3: field '{msg}'" in str(e.value), str(e.value)


@pytest.mark.parametrize("col, value", [(1, "1e308"), (3, "-inf"), (6, "nan"), (7, "-0.03"), (12, "inf")])
def test_eop_values_are_checked(tmp_path, col, value):
    from dgcal.fields.io.formats import EOP_COLUMNS, EOP_SIGMA_COLUMNS, read_eop
    row = "a.jpg,480000,4438000,1900,0.5,-0.25,90,0.03,0.03,0.04,0.003,0.003,0.002".split(",")
    row[col] = value
    p = tmp_path / "eop.csv"
    p.write_text(",".join(EOP_COLUMNS + EOP_SIGMA_COLUMNS) + "\n" + ",".join(row) + "\n")
    with pytest.raises(InputError) as e:
        read_eop(p)
    assert f"eop.csv:2: field '{(EOP_COLUMNS + EOP_SIGMA_COLUMNS)[col].lower()}'" in str(e.value), str(e.value)


@pytest.mark.parametrize("text, where", [
    ("image,id,x,y\na,1,nan,3\n", "field 'x'"), ("image,id,x,y\na,1,2,1e308\n", "field 'y'"),
    ("image,id,x,y,sx,sy\na,1,2,3,inf,1\n", "field 'sx'"), ("image,id,x,y,sx,sy\na,1,2,3,1,0\n", "field 'sy'"),
])
def test_image_coordinates_and_sigmas(tmp_path, text, where):
    from dgcal.fields.io.formats import read_measurements
    p = tmp_path / "m.csv"
    p.write_text(text)
    with pytest.raises(InputError, match=rf"m.csv:2: {where}"):
        read_measurements(p)


def test_mount_and_check_with_huge_numbers_exit_2(tmp_path, capsys):
    """Through the command line: a 1e308 GPS week in the events, an inf EOP, a 1e308 lever arm exit 2 naming the
    file (before: OverflowError, LinAlgError or scipy bounds errors, exit 3)."""
    from dgcal.sim.mounting import simulate_mounting, write_mounting_sim
    small = dict(n_strips=2, length_m=400, rate_hz=5, photo_interval_s=3)
    d = tmp_path / "sim"
    write_mounting_sim(simulate_mounting(5, n_ground=16, calibration=small, mapping=small), d)
    c = d / "calibration"
    ev = c / "events.csv"
    lines = ev.read_text().splitlines()
    lines[3] = lines[3].replace(",2200,", ",1e308,")
    bad_ev = tmp_path / "events.csv"
    bad_ev.write_text("\n".join(lines) + "\n")
    eop = (c / "eop.csv").read_text().splitlines()
    eop[2] = ",".join(["inf" if k == 2 else v for k, v in enumerate(eop[2].split(","))])
    bad_eop = tmp_path / "eop.csv"
    bad_eop.write_text("\n".join(eop) + "\n")
    for e, o, expect in ((bad_ev, c / "eop.csv", f"{bad_ev}:4: field 'gps_week'"),
                         (ev, bad_eop, f"{bad_eop}:3: field 'y'")):
        rc = main(["mount", "--eop", str(o), "--crs", "EPSG:32651", "--trajectory", str(c / "trajectory.csv"),
                   "--events", str(e), "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and err.startswith(f"dgcal mount: error: {expect}"), err
    m = _mounting(tmp_path, lever_arm_m=[1e308, 0, 0])
    rc = main(["check", "--mounting", str(m), "--trajectory", str(d / "mapping/trajectory.csv"), "--events",
               str(d / "mapping/events.csv"), "--measurements", str(d / "mapping/measurements.csv"), "--gcp",
               str(d / "ground.csv"), "--camera", str(d / "camera.json"), "--crs", "EPSG:32651", "--out",
               str(tmp_path / "check")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and f"{m}: field 'lever_arm_m'" in err and "outside the plausible range" in err, err


# ---------------------------------------------------------------------------------------------
# campaign files: a value of the wrong type names its key
# ---------------------------------------------------------------------------------------------
CAMPAIGN = """crs = "EPSG:32651"
[camera]
field = "field.csv"
measurements = "m.csv"
image_size = [6000, 4000]
[pos]
imu = "imu.txt"
events = "events.csv"
gnss = "gnss.csv"
lever_arm_gnss = [0.05, 0, -0.35]
[mount]
pos_common_fraction = 0.5
"""


@pytest.mark.parametrize("old, new, where", [
    ("image_size = [6000, 4000]", 'image_size = "big"', "campaign.toml:5: field 'camera.image_size'"),
    ("image_size = [6000, 4000]", "image_size = [6000.5, 4000]", "field 'camera.image_size[0]'"),
    ("image_size = [6000, 4000]", "image_size = [true, 4000]", "field 'camera.image_size[0]'"),
    ("image_size = [6000, 4000]", "image_size = [0, 4000]", "field 'camera.image_size[0]'"),
    ('field = "field.csv"', "field = 5", "campaign.toml:3: field 'camera.field'"),
    ('field = "field.csv"', "field = []", "field 'camera.field'"),
    ('crs = "EPSG:32651"', "crs = 32651", "campaign.toml:1: field 'crs'"),
    ("lever_arm_gnss = [0.05, 0, -0.35]", 'lever_arm_gnss = [0.05, "a", -0.35]', "field 'pos.lever_arm_gnss'"),
    ("lever_arm_gnss = [0.05, 0, -0.35]", "lever_arm_gnss = [0.05, nan, -0.35]", "field 'pos.lever_arm_gnss'"),
    ("lever_arm_gnss = [0.05, 0, -0.35]", "lever_arm_gnss = [1e308, 0, 0]", "field 'pos.lever_arm_gnss'"),
    ("pos_common_fraction = 0.5", "pos_common_fraction = 2", "field 'mount.pos_common_fraction'"),
    ("pos_common_fraction = 0.5", 'pos_common_fraction = "half"', "field 'mount.pos_common_fraction'"),
    ('gnss = "gnss.csv"', 'gnss = "gnss.csv"\nfrequencies = 2.5', "field 'pos.frequencies'"),
    ('gnss = "gnss.csv"', 'gnss = "gnss.csv"\nset = "rate=5"', "field 'pos.set'"),
    ('measurements = "m.csv"', 'measurements = "m.csv"\nargs = 5', "field 'camera.args'"),
    ('crs = "EPSG:32651"', 'crs = "EPSG:32651"\ncheck = 3', "campaign.toml:2: field 'check'"),
])
def test_campaign_values_of_the_wrong_type_name_the_key(tmp_path, old, new, where):
    """Before: ValueError or TypeError tracebacks (Path(5), int('2.5'), a string iterated as args)."""
    from dgcal.campaign import load_campaign
    p = tmp_path / "campaign.toml"
    assert old in CAMPAIGN
    p.write_text(CAMPAIGN.replace(old, new))
    with pytest.raises(InputError) as e:
        load_campaign(p)
    assert where in str(e.value) and str(p) in str(e.value), str(e.value)


def test_campaign_file_not_utf8_and_valid(tmp_path):
    from dgcal.campaign import load_campaign
    p = tmp_path / "campaign.toml"
    p.write_text(CAMPAIGN)
    assert load_campaign(p)["camera"]["image_size"] == [6000, 4000]
    p.write_bytes(CAMPAIGN.encode().replace(b"EPSG", b"\xffPSG"))
    with pytest.raises(InputError, match=r"campaign.toml:1: not utf-8 text"):
        load_campaign(p)


# ---------------------------------------------------------------------------------------------
# IMU text whose first line is ",,,", and the helpers
# ---------------------------------------------------------------------------------------------
def test_imu_file_whose_first_line_is_commas(tmp_path, capsys):
    """Before: IndexError. Now an InputError naming the file, from every IMU reader and from `dgcal pos`."""
    from dgcal.pos.ins.imu_data import read_imu_csv, read_imu_text, read_kf_gins
    p = tmp_path / "imu.csv"
    p.write_text(",,,\n302000.01,0,0,0,0,0,-0.098\n302000.02,0,0,0,0,0,-0.098\n")
    for reader in (read_imu_csv, read_imu_text, read_kf_gins):
        try:
            reader(p)                      # read_imu_text takes ",,," as a header line: a valid file
        except InputError as e:
            assert "\n" not in str(e) and str(p) in str(e)
    with pytest.raises(InputError, match=r"imu.csv:1: missing column"):
        read_imu_csv(p)
    g = tmp_path / "gnss.csv"
    g.write_text("gps_week,gps_sow,x,y,z\n2150,302000,1,2,3\n")
    ev = tmp_path / "ev.csv"
    ev.write_text("image,gps_week,gps_sow\na,2150,302000.015\n")
    rc = main(["pos", "--mode", "lc", "--imu", str(p), "--gnss", str(g), "--events", str(ev), "--out",
               str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "internal error" not in err, err


def test_validate_helpers():
    assert validate.finite("1.5", "f.csv", 3, "x") == 1.5
    assert validate.integer(12.0) == 12 and validate.integer("7", 0, 10) == 7
    assert validate.image_size(6000, "4000") == (6000, 4000)
    assert validate.number(".Nan") != validate.number(".Nan")
    for bad, fn in ((float("nan"), validate.finite), ("1e400", validate.finite), (True, validate.finite),
                    ("１２", validate.finite), (0.0, validate.positive), (-1e-9, validate.non_negative),
                    (2.5, validate.integer), (None, validate.finite), ([1], validate.finite)):
        with pytest.raises(InputError) as e:
            fn(bad, path="f.csv", line=3, field="x")
        assert str(e.value).startswith("f.csv:3: field 'x': "), str(e.value)
    with pytest.raises(InputError, match=r"f.csv:7: field 'v': 1e\+308 m/s is outside"):
        validate.values_in_range(np.array([1.0, 1e308]), -1e4, 1e4, "f.csv", "v", np.array([6, 7]), unit="m/s")
    a = validate.values_in_range(np.array([1.0, np.nan]), 0, 2, allow_nan=True)
    assert math.isnan(a[1])
    with pytest.raises(InputError, match=r"f.csv:2: field 'gps_week': must be a whole number"):
        validate.gps_week_sow(np.array([2200.0, 2200.5]), np.array([1.0, 2.0]), "f.csv", np.array([1, 2]))


def test_input_errors_are_one_line():
    e = InputError("header has a\nb", "dir/x\ny.csv", 3, "f\u2028g")
    assert "\n" not in str(e) and "\u2028" not in str(e) and str(e).startswith("dir/x y.csv:3: ")
