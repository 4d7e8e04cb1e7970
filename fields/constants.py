"""Physical, geodetic and time constants used across dgcal (one definition each)."""
from __future__ import annotations

import numpy as np

C_LIGHT = 299792458.0                  # m/s, speed of light in vacuum
OMEGA_EARTH = 7.2921151467e-5          # rad/s, WGS84 earth rotation rate
OMEGA_IE_E = np.array([0.0, 0.0, OMEGA_EARTH])   # earth rotation vector in ECEF, rad/s
GM_WGS84 = 3.986004418e14              # m^3/s^2, WGS84 earth gravitational constant (with atmosphere)
GM_GPS = 3.986005e14                   # m^3/s^2, the value of the GPS interface specification (broadcast orbits)
J2_WGS84 = 1.082626684e-3              # second zonal harmonic (EGM96/WGS84)
A_WGS84 = 6378137.0                    # m, WGS84 semi-major axis
G0 = 9.80665                           # m/s^2, standard gravity (unit of "g" in IMU data sheets)
F_L1 = 1575.42e6                       # Hz, GPS L1 carrier
SECONDS_PER_WEEK = 604800.0            # s, one GPS week
SECONDS_PER_DAY = 86400.0              # s
GPS_EPOCH_UNIX_S = 315964800.0         # s, 1980-01-06T00:00:00 (GPS time zero) on the Unix time axis
# GPS - UTC in whole seconds, each from the UTC instant (Unix seconds) it took effect (IERS Bulletin C);
# none since 2017-01-01: 18 s
GPS_UTC_LEAP_SECONDS = (
    (362793600, 1), (394329600, 2), (425865600, 3), (489024000, 4), (567993600, 5), (631152000, 6),
    (662688000, 7), (709948800, 8), (741484800, 9), (773020800, 10), (820454400, 11), (867715200, 12),
    (915148800, 13), (1136073600, 14), (1230768000, 15), (1341100800, 16), (1435708800, 17), (1483228800, 18),
)
