"""A small PX4 ULog written byte by byte (the layout of PX4's logger: header, flag bits, formats, subscriptions,
data): vehicle_imu at 200 Hz, vehicle_gps_position at 5 Hz, camera_capture every 2 s, for the readers' tests."""
from __future__ import annotations

import struct

import numpy as np

MAGIC = b"ULog\x01\x12\x35"
FORMATS = {
    "vehicle_imu": "uint64_t timestamp;uint64_t timestamp_sample;float[3] delta_angle;float[3] delta_velocity;"
                   "uint16_t delta_angle_dt;uint16_t delta_velocity_dt;",
    "vehicle_gps_position": "uint64_t timestamp;uint64_t time_utc_usec;",
    "camera_capture": "uint64_t timestamp;uint64_t timestamp_utc;uint32_t seq;",
}
BOOT_TO_UNIX_US = 1_700_000_000_000_000 - 60_000_000      # the UTC of boot time 0 (boot 60 s = 1.7e9 Unix s)


def msg(kind: str, payload: bytes) -> bytes:
    """One ULog message: uint16 size, uint8 type, payload."""
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def ulog_bytes(seconds: float = 10.0, rate_hz: float = 200.0, gyro=(0.01, -0.02, 0.03),
               accel=(0.1, 0.2, -9.81), extra_formats: dict | None = None, extra_logged: tuple = ()) -> bytes:
    """A ULog of `seconds` of IMU data from boot 60 s (rates `gyro` rad/s, specific force `accel` m/s^2, FRD)."""
    out = [MAGIC + b"\x01" + struct.pack("<Q", 0), msg("B", bytes(40))]
    formats = {**FORMATS, **(extra_formats or {})}
    for name, fields in formats.items():
        out.append(msg("F", f"{name}:{fields}".encode()))
    for i, name in enumerate([*FORMATS, *extra_logged]):
        out.append(msg("A", struct.pack("<BH", 0, i) + name.encode()))
    n = int(seconds * rate_hz)
    dt_us = int(round(1e6 / rate_hz))
    t0 = 60_000_000
    for k in range(n):
        ts = t0 + k * dt_us
        out.append(msg("D", struct.pack("<HQQ3f3fHH", 0, ts + 500, ts, *(np.array(gyro) * dt_us * 1e-6),
                                        *(np.array(accel) * dt_us * 1e-6), dt_us, dt_us)))
        if k % int(rate_hz / 5) == 0:
            out.append(msg("D", struct.pack("<HQQ", 1, ts, ts + BOOT_TO_UNIX_US)))
        if k % int(2 * rate_hz) == 0:
            out.append(msg("D", struct.pack("<HQQI", 2, ts, ts + BOOT_TO_UNIX_US, k // int(2 * rate_hz) + 1)))
    return b"".join(out)
