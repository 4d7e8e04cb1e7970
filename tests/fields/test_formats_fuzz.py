# ruff: noqa: E501  (the RTKLIB .pos sample keeps its real line length)
"""Fuzzing every file reader of issue 13 (hypothesis): a valid file of the real shape, mutated (bytes deleted,
inserted, replaced, lines dropped, doubled, swapped, truncated), either reads or fails with one InputError line
naming the file - never another exception. 200 cases per reader here; `pytest -m fuzz` runs 2000 each."""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dgcal.calib.camera.files import read_camera
from dgcal.fields.io.gcp_files import read_odm_gcp_list
from dgcal.pos.events import read_any_events, read_mrk, read_utc_events
from dgcal.pos.gnss.solution_files import read_gnss_csv, read_nmea_gga, read_rtklib_pos
from dgcal.pos.ins.error_model import read_imu_datasheet
from dgcal.pos.ins.imu_formats import imu_format, read_imu
from dgcal.pos.ins.sbet import SBET_DTYPE, read_sbet
from dgcal.pos.ins.time_tags import read_time_tag
from dgcal.reports.exports.calibration import read_calibration_export
from dgcal.reports.exports.eop import read_odm_geo

from fuzz_checks import FuzzStats, check_read, nan_fields

from test_formats_misreads import COLMAP_TWO_CAMERAS, METASHAPE_CAMERAS_XML, ODM_GCP_4326, ROS_CAMERA_INFO

# the real RTKLIB layout (one line per epoch, wider than the line limit)
POS = """% program   : RTKPOST ver.demo5 b34h
% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)
%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio    vn(m/s)    ve(m/s)    vu(m/s)      sdvn     sdve     sdvu    sdvne    sdveu    sdvun
2025/07/08 19:34:18.499   40.096626800 -105.147448300  1601.4740   1  21   0.0099   0.0099   0.0100   0.0000   0.0000   0.0000   0.00    0.0    0.01000   -0.00200    0.00900   0.05869  0.05869  0.05869  0.00000  0.00000  0.00000
2025/07/08 19:34:18.749   40.096626800 -105.147448300  1601.4760   1  21   0.0099   0.0099   0.0100   0.0010  -0.0020   0.0005   0.00    0.0    0.00100    0.00200   -0.00600   0.05586  0.05586  0.05586  0.00000  0.00000  0.00000
2025/07/08 19:34:18.999   40.096626800 -105.147448300  1601.4760   2  21   0.0599   0.0699   0.1200   0.0100   0.0000   0.0000   1.00    2.1   -0.00500    0.00300   -0.00100   0.06152  0.06152  0.06152  0.00000  0.00000  0.00000
"""
def _nmea(body: str) -> str:
    c = 0
    for ch in body:
        c ^= ord(ch)
    return f"${body}*{c:02X}\r\n"


NMEA = (_nmea("GPRMC,193418.40,A,4005.79761,N,10508.84690,W,0.011,,080725,,,D")
        + _nmea("GPGGA,193418.40,4005.79761,N,10508.84690,W,4,12,0.79,1621.1,M,-19.6,M,1.0,0000")
        + _nmea("GPGGA,193418.60,4005.79762,N,10508.84691,W,5,12,0.79,1621.2,M,-19.6,M,1.0,0000"))
GNSS_CSV = ("gps_week,gps_sow,x,y,z,fix,sx,sy,sz,sxy,sxz,syz\n"
            "2374,243258.5,-1283621.1,-4726905.3,4079536.2,fixed,0.01,0.02,0.02,0.005,-0.004,0.01\n"
            "2374,243259.5,-1283622.1,-4726905.3,4079536.2,float,0.05,0.05,0.06,0,0,0\n")
MRK = ("1\t282401.669089\t[2404]\t   101,N\t   107,E\t   129,V\t22.77995359,Lat\t114.10089118,Lon\t139.231,Ellh\t"
       "0.002967, 0.003104, 0.007622\t50,Q\r\n"
       "2\t282403.671212\t[2404]\t    -7,N\t    13,E\t   212,V\t22.77997101,Lat\t114.10089203,Lon\t139.244,Ellh\t"
       "0.002971, 0.003101, 0.007630\t50,Q\r\n")
UTC_EVENTS = "image,utc\nDSC0001.JPG,2025-07-08T19:34:18.123Z\nDSC0002.JPG,2025-07-08 19:34:20.125\n"
IMU_CSV = "".join(f"0.1{i % 10}1,0.02{i % 7},1.0{i % 3}3,-0.671,3.082,0.198,{261906 + 10 * i}\n" for i in range(12))
IMU_TOML = ('preset = "rtklibexplorer"\n[axes]\neuler_zyx_deg = [180, 0, 180]\nmounting_deg = [0, -6.79, 5.35]\n'
            'mounting = "add"\n')
GRADE = ('name = "x"\nbase = "adis16405"\n[gyro]\nnoise_density_deg_s_rt_hz = 0.0038\nturn_on_deg_s = 0.2\n'
         '[accel]\nnoise_density_ug_rt_hz = 70\nrange_g = 16\n')
GEO = ("EPSG:32613\nIMG_0001.JPG 480000.0 4438000.0 1800.0 15.2 0.4 -0.3 0.02 0.04\n"
       "IMG_0002.JPG 480100.0 4438010.0 1801.0 195.0 1.1 0.2\n")
CAL = ("# dgcal mounting (joint) for pospac\nformat: pospac\ndelay_s: -0.014\nmethod: joint\n"
       "lever_arm_xyz_m: 0.31 -0.12 0.25\nframe: vehicle x forward, y right, z down\n"
       "boresight_tx_ty_tz_deg: 0.1 -0.2 0.3\nboresight_tx_ty_tz_arcmin: 6 -12 18\n")


def _tag_bytes(n: int = 8) -> bytes:
    head = bytearray(64)
    head[:20] = b"TIMETAG RTKLIB demo5"
    head[60:] = struct.pack("<I", 1132621244)
    rec = b"".join(struct.pack("<II", 131 + 15 * i, 37 + 60 * i) for i in range(n))
    return bytes(head) + struct.pack("<Id", 1752003261, 0.854) + rec


def _sbet_bytes(n: int = 3) -> bytes:
    r = np.zeros(n, SBET_DTYPE)
    r["time"] = 243258.5 + np.arange(n)
    r["lat"], r["lon"], r["alt"] = np.radians(40.1), np.radians(-105.1), 1601.0
    return r.tobytes()


def _imu_reader(tmp: Path):
    (tmp / "f.toml").write_text(IMU_TOML)
    tag = tmp / "imu.csv.tag"
    tag.write_bytes(_tag_bytes(20))

    def read(p: Path):
        return read_imu(p, imu_format(tmp / "f.toml"), tag=tag)
    return read


READERS = {
    "rtklib-pos": (POS.encode(), ".pos", lambda tmp: read_rtklib_pos),
    "nmea-gga": (NMEA.encode(), ".nmea", lambda tmp: read_nmea_gga),
    "gnss-csv": (GNSS_CSV.encode(), ".csv", lambda tmp: read_gnss_csv),
    "dji-mrk": (MRK.encode(), ".MRK", lambda tmp: read_mrk),
    "utc-events": (UTC_EVENTS.encode(), ".csv", lambda tmp: read_utc_events),
    "any-events": (MRK.encode(), ".MRK", lambda tmp: read_any_events),
    "imu-description": (IMU_CSV.encode(), ".csv", _imu_reader),
    "imu-format-toml": (IMU_TOML.encode(), ".toml", lambda tmp: imu_format),
    "imu-datasheet": (GRADE.encode(), ".toml", lambda tmp: read_imu_datasheet),
    "time-tag": (_tag_bytes(), ".tag", lambda tmp: read_time_tag),
    "sbet": (_sbet_bytes(), ".out", lambda tmp: (lambda p: read_sbet(p, 2374))),
    "metashape-xml": (METASHAPE_CAMERAS_XML.encode(), ".xml", lambda tmp: read_camera),
    "ros-camera-info": (ROS_CAMERA_INFO.encode(), ".yaml", lambda tmp: read_camera),
    "colmap-cameras": (COLMAP_TWO_CAMERAS.rsplit("2 PINHOLE", 1)[0].encode(), ".txt", lambda tmp: read_camera),
    "odm-gcp-list": (ODM_GCP_4326.encode(), ".txt", lambda tmp: read_odm_gcp_list),
    "odm-geo": (GEO.encode(), ".txt", lambda tmp: read_odm_geo),
    "calibration-export": (CAL.encode(), ".txt", lambda tmp: read_calibration_export),
}

_OPS = st.lists(st.tuples(st.sampled_from(["del", "ins", "rep", "dropline", "dupline", "swap", "trunc", "num"]),
                          st.integers(0, 10 ** 6), st.binary(min_size=1, max_size=6)), min_size=1, max_size=4)
_NUMS = [b"nan", b"inf", b"-1e309", b"1e400", b"-0", b"99999999999", b"", b"1.5.2", b"-", b"0x10", b"\xff\xfe"]


def _mutate(data: bytes, ops) -> bytes:
    b = bytearray(data)
    for op, pos, payload in ops:
        if not b:
            b = bytearray(payload)
            continue
        i = pos % len(b)
        lines = bytes(b).split(b"\n")
        j = pos % len(lines)
        if op == "del":
            del b[i:i + len(payload)]
        elif op == "ins":
            b[i:i] = payload
        elif op == "rep":
            b[i:i + len(payload)] = payload
        elif op == "dropline":
            del lines[j]
            b = bytearray(b"\n".join(lines))
        elif op == "dupline":
            lines.insert(j, lines[j])
            b = bytearray(b"\n".join(lines))
        elif op == "swap" and len(lines) > 1:
            k = (j + 1) % len(lines)
            lines[j], lines[k] = lines[k], lines[j]
            b = bytearray(b"\n".join(lines))
        elif op == "trunc":
            b = b[:i]
        elif op == "num":
            toks = bytes(b).replace(b",", b" , ").replace(b"\t", b" \t ").split(b" ")
            nums = [k for k, t in enumerate(toks) if t[:1].isdigit() or t[:1] == b"-"]
            if nums:
                toks[nums[pos % len(nums)]] = _NUMS[pos % len(_NUMS)]
                b = bytearray(b" ".join(toks).replace(b" , ", b",").replace(b" \t ", b"\t"))
    return bytes(b)


def _fuzz(name: str, tmp_path_factory, n: int) -> None:
    tmp = tmp_path_factory.mktemp(name)
    sample, suffix, make = READERS[name]
    p = tmp / f"input{suffix}"
    p.write_bytes(sample)
    reader = make(tmp)
    allowed_nan = nan_fields(reader(p))
    stats = FuzzStats(name)

    @settings(max_examples=n, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(_OPS)
    def run(ops):
        check_read(reader, p, _mutate(sample, ops), stats, allowed_nan, names=("f.toml", ".tag"))
    try:
        run()
    finally:
        stats.record()


@pytest.mark.parametrize("name", sorted(READERS))
def test_reader_valid_sample_reads(name, tmp_path):
    sample, suffix, make = READERS[name]
    p = tmp_path / f"input{suffix}"
    p.write_bytes(sample)
    make(tmp_path)(p)


@pytest.mark.parametrize("name", sorted(READERS))
def test_reader_fuzz_200(name, tmp_path_factory):
    _fuzz(name, tmp_path_factory, 200)


@pytest.mark.fuzz
@pytest.mark.parametrize("name", sorted(READERS))
def test_reader_fuzz_2000(name, tmp_path_factory):
    _fuzz(name, tmp_path_factory, 2000)
