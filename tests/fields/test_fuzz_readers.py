"""Fuzzing every reader of dgcal's inputs (issue 16): a valid file of each kind (camera.json, OpenCV YAML/XML,
COLMAP, MicMac, field/ground points, measurements, EOPs, events, trajectory, mounting.json, campaign.toml, IMU
text, RINEX observation and navigation files, exports, boards, low-cost logger files), mutated (bytes deleted,
inserted, replaced, lines dropped/doubled/swapped, truncation, invalid UTF-8, unclosed quotes, columns removed,
numbers replaced by NaN, inf, 1e308, 1e-320, 25-digit integers or nothing) either reads or fails with one
InputError line naming the file: never another exception, never a native abort.

tests/fields/test_formats_fuzz.py fuzzes the readers of issue 13 (GNSS solutions, DJI MRK, IMU descriptions, SBET,
time tags, Metashape, ROS camera_info, ODM files); this file covers the rest. The default run tries
`DEFAULT_CASES` mutations per reader; `pytest -m fuzz` runs `LONG_CASES` (>= 2000) each.
"""
from __future__ import annotations

import gzip
import json
import os
from pathlib import Path

import hatanaka
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dgcal.fields.errors import InputError

from fuzz_checks import FuzzStats, check_read, nan_fields
from test_bingo_metashape import H as BINGO_H
from test_bingo_metashape import METASHAPE as METASHAPE_MARKERS
from test_bingo_metashape import PIX_MM as BINGO_PIX_MM
from test_bingo_metashape import W as BINGO_W
from test_bingo_metashape import pix4d_bingo_text, truth
from test_formats_fuzz import GNSS_CSV, NMEA, POS, _mutate
from test_pix4d_companions import GCPS as PIX4D_GCPS
from test_pix4d_companions import MARKS as PIX4D_MARKS
from test_gnss_rinex2 import NAV_211, NAV_304, OBS_211, OBS_304

DEFAULT_CASES = 60
LONG_CASES = int(os.environ.get("DGCAL_FUZZ_CASES", 2000))   # `pytest -m fuzz` (DGCAL_FUZZ_CASES=N to change)

# ---------------------------------------------------------------------------------------------
# mutations: the byte-level ones of test_formats_fuzz plus the ways real files go wrong
# ---------------------------------------------------------------------------------------------
_BASE_OPS = ["del", "ins", "rep", "dropline", "dupline", "swap", "trunc", "num"]
_MORE_OPS = ["badutf8", "quote", "value", "value", "dropcol", "dropheadcol", "blank"]
_VALUES = [b"nan", b"NaN", b"-nan", b"inf", b"-inf", b"Infinity", b"1e308", b"-1e308", b"1e309", b"1e-320",
           b"9999999999999999999999999", b"0", b"-0", b"-1", b"1.5", b"", b"\xef\xbc\x91\xef\xbc\x92", b"true",
           b"[]", b"{}", b'"x"', b"0x1p3", b"1_000"]
OPS = st.lists(st.tuples(st.sampled_from(_BASE_OPS + _MORE_OPS), st.integers(0, 10 ** 6),
                         st.binary(min_size=1, max_size=6)), min_size=1, max_size=4)


def _numeric_tokens(b: bytes) -> list[tuple[int, int]]:
    """(start, end) of every number-like token of `b`."""
    import re
    return [m.span() for m in re.finditer(rb"(?<![A-Za-z_])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][-+]?\d+)?", b)]


def mutate(data: bytes, ops) -> bytes:
    """`data` after the mutations `ops` (op, position, payload)."""
    b = bytes(data)
    for op, pos, payload in ops:
        if op in _BASE_OPS:
            b = _mutate(b, [(op, pos, payload)])
            continue
        if not b:
            b = payload
            continue
        i = pos % len(b)
        if op == "badutf8":
            b = b[:i] + (b"\xff", b"\xc3\x28", b"\xed\xa0\x80", b"\x80")[pos % 4] + b[i:]
        elif op == "quote":
            b = b[:i] + (b'"', b"'", b"[", b"{", b"<")[pos % 5] + b[i:]
        elif op in ("value", "blank"):
            toks = _numeric_tokens(b)
            if toks:
                s, e = toks[pos % len(toks)]
                b = b[:s] + (b"" if op == "blank" else _VALUES[pos % len(_VALUES)]) + b[e:]
        elif op in ("dropcol", "dropheadcol"):
            lines = b.split(b"\n")
            sep = b"," if b"," in b else None
            k = pos % 8
            for j, line in enumerate(lines):
                if op == "dropheadcol" and j > 0:
                    break
                parts = line.split(sep) if sep else line.split(b" ")
                if len(parts) > k:
                    del parts[k]
                    lines[j] = (sep or b" ").join(parts)
            b = b"\n".join(lines)
    return b


# ---------------------------------------------------------------------------------------------
# valid samples, written by dgcal's own writers (or in the other program's exact layout)
# ---------------------------------------------------------------------------------------------
def _camera():
    from dgcal.calib.camera.models import Fraser7
    return Fraser7((6000, 4000), [4000.0, 3010.0, 1985.0, -0.08, 0.05, -0.01, 2e-4, -1e-4, 1.5, 0.0])


def _write(tmp: Path, name: str, writer) -> bytes:
    p = tmp / name
    writer(p)
    return p.read_bytes()


def s_camera_json(tmp):
    from dgcal.calib.camera.files import write_camera_json
    cam = _camera()
    return _write(tmp, "camera.json", lambda p: write_camera_json(p, cam, np.abs(cam.params) * 1e-3 + 1e-6,
                                                                  {"rms_px": 0.2}))


def s_opencv_yaml(tmp):
    import cv2
    def w(p):
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", 640)
        fs.write("image_height", 480)
        fs.write("camera_matrix", np.array([[500.0, 0, 320], [0, 505, 240], [0, 0, 1]]))
        fs.write("distortion_coefficients", np.array([[-0.1, 0.01, 0.001, 0.002, 0.0]]))
        fs.release()
    return _write(tmp, "calib.yml", w)


# OpenCV 4's FileStorage YAML header and layout (what most calibration files on disk look like)
OPENCV4_YAML = b"""%YAML:1.0
---
calibration_time: "Tue 02 Dec 2025 10:00:00 CET"
image_width: 1280
image_height: 720
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 9.1234567890000000e+02, 0., 6.4012345678900000e+02, 0.,
       9.1300000000000000e+02, 3.6000000000000000e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -1.2000000000000000e-01, 5.0000000000000003e-02, 1.0000000000000000e-04,
       -2.0000000000000000e-04, 0. ]
avg_reprojection_error: 2.4000000000000000e-01
"""


def s_opencv_xml(tmp):
    import cv2
    def w(p):
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", 640)
        fs.write("image_height", 480)
        fs.write("camera_matrix", np.array([[500.0, 0, 320], [0, 505, 240], [0, 0, 1]]))
        fs.write("distortion_coefficients", np.array([[-0.1, 0.01, 0.001, 0.002, 0.0, 0.01, 0.0, 0.0]]))
        fs.release()
    return _write(tmp, "calib.xml", w)


def s_colmap(tmp):
    from dgcal.calib.camera.files import write_colmap_cameras_txt
    return _write(tmp, "cameras.txt", lambda p: write_colmap_cameras_txt(p, _camera()))


MICMAC_V1 = b"""<?xml version="1.0" ?>
<ExportAPERO>
     <CalibrationInternConique>
          <KnownConv>eConvApero_DistM2C</KnownConv>
          <PP>3005.5 1990.25</PP>
          <F>4001.5</F>
          <SzIm>6000 4000</SzIm>
          <CalibDistortion>
               <ModRad>
                    <CDist>3004.1 1991.7</CDist>
                    <CoeffDist>-4.9e-09</CoeffDist>
                    <CoeffDist>1.9e-16</CoeffDist>
               </ModRad>
          </CalibDistortion>
     </CalibrationInternConique>
</ExportAPERO>
"""

MMVII = b"""<?xml version="1.0" encoding="ISO8859-1" standalone="yes" ?>
<RootData>
   <InternalCalibration>
      <Name>"CalibIntr_Test"</Name>
      <PixelFrame><NbPix>6000 4000</NbPix></PixelFrame>
      <PerfectProj><F>4002.0</F><PP>3001.0 1995.0</PP></PerfectProj>
      <Projection>"Stenope"</Projection>
      <Distorsion>
         <Radial><K1>-0.08</K1><K2>0.05</K2><K3>-0.01</K3></Radial>
         <Decentric><p1>1e-3</p1><p2>-2e-3</p2></Decentric>
         <Polynomial><b1>1e-4</b1><b2>0</b2></Polynomial>
      </Distorsion>
   </InternalCalibration>
</RootData>
"""


def _points():
    from dgcal.fields.io.formats import Points
    ids = np.array([f"P{k}" for k in range(6)], dtype=object)
    xyz = np.column_stack([480000 + 10.0 * np.arange(6), 4438000 + 7.0 * np.arange(6), 1600 + np.arange(6.0)])
    return Points(ids, xyz, np.full((6, 3), 0.02), np.array(["control", "check"] * 3, dtype=object))


def s_points(tmp):
    from dgcal.fields.io.formats import write_points
    return _write(tmp, "gcp.csv", lambda p: write_points(p, _points(), with_role=True))


def s_measurements(tmp):
    from dgcal.fields.io.formats import Measurements, write_measurements
    n = 8
    m = Measurements(np.array([f"IMG_{k % 3}.JPG" for k in range(n)], dtype=object),
                     np.array([f"P{k}" for k in range(n)], dtype=object),
                     np.column_stack([100 + 37.5 * np.arange(n), 2000 - 11.25 * np.arange(n)]), np.full((n, 2), 0.5))
    return _write(tmp, "measurements.csv", lambda p: write_measurements(p, m))


MICMAC_POINTS = b"""<?xml version="1.0" ?>
<Global>
  <DicoAppuisFlottant>
    <OneAppuisDAF>
      <Pt>480000.5 4438000.25 1600.125</Pt>
      <NamePt>P1</NamePt>
      <Incertitude>0.01 0.01 0.02</Incertitude>
    </OneAppuisDAF>
    <OneAppuisDAF>
      <Pt>480010.5 4438007.25 1601.125</Pt>
      <NamePt>P2</NamePt>
      <Incertitude>1 1 1</Incertitude>
    </OneAppuisDAF>
  </DicoAppuisFlottant>
</Global>
"""

MICMAC_MEASUREMENTS = b"""<?xml version="1.0" ?>
<SetOfMesureAppuisFlottants>
  <MesureAppuiFlottant1Im>
    <NameIm>IMG_0001.JPG</NameIm>
    <OneMesureAF1I><NamePt>P1</NamePt><PtIm>1024.5 768.25</PtIm></OneMesureAF1I>
    <OneMesureAF1I><NamePt>P2</NamePt><PtIm>2048.5 1536.75</PtIm></OneMesureAF1I>
  </MesureAppuiFlottant1Im>
</SetOfMesureAppuisFlottants>
"""


def _eop():
    from dgcal.fields.io.formats import EOP
    n = 5
    return EOP(np.array([f"IMG_{k:04d}.JPG" for k in range(n)], dtype=object),
               np.column_stack([480000 + 50.0 * np.arange(n), 4438000 + np.zeros(n), 1900 + np.zeros(n)]),
               np.column_stack([0.5 * np.arange(n), -0.25 * np.arange(n), 90.0 + np.arange(n)]),
               np.tile([0.03, 0.03, 0.04, 0.003, 0.003, 0.002], (n, 1)))


def s_eop(tmp):
    from dgcal.fields.io.formats import write_eop
    return _write(tmp, "eop.csv", lambda p: write_eop(p, _eop()))


def s_events(tmp):
    from dgcal.fields.io.formats import Events, write_events
    ev = Events(np.array([f"IMG_{k:04d}.JPG" for k in range(5)], dtype=object), 2200 * 604800 + 300000.5
                + 1.5 * np.arange(5))
    return _write(tmp, "events.csv", lambda p: write_events(p, ev))


def _trajectory():
    from dgcal.fields.io.formats import Trajectory
    n = 6
    t = 2200 * 604800 + 300000.0 + 0.5 * np.arange(n)
    return Trajectory(t, 40.1 + 1e-5 * np.arange(n), -105.1 + 1e-5 * np.arange(n), 1800 + np.zeros(n),
                      np.tile([20.0, 5.0, 0.1], (n, 1)), np.tile([1.0, 2.0, 75.0], (n, 1)),
                      np.tile([0.05, 0.05, 0.08, 0.01, 0.01, 0.03], (n, 1)))


def s_trajectory(tmp):
    from dgcal.fields.io.formats import write_trajectory
    return _write(tmp, "trajectory.csv", lambda p: write_trajectory(p, _trajectory()))


def s_mounting(tmp):
    from dgcal.calib.mounting.common import MountingResult
    cov = np.diag([1e-6, 4e-4, 4e-4, 9e-4, 1e-8, 1e-8, 4e-8])
    cov[1, 2] = cov[2, 1] = 1e-4
    m = MountingResult("joint", np.array([0.31, -0.12, 0.25]), np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]),
                       -0.014, cov, 20, ["IMG_0007.JPG"], ["a warning"],
                       {"image": ["IMG_0001.JPG", "IMG_0002.JPG"], "lever_x": [0.3, 0.32]},
                       {"pos_common_fraction": 0.5, "covariance_random": (cov / 2).tolist()}, "joint")
    return json.dumps(m.to_json(), indent=2).encode()


CAMPAIGN = b"""# a campaign
name = "fuzz"
crs = "EPSG:32651"
truth = "truth.json"

[camera]
field = "field/field.csv"
measurements = "field/measurements.csv"
image_size = [6000, 4000]
model = "fraser7"
args = ["--reject", "4"]

[triangulation]
gcp = "flight/gcp.csv"
measurements = "flight/measurements.csv"

[pos]
mode = "tc"
imu = "flight/imu.txt"
events = "flight/events.csv"
rinex_obs = "flight/rover.rnx"
rinex_nav = "flight/nav.rnx"
rinex_base = "flight/base.rnx"
base_position = [-2975439.6748, 5029425.6965, 2547360.6518]
frequencies = 2
imu_grade = "flight/imu_model.toml"
lever_arm_gnss = [0.05, 0, -0.35]
set = ["gnss_sigma_scale=1.5"]

[mount]
method = "proposed"
compare = ["traditional", "iso"]
pos_common_fraction = 1.0

[check]
gcp = "flight/gcp.csv"
measurements = "flight/measurements_gcp.csv"
events = "flight/events.csv"
"""


def _imu():
    from dgcal.pos.ins.imu_data import ImuData
    n = 40
    t = 2150 * 604800 + 302000.0 + 0.01 * (1 + np.arange(n))
    rng = np.random.default_rng(3)
    return ImuData(t, rng.normal(0, 1e-4, (n, 3)), rng.normal(0, 1e-3, (n, 3)) + [0, 0, -0.098], 100.0)


def s_imu_csv(tmp):
    from dgcal.pos.ins.imu_data import write_imu_csv
    return _write(tmp, "imu.csv", lambda p: write_imu_csv(p, _imu()))


def s_kf_gins(tmp):
    from dgcal.pos.ins.imu_data import write_kf_gins
    return _write(tmp, "imu.txt", lambda p: write_kf_gins(p, _imu()))


PIX4D = (b"imageName X Y Z Omega Phi Kappa\n"
         b"IMG_0001.JPG 480000.123 4438000.456 1800.789 1.25 -0.5 89.75\n"
         b"IMG_0002.JPG 480050.123 4438000.456 1800.789 1.5 -0.25 90.25\n")


def s_metashape_opk(tmp):
    from dgcal.reports.exports.eop import write_metashape
    return _write(tmp, "metashape_opk.csv", lambda p: write_metashape(p, _eop()))


def s_colmap_images(tmp):
    """images.txt of dgcal's COLMAP export (the folder also holds georef.json, which stays valid)."""
    from dgcal.fields.crs import MapGrid
    from dgcal.reports.exports.eop import write_colmap
    d = tmp / "colmap_sample"
    write_colmap(d, _eop(), MapGrid("EPSG:32613"), _camera())
    return (d / "images.txt").read_bytes()


BOARD = b'type = "charuco"\ncolumns = 7\nrows = 5\nsquare_m = 0.04\nmarker_m = 0.03\ndictionary = "DICT_5X5_250"\n'


def s_gnss_fixes(tmp):
    from dgcal.pos.lowcost.fix_files import GnssFixes, write_gnss_fixes
    n = 5
    fx = GnssFixes(2150 * 604800 + 302000.0 + 0.2 * np.arange(n),
                   np.tile([-1283621.1, -4726905.3, 4079536.2], (n, 1)) + np.arange(n)[:, None],
                   np.tile([1.5, 1.5, 3.0], (n, 1)), np.tile([1.0, 2.0, 0.5], (n, 1)),
                   np.tile([0.1, 0.1, 0.2], (n, 1)))
    return _write(tmp, "gnss_fixes.csv", lambda p: write_gnss_fixes(p, fx))


LOGGER_FORMAT = b"""# a logger described in TOML
rate_hz = 50.0
counter_bits = 16
delimiter = ","
header = true
[columns]
counter = "counter"
pps = "pps"
photo = "photo"
trigger = "trigger"
[units]
laser = "cm"
[signals]
photo_polarity = -1
pps_inverted = false
trigger_level = 0.5
[gnss]
rate_hz = 50.0
week = "gps_week"
time = "gps_sow"
height = "h"
"""
GNSS_LOG = b"gps_week,gps_sow,h\n" + b"".join(b"2150,%.2f,%.3f\n" % (302000 + 0.02 * k, 120.5 + 0.01 * k)
                                              for k in range(12))
LOGGER_CSV = b"counter,pps,photo,trigger\n" + b"".join(b"%d,%d,%.3f,%d\n" % (k, k % 50 == 0, 0.5, k == 7)
                                                       for k in range(12))
SYNC_IMAGES = b"image,camera_time_s\nDSC_0001.JPG,1751980000.25\nDSC_0002.JPG,1751980002.5\n"
GNSS_VELOCITY = b"t_gps,vn,ve,vd\n" + b"".join(b"%.1f,%.3f,%.3f,0.1\n" % (1.3e9 + 0.2 * k, 10 + 0.01 * k, -3.0)
                                               for k in range(12))


def s_dem(tmp):
    from dgcal.calib.dg.dem import Dem, write_geotiff_dem
    H = 100 + np.arange(20.0).reshape(4, 5)
    dem = Dem(H, np.array([[10.0, 0.0, 480000.0], [0.0, -10.0, 4438000.0]]), "EPSG:32613")
    return _write(tmp, "dem.tif", lambda p: write_geotiff_dem(p, dem))


def s_plate_layout(tmp):
    from dgcal.fields.targets.plate import TargetField, write_field
    write_field(tmp / "plate_field.csv", TargetField(square_m=0.16, marker_m=0.12))
    return (tmp / "plate_field.json").read_bytes()


def s_board_layout(tmp):
    from dgcal.fields.targets.boards import Board, write_board_field
    write_board_field(tmp / "board_field.csv", Board("charuco", 5, 4, 0.03, 0.02, "DICT_4X4_50"))
    return (tmp / "board_field.json").read_bytes()


def _layout_reader(module: str, name: str):
    def make(tmp):
        import importlib
        load = getattr(importlib.import_module(module), name)
        return lambda p: load(p.with_suffix(".csv"))   # the layout JSON beside a field CSV
    return make


BINGO = pix4d_bingo_text(truth(n_img=2, n_pts=3))
LASER_RANGES = b"image,range_m,s_range_m\nIMG_0001.JPG,120.5,0.05\nIMG_0002.JPG,121.25,0.05\n"


def s_ulog(tmp):
    from ulog_writer import ulog_bytes
    return ulog_bytes(4.0, rate_hz=100.0)


def _bag_imu(tmp, version: int) -> Path:
    from test_pos_io_rosbags import T0_UNIX, TS, TS1, _imu_msg, _write
    u = T0_UNIX + np.arange(12) / 100
    bag = tmp / ("sample.bag" if version == 1 else "sample_bag")
    if not bag.exists():
        _write(bag, version, {"/imu": ("sensor_msgs/msg/Imu", [(x, _imu_msg(x, [0.1, 0, 0], [0, 0, 9.8],
                                                                            TS1 if version == 1 else TS))
                                                                for x in u])})
    return bag


def s_ros1_bag(tmp):
    return _bag_imu(tmp, 1).read_bytes()


def s_ros2_db3(tmp):
    return next(_bag_imu(tmp, 2).glob("*.db3")).read_bytes()


def _ros2_reader(tmp):
    """read_rosbag_imu of a ROS 2 bag folder whose .db3 is the mutated file (errors name the folder: say it is `p`)."""
    from dgcal.pos.ros_bags import read_rosbag_imu
    bag = _bag_imu(tmp, 2)
    db3 = next(bag.glob("*.db3"))

    def read(p):
        db3.write_bytes(p.read_bytes())
        try:
            return read_rosbag_imu(bag)
        except InputError as exc:
            raise InputError(str(exc).replace(str(bag), str(p))) from None
    return read


def s_sp3(tmp):
    import gzip
    src = Path(__file__).resolve().parents[1] / "pos/gnss/data/COD0MGXFIN_20210781100_02H_05M_ORB.SP3.gz"
    lines = gzip.open(src, "rb").read().split(b"\n")
    epochs = [i for i, ln in enumerate(lines) if ln.startswith(b"*")]
    body = lines[:epochs[2]]
    # as real products have them: a satellite missing at one epoch, one bad clock (NaN in memory: "no value")
    del body[epochs[1] + 1]
    first = epochs[0] + 1
    body[first] = body[first][:46] + b"999999.999999" + body[first][60:]
    return b"\n".join(body + [b"EOF", b""])


def s_smrmsg(tmp):
    from dgcal.pos.ins.sbet import SMRMSG_DTYPE
    r = np.zeros(4, SMRMSG_DTYPE)
    r["time"] = 243258.5 + np.arange(4)
    for name in SMRMSG_DTYPE.names[1:]:
        r[name] = 0.01 + 0.001 * np.arange(4)
    return r.tobytes()


def _colmap_tracks_model(tmp) -> Path:
    from test_colmap_tracks import write_text_model
    d = tmp / "colmap_tracks_model"
    if not d.exists():
        write_text_model(d, np.random.default_rng(5), n_img=3, n_pts=8)
    return d


def s_colmap_tracks_images(tmp):
    return (_colmap_tracks_model(tmp) / "images.txt").read_bytes()


def _colmap_tracks_reader(tmp):
    """read_colmap_tracks of a model folder whose images.txt is the mutated file (errors naming it: say it is `p`)."""
    from dgcal.fields.io.colmap_tracks import read_colmap_tracks
    d = _colmap_tracks_model(tmp)

    def read(p):
        (d / "images.txt").write_bytes(p.read_bytes())
        try:
            return read_colmap_tracks(d)
        except InputError as exc:
            raise InputError(str(exc).replace(str(d / "images.txt"), str(p)).replace(str(d), str(p))) from None
    return read


def _bingo_reader(tmp):
    from dgcal.fields.io.bingo import read_bingo
    return lambda p: read_bingo(p, (BINGO_W, BINGO_H), BINGO_PIX_MM)


def _smrmsg_reader(tmp):
    from dgcal.pos.ins.sbet import read_smrmsg
    return lambda p: read_smrmsg(p, 2374)


def _imu_input_reader(tmp):
    from dgcal.pos.readers import ImuInput, read_imu_input
    return lambda p: read_imu_input(ImuInput(p), gps_week=2150)


def _fix_input_reader(tmp):
    from dgcal.pos.readers import FixInput, read_fix_input
    return lambda p: read_fix_input(FixInput(p))


# ---------------------------------------------------------------------------------------------
# the readers
# ---------------------------------------------------------------------------------------------
def _camera_reader(tmp):
    from dgcal.calib.camera.files import read_camera
    return read_camera


def _plan_reader(tmp):
    from dgcal.campaign import load_campaign, plan

    def read(p):
        return plan(load_campaign(p), tmp / "campaign_out")
    return read


def _colmap_reader(tmp):
    from dgcal.reports.exports.eop import read_colmap
    d = tmp / "colmap_model"
    s_colmap_images(tmp)
    import shutil
    shutil.copytree(tmp / "colmap_sample", d, dirs_exist_ok=True)

    def read(p):
        (d / "images.txt").write_bytes(p.read_bytes())
        try:
            return read_colmap(d)
        except InputError as exc:   # the error names images.txt of the folder: say it is `p`
            if "images.txt" in str(exc):
                raise InputError(str(exc).replace(str(d / "images.txt"), str(p))) from None
            raise
    return read


def _imp(module: str, name: str):
    def make(tmp):
        import importlib
        return getattr(importlib.import_module(module), name)
    return make


def _logger_reader(tmp):
    from dgcal.pos.lowcost.logger_format import read_logger, read_logger_format
    fmt = tmp / "logger.toml"
    fmt.write_bytes(LOGGER_FORMAT)
    return lambda p: read_logger(p, read_logger_format(fmt), 2150)


def _imu_text_reader(tmp):
    from dgcal.pos.ins.imu_data import read_imu_text
    return lambda p: read_imu_text(p, gps_week=2150)


def _const(data: bytes):
    return lambda tmp: data


UBX_LOG = Path(__file__).parents[1] / "pos" / "gnss" / "data" / "walk_0827_60s.ubx"


def s_ubx_obs(tmp):
    """The real u-blox log's first 12 RXM-RAWX epochs with the NMEA sentences between them (`pos/gnss/ubx.py`)."""
    data, k = UBX_LOG.read_bytes(), 0
    for _ in range(13):
        k = data.find(b"\xb5\x62\x02\x15", k + 1)
    return data[:k]


def s_ubx_nav(tmp):
    """The real log's first RAWX epoch and every RXM-SFRBX message, re-framed (3 GPS, 6 Galileo, 8 BeiDou sets)."""
    from dgcal.pos.gnss.ubx import ubx_frame, ubx_frames
    msgs = ubx_frames(UBX_LOG.read_bytes()).messages
    first = next(m for m in msgs if m[:2] == (0x02, 0x15))
    return ubx_frame(*first) + b"".join(ubx_frame(*m) for m in msgs if m[:2] == (0x02, 0x13))


READERS = {
    # cameras
    "camera-json": (s_camera_json, ".json", _camera_reader),
    "opencv-yaml-cv2": (s_opencv_yaml, ".yml", _camera_reader),
    "opencv-yaml-4": (_const(OPENCV4_YAML), ".yaml", _camera_reader),
    "opencv-xml": (s_opencv_xml, ".xml", _camera_reader),
    "colmap-cameras-opencv": (s_colmap, ".txt", _camera_reader),
    "micmac-v1": (_const(MICMAC_V1), ".xml", _camera_reader),
    "mmvii": (_const(MMVII), ".xml", _camera_reader),
    # ground, image measurements
    "points-csv": (s_points, ".csv", _imp("dgcal.fields.io.formats", "read_points")),
    "any-points-csv": (s_points, ".csv", _imp("dgcal.fields.io.gcp_files", "read_any_points")),
    "measurements-csv": (s_measurements, ".csv", _imp("dgcal.fields.io.formats", "read_measurements")),
    "any-measurements-csv": (s_measurements, ".csv", _imp("dgcal.fields.io.gcp_files", "read_any_measurements")),
    "micmac-points": (_const(MICMAC_POINTS), ".xml", _imp("dgcal.fields.io.gcp_files", "read_any_points")),
    "micmac-measurements": (_const(MICMAC_MEASUREMENTS), ".xml",
                            _imp("dgcal.fields.io.gcp_files", "read_any_measurements")),
    # orientations, times, POS
    "eop-csv": (s_eop, ".csv", _imp("dgcal.fields.io.formats", "read_eop")),
    "events-csv": (s_events, ".csv", _imp("dgcal.fields.io.formats", "read_events")),
    "any-events-csv": (s_events, ".csv", _imp("dgcal.pos.events", "read_any_events")),
    "trajectory-csv": (s_trajectory, ".csv", _imp("dgcal.fields.io.formats", "read_trajectory")),
    "any-trajectory-csv": (s_trajectory, ".csv", _imp("dgcal.pos.ins.sbet", "read_any_trajectory")),
    "mounting-json": (s_mounting, ".json", _imp("dgcal.calib.mounting.common", "read_mounting_json")),
    "campaign-toml": (_const(CAMPAIGN), ".toml", _plan_reader),
    "imu-csv": (s_imu_csv, ".csv", _imp("dgcal.pos.ins.imu_data", "read_imu_csv")),
    "imu-kf-gins": (s_kf_gins, ".txt", _imp("dgcal.pos.ins.imu_data", "read_kf_gins")),
    "imu-text": (s_kf_gins, ".txt", _imu_text_reader),
    "rinex-obs-2": (_const(OBS_211.encode()), ".21o", _imp("dgcal.pos.gnss.rinex", "read_rinex_obs")),
    "rinex-obs-3": (_const(OBS_304.encode()), ".rnx", _imp("dgcal.pos.gnss.rinex", "read_rinex_obs")),
    # Hatanaka-compressed (crx2rnx on the mutated stream) and gzip containers (`pos/gnss/gnss_files.py`)
    "rinex-obs-crinex": (_const(hatanaka.rnx2crx(OBS_304.encode())), ".21d",
                         _imp("dgcal.pos.gnss.rinex", "read_rinex_obs")),
    "rinex-obs-gzip": (_const(gzip.compress(OBS_211.encode())), ".21o.gz",
                       _imp("dgcal.pos.gnss.rinex", "read_rinex_obs")),
    "rinex-nav-2": (_const(NAV_211.encode()), ".21n", _imp("dgcal.pos.gnss.rinex", "read_rinex_nav")),
    "rinex-nav-3": (_const(NAV_304.encode()), ".rnx", _imp("dgcal.pos.gnss.rinex", "read_rinex_nav")),
    "rinex-nav-4": (_const((Path(__file__).parents[1] / "pos" / "gnss" / "data" / "233h_rnx_part.nav").read_bytes()),
                    ".rnx", _imp("dgcal.pos.gnss.rinex", "read_rinex_nav")),
    # u-blox UBX raw logs read as RINEX (`pos/gnss/ubx.py`)
    "ubx-obs": (s_ubx_obs, ".ubx", _imp("dgcal.pos.gnss.rinex", "read_rinex_obs")),
    "ubx-nav": (s_ubx_nav, ".ubx", _imp("dgcal.pos.gnss.rinex", "read_rinex_nav")),
    # exports read back
    "pix4d": (_const(PIX4D), ".txt", _imp("dgcal.reports.exports.eop", "read_pix4d")),
    "metashape-opk": (s_metashape_opk, ".csv", _imp("dgcal.reports.exports.eop", "read_metashape")),
    "colmap-images": (s_colmap_images, ".txt", _colmap_reader),
    # boards, low-cost payload files
    "board-toml": (_const(BOARD), ".toml", _imp("dgcal.fields.targets.boards", "read_board")),
    "gnss-fixes": (s_gnss_fixes, ".csv", _imp("dgcal.pos.lowcost.fix_files", "read_gnss_fixes")),
    "logger-format": (_const(LOGGER_FORMAT), ".toml", _imp("dgcal.pos.lowcost.logger_format",
                                                           "read_logger_format")),
    "gnss-log": (_const(GNSS_LOG), ".csv", _imp("dgcal.pos.lowcost.logger_format", "read_gnss_log")),
    "logger-csv": (_const(LOGGER_CSV), ".csv", _logger_reader),
    "laser-ranges": (_const(LASER_RANGES), ".csv", _imp("dgcal.calib.dg.single_image", "read_laser_ranges")),
    "sync-images-csv": (_const(SYNC_IMAGES), ".csv", _imp("dgcal.pos.lowcost.sync", "read_images")),
    "gnss-velocity": (_const(GNSS_VELOCITY), ".csv", _imp("dgcal.pos.lowcost.flow", "read_gnss_velocity")),
    "geotiff-dem": (s_dem, ".tif", _imp("dgcal.calib.dg.dem", "read_geotiff_dem")),
    # binary logs and bags, the POS input registries (sniffed by content), precise orbits, SBET sigmas
    "px4-ulog-imu": (s_ulog, ".ulg", _imp("dgcal.pos.ins.ulog", "read_ulog_imu")),
    "px4-ulog-camera": (s_ulog, ".ulg", _imp("dgcal.pos.ins.ulog", "read_ulog_camera_capture")),
    "ros1-bag-imu": (s_ros1_bag, ".bag", _imp("dgcal.pos.ros_bags", "read_rosbag_imu")),
    "ros2-bag-imu": (s_ros2_db3, ".db3", _ros2_reader),
    "imu-input-csv": (s_imu_csv, ".csv", _imu_input_reader),
    "imu-input-kf-gins": (s_kf_gins, ".txt", _imu_input_reader),
    "imu-input-ulog": (s_ulog, ".ulg", _imu_input_reader),
    "fix-input-gnss-csv": (_const(GNSS_CSV.encode()), ".csv", _fix_input_reader),
    "fix-input-rtklib-pos": (_const(POS.encode()), ".pos", _fix_input_reader),
    "fix-input-nmea": (_const(NMEA.encode()), ".nmea", _fix_input_reader),
    "sp3": (s_sp3, ".sp3", _imp("dgcal.pos.gnss.precise", "read_sp3")),
    "smrmsg": (s_smrmsg, ".out", _smrmsg_reader),
    # the companions of Pix4D's and Metashape's exports (issue 29's readers)
    "pix4d-gcps": (_const(PIX4D_GCPS.encode()), ".txt", _imp("dgcal.fields.io.pix4d_marks", "read_pix4d_gcps")),
    "pix4d-marks": (_const(PIX4D_MARKS.encode()), ".txt", _imp("dgcal.fields.io.pix4d_marks", "read_pix4d_marks")),
    "metashape-markers": (_const(METASHAPE_MARKERS.encode()), ".xml", _imp("dgcal.fields.io.metashape_markers",
                                                                            "read_metashape_markers")),
    "pix4d-bingo": (_const(BINGO.encode()), ".txt", _bingo_reader),
    "centres-csv": (s_eop, ".csv", _imp("dgcal.fields.io.centres", "read_centres")),
    "colmap-tracks": (s_colmap_tracks_images, ".txt", _colmap_tracks_reader),
    "plate-layout-json": (s_plate_layout, ".json", _layout_reader("dgcal.fields.targets.plate", "load_layout")),
    "board-layout-json": (s_board_layout, ".json", _layout_reader("dgcal.fields.targets.boards",
                                                                   "load_board_layout")),
}

def check_one(reader, p: Path, data: bytes) -> None:
    """Write `data` to `p` and read it: a result or one InputError line naming the file."""
    check_read(reader, p, data, FuzzStats("one"))


def _fuzz(name: str, tmp_path_factory, n: int) -> None:
    tmp = tmp_path_factory.mktemp(name)
    build, suffix, make = READERS[name]
    sample = build(tmp)
    reader = make(tmp)
    p = tmp / f"input{suffix}"
    p.write_bytes(sample)
    allowed_nan = nan_fields(reader(p))
    stats = FuzzStats(name)

    @settings(max_examples=n, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(OPS)
    def run(ops):
        check_read(reader, p, mutate(sample, ops), stats, allowed_nan)
    try:
        run()
    finally:
        stats.record()


@pytest.mark.parametrize("name", sorted(READERS))
def test_valid_sample_reads(name, tmp_path):
    build, suffix, make = READERS[name]
    p = tmp_path / f"input{suffix}"
    p.write_bytes(build(tmp_path))
    make(tmp_path)(p)


@pytest.mark.parametrize("name", sorted(READERS))
def test_reader_fuzz(name, tmp_path_factory):
    _fuzz(name, tmp_path_factory, DEFAULT_CASES)


@pytest.mark.fuzz
@pytest.mark.parametrize("name", sorted(READERS))
def test_reader_fuzz_long(name, tmp_path_factory):
    _fuzz(name, tmp_path_factory, LONG_CASES)

