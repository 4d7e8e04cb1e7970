"""PX4 ULog read with bounded effort (issue 31): a valid log written byte by byte reads as IMU data and camera events;
a damaged one (nested formats that flatten to billions of fields, a format containing itself, a corrupt message
header, a corrupt header among the definitions on which pyulog loops for ever, values beyond any IMU) is refused
with one InputError naming the file, within seconds - pyulog alone spends minutes on the first and never returns
on the fourth; cut or mutated logs read or are refused within seconds."""
from __future__ import annotations

import struct
import time

import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.io.timescales import gps_from_unix_utc
from dgcal.pos.ins.ulog import read_ulog_camera_capture, read_ulog_imu
from dgcal.pos.ins.ulog_stream import scan_ulog
from dgcal.pos.readers import ImuInput, read_imu_input

from ulog_writer import FORMATS, MAGIC, msg, ulog_bytes


def _write(tmp_path, data: bytes, name="log.ulg"):
    p = tmp_path / name
    p.write_bytes(data)
    return p


def test_valid_log_reads_imu_and_camera_events(tmp_path):
    p = _write(tmp_path, ulog_bytes(10.0, gyro=(0.01, -0.02, 0.03), accel=(0.1, 0.2, -9.81)))
    assert scan_ulog(p) == p.stat().st_size
    imu = read_imu_input(ImuInput(p))
    assert len(imu) == 2000
    assert np.allclose(imu.gyro_rad_s[1:], [0.01, -0.02, 0.03], atol=1e-6)
    assert np.allclose(imu.accel_m_s2[1:], [0.1, 0.2, -9.81], atol=1e-5)
    # boot 60 s is Unix 1.7e9 s: the samples are stamped at their timestamp_sample
    assert abs(imu.t[0] - gps_from_unix_utc(np.array([1.7e9]))[0]) < 1e-5
    ev = read_ulog_camera_capture(p)
    assert list(ev.image[:2]) == ["IMG_0001.JPG", "IMG_0002.JPG"] and np.allclose(np.diff(ev.t), 2.0)


def test_nested_format_explosion_refused_fast(tmp_path):
    """A format of 65535 elements of a format of 65535 floats: pyulog would flatten 4e9 fields (minutes, memory)."""
    p = _write(tmp_path, ulog_bytes(2.0, extra_formats={"inner": "float[65535] x;",
                                                        "outer": "uint64_t timestamp;inner[65535] y;"},
                                    extra_logged=("outer",)))
    t0 = time.perf_counter()
    with pytest.raises(InputError, match=r"log\.ulg.*'outer' flattens to more than 65535 fields"):
        read_ulog_imu(p)
    assert time.perf_counter() - t0 < 2.0


def test_format_containing_itself_refused(tmp_path):
    p = _write(tmp_path, ulog_bytes(1.0, extra_formats={"loop": "uint64_t timestamp;loop x;"}, extra_logged=("loop",)))
    with pytest.raises(InputError, match="'loop' contains itself"):
        read_ulog_imu(p)


def test_corrupt_message_header_names_the_offset(tmp_path):
    """A header pyulog takes as corrupt (type 0 with a size) in the middle of the data: refused, naming the byte and
    how much of the log can be read (pyulog would skip to a later message and drop data silently)."""
    data = ulog_bytes(20.0)
    k = len(data) // 2
    k = data.index(b"D", k) - 2          # a message start: its 2-byte size precedes the type
    bad = data[:k] + msg("\x00", bytes(300)) + data[k:]
    p = _write(tmp_path, bad)
    with pytest.raises(InputError, match=rf"damaged at byte {k} of {len(bad)} .*first {k} bytes are readable"):
        read_ulog_imu(p)


@pytest.mark.parametrize("tail", [struct.pack("<HB", 5000, 0) + b"x" * 10,      # cut short by the end of the file
                                  struct.pack("<HB", 20000, ord("D")) + bytes(20000)])   # data among definitions
def test_corrupt_header_among_the_definitions_refused(tmp_path, tail):
    """pyulog loops for ever on the first (it steps back over more than it read) and steps byte by byte on the
    second: both refused at once."""
    defs = MAGIC + b"\x01" + struct.pack("<Q", 0) + msg("B", bytes(40)) + b"".join(
        msg("F", f"{k}:{v}".encode()) for k, v in FORMATS.items())
    p = _write(tmp_path, defs + tail)
    t0 = time.perf_counter()
    with pytest.raises(InputError, match=rf"damaged at byte {len(defs)} of"):
        read_ulog_imu(p)
    assert time.perf_counter() - t0 < 2.0


@pytest.mark.parametrize("value", [1e20, np.inf, np.nan])
def test_imu_values_beyond_any_imu_refused(tmp_path, value):
    p = _write(tmp_path, ulog_bytes(2.0, gyro=(0.01, value, 0.0)))
    with pytest.raises(InputError, match=r"log\.ulg.*vehicle_imu"):
        read_ulog_imu(p)


def test_missing_field_named(tmp_path):
    fmt = {"vehicle_imu": "uint64_t timestamp;uint64_t timestamp_sample;float[3] delta_angle;float[3] delta_velocity;"
                          "uint16_t delta_angle_dt;uint16_t dv_dt;"}
    p = _write(tmp_path, ulog_bytes(1.0, extra_formats=fmt))
    with pytest.raises(InputError, match=r"vehicle_imu\.delta_velocity_dt"):
        read_ulog_imu(p)


def test_cut_and_mutated_logs_bounded(tmp_path):
    """A log cut at 40 places reads (the samples before the cut) or is refused; 200 random 1-8-byte overwrites of a
    60 s log each read or are refused within 5 s, never another exception."""
    data = ulog_bytes(60.0)
    p = tmp_path / "log.ulg"
    n_read = 0
    for cut in np.linspace(2000, len(data) - 1, 40).astype(int):
        p.write_bytes(data[:cut])
        try:
            imu = read_ulog_imu(p)
            n_read += 1
            assert len(imu) <= 12000
        except InputError as exc:
            assert "log.ulg" in str(exc)
    assert n_read >= 35
    rng = np.random.default_rng(31)
    slowest = 0.0
    for _ in range(200):
        b = bytearray(data)
        i = int(rng.integers(16, 3000)) if rng.random() < 0.5 else int(rng.integers(16, len(b)))
        b[i:i + int(rng.integers(1, 9))] = rng.integers(0, 256, 8, dtype=np.uint8).tobytes()
        p.write_bytes(bytes(b))
        t0 = time.perf_counter()
        try:
            read_ulog_imu(p)
        except InputError as exc:
            assert "log.ulg" in str(exc) and "\n" not in str(exc)
        slowest = max(slowest, time.perf_counter() - t0)
    assert slowest < 5.0
