"""GNSS propagation and geometry models: elevation/azimuth, Klobuchar, Saastamoinen, Sagnac, weights.

All functions are vectorised over satellites. Angles are radians inside, positions ECEF metres.
"""
from __future__ import annotations

import numpy as np

from dgcal.fields.constants import C_LIGHT, F_L1, OMEGA_EARTH, SECONDS_PER_DAY, SECONDS_PER_WEEK
from dgcal.fields.crs import ecef_to_geodetic
from dgcal.fields.frames import R_ecef_to_enu


def elevation_azimuth(p_rx_ecef: np.ndarray, p_sat_ecef: np.ndarray,
                      lat_lon_deg: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Elevation and azimuth (rad, azimuth clockwise from north) of satellites (n,3) seen from p_rx (3,)."""
    if lat_lon_deg is None:
        lat, lon, _ = ecef_to_geodetic(p_rx_ecef)
    else:
        lat, lon = lat_lon_deg
    d = np.atleast_2d(p_sat_ecef) - p_rx_ecef
    e_enu = (d / np.linalg.norm(d, axis=1, keepdims=True)) @ R_ecef_to_enu(lat, lon).T
    elev = np.arcsin(np.clip(e_enu[:, 2], -1.0, 1.0))
    azim = np.mod(np.arctan2(e_enu[:, 0], e_enu[:, 1]), 2 * np.pi)
    return elev, azim


def klobuchar_delay_m(t_gps: float, lat_deg: float, lon_deg: float, elev: np.ndarray,
                      azim: np.ndarray, ion: np.ndarray | None, freq_hz: np.ndarray | float = F_L1
                      ) -> np.ndarray:
    """Klobuchar (IS-GPS-200) slant ionospheric group delay (m) at the given carrier frequencies.

    ``ion`` is the 2x4 (alpha, beta) array of the navigation header (GPSA/GPSB); with None the
    delay is zero. The L1 delay is scaled by (f_L1/f)^2 for other frequencies.
    """
    elev = np.asarray(elev, float)
    if ion is None or not np.any(ion):
        return np.zeros_like(elev)
    alpha, beta = np.asarray(ion[0], float), np.asarray(ion[1], float)
    el_sc = elev / np.pi                                    # semicircles
    psi = 0.0137 / (el_sc + 0.11) - 0.022                   # earth-centred angle, semicircles
    phi_i = np.clip(lat_deg / 180.0 + psi * np.cos(azim), -0.416, 0.416)
    lam_i = lon_deg / 180.0 + psi * np.sin(azim) / np.cos(phi_i * np.pi)
    phi_m = phi_i + 0.064 * np.cos((lam_i - 1.617) * np.pi)
    sow = np.mod(t_gps, SECONDS_PER_WEEK)
    t_local = np.mod(43200.0 * lam_i + sow, SECONDS_PER_DAY)
    slant = 1.0 + 16.0 * (0.53 - el_sc) ** 3
    pw = phi_m[..., None] ** np.arange(4)
    amp = np.maximum(pw @ alpha, 0.0)
    per = np.maximum(pw @ beta, 72000.0)
    x = 2.0 * np.pi * (t_local - 50400.0) / per
    cosine = np.where(np.abs(x) < 1.57, 1.0 - x ** 2 / 2.0 + x ** 4 / 24.0, 0.0)
    delay_s = slant * (5e-9 + amp * cosine)
    delay = C_LIGHT * delay_s * (F_L1 / np.asarray(freq_hz, float)) ** 2
    return np.where(elev > 0, delay, 0.0)


def saastamoinen_delay_m(lat_deg, h_m, elev: np.ndarray, humidity: float = 0.7) -> np.ndarray:
    """Saastamoinen slant tropospheric delay (m) with the standard atmosphere (RTKLIB's form).

    ``lat_deg`` and ``h_m`` (ellipsoidal) may be scalars or arrays broadcasting with ``elev``;
    outside -100 m .. 10 km the delay is zero.
    """
    elev = np.asarray(elev, float)
    h_m = np.asarray(h_m, float)
    hgt = np.maximum(h_m, 0.0)
    pres = 1013.25 * (1.0 - 2.2557e-5 * hgt) ** 5.2568
    temp = 15.0 - 6.5e-3 * hgt + 273.16
    e = 6.108 * humidity * np.exp((17.15 * temp - 4684.0) / (temp - 38.45))
    cosz = np.sin(np.maximum(elev, 1e-3))                   # cos(zenith angle)
    lat = np.radians(lat_deg)
    dry = 0.0022768 * pres / (1.0 - 0.00266 * np.cos(2.0 * lat) - 0.00028 * hgt / 1e3) / cosz
    wet = 0.002277 * (1255.0 / temp + 0.05) * e / cosz
    valid = (elev > 0) & (h_m > -100.0) & (h_m < 1e4)
    return np.where(valid, dry + wet, 0.0)


def sagnac_rotate(p_sat_ecef: np.ndarray, v_sat_ecef: np.ndarray, tau_s: np.ndarray,
                  tau_dot: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Rotate satellite states at transmission into the ECEF frame of reception (Earth rotation).

    ``tau_s``: signal travel time (s) per satellite; ``tau_dot``: its rate d(tau)/dt_rx
    (= range rate / c). Returns the position and the velocity with respect to reception time,
    ``d/dt_rx [Rz(w tau) p_sat(t_rx - tau)]``, including the light-time rate terms.
    """
    th = OMEGA_EARTH * np.asarray(tau_s, float)
    c, s = np.cos(th), np.sin(th)
    x, y, z = p_sat_ecef[:, 0], p_sat_ecef[:, 1], p_sat_ecef[:, 2]
    vx, vy, vz = v_sat_ecef[:, 0], v_sat_ecef[:, 1], v_sat_ecef[:, 2]
    p = np.stack([c * x + s * y, -s * x + c * y, z], axis=1)
    k = 1.0 - np.asarray(tau_dot, float)                    # d t_tx / d t_rx
    w = OMEGA_EARTH * np.asarray(tau_dot, float)
    v = np.stack([k * (c * vx + s * vy) + w * (-s * x + c * y),
                  k * (-s * vx + c * vy) + w * (-c * x - s * y),
                  k * vz], axis=1)
    return p, v


def code_sigma_m(elev: np.ndarray, zenith_m: float = 0.3) -> np.ndarray:
    """Elevation-dependent code noise sigma (m): ``zenith_m * sqrt(1/2 + 1/(2 sin^2 el))``.

    Equals ``zenith_m`` at the zenith and grows like 1/sin(el) towards the horizon (RTKLIB's
    ``a^2 + b^2/sin^2 el`` with a = b).
    """
    s = np.sin(np.maximum(np.asarray(elev, float), np.radians(2.0)))
    return zenith_m * np.sqrt(0.5 + 0.5 / s ** 2)


# Broadcast orbit and clock: the signal-in-space range error (orbit and clock, RMS over the Earth) each system's
# broadcast ephemerides leave, as measured against precise orbits and clocks (Montenbruck et al. 2018, "Multi-GNSS
# signal-in-space range error assessment", GPS Solutions 22:7: GPS 0.6 m, Galileo 0.2-0.3 m, QZSS 0.6 m, BeiDou
# ~1 m, GLONASS 1.5-2 m: 1.8 m here). The navigation message's own URA/SISA (2-3 m when all is nominal) is a
# conservative bound, three to ten times these: as the budget it made SPP's sigmas two to four times too large
# (issue 27).
SISRE_M = {"G": 0.6, "E": 0.3, "J": 0.6, "C": 1.0, "R": 1.8}
# The URA/SISA a nominal message states (m): GPS and BeiDou URA index 0 (at most 2.4 m; RINEX files write 2.0),
# QZSS 2.8 m, Galileo's usual SISA 3.12 m. A satellite whose message states more is trusted less in proportion.
URA_NOMINAL_M = {"G": 2.4, "E": 3.12, "J": 2.8, "C": 2.4, "R": 2.4}   # GLONASS records state none: given this
# Saastamoinen with the standard atmosphere: its zenith delay is off by ~0.1 m (the wet part the standard humidity
# does not know); mapped to the satellite's elevation.
ZTD_SIGMA_M = 0.1
# Klobuchar with the day's coefficients: the share of the modelled slant delay taken as the error that reaches the
# position (the model removes about half of the delay's RMS at mid-latitudes, and of the half it leaves the part
# common to all satellites goes into the receiver clock); the whole delay with default coefficients.
KLOBUCHAR_SHARE = 0.3


def tropo_mapping(elev: np.ndarray) -> np.ndarray:
    """Elevation mapping of a zenith tropospheric delay, ``1.001 / sqrt(0.002001 + sin^2 el)`` (Black & Eisner)."""
    s = np.sin(np.maximum(np.asarray(elev, float), 0.0))
    return 1.001 / np.sqrt(0.002001 + s ** 2)


def orbit_clock_sigma_m(ura_m: np.ndarray | float, system: np.ndarray | str | None = None) -> np.ndarray:
    """Sigma (m) of a broadcast orbit and clock: the system's `SISRE_M`, scaled up by the navigation message's
    URA/SISA `ura_m` where it states more than a nominal message (`URA_NOMINAL_M`). Without `system` (or for a system
    not in the tables) GPS's values."""
    ura = np.asarray(ura_m, float)
    if system is None:
        sis, nom = SISRE_M["G"], URA_NOMINAL_M["G"]
    else:
        sy = np.asarray(system)
        sis = np.select([sy == k for k in SISRE_M], list(SISRE_M.values()), SISRE_M["G"])
        nom = np.select([sy == k for k in URA_NOMINAL_M], list(URA_NOMINAL_M.values()), URA_NOMINAL_M["G"])
    return sis * np.maximum(1.0, np.where(np.isfinite(ura), ura, 0.0) / nom)


def model_sigma_m(elev: np.ndarray, iono_m: np.ndarray, ura_m: np.ndarray | float = 2.0,
                  iono_share: float = KLOBUCHAR_SHARE, system: np.ndarray | str | None = None,
                  orbit_clock_m: np.ndarray | float | None = None) -> np.ndarray:
    """Sigma (m) of the broadcast-model errors of a pseudorange: `iono_share` of the Klobuchar delay `iono_m`
    (`KLOBUCHAR_SHARE` with the day's coefficients), the troposphere's `ZTD_SIGMA_M` mapped to the elevation, and the
    orbit and clock (`orbit_clock_sigma_m` of the message's URA/SISA and the satellite's system; `orbit_clock_m`
    instead when given, e.g. precise products' `dgcal.pos.gnss.precise.PRECISE_SIGMA_M`)."""
    tropo = ZTD_SIGMA_M * tropo_mapping(elev)
    oc = orbit_clock_sigma_m(ura_m, system) if orbit_clock_m is None else np.asarray(orbit_clock_m, float)
    return np.sqrt((iono_share * np.asarray(iono_m)) ** 2 + tropo ** 2 + oc ** 2)
