"""The zero-difference model of `dgcal.pos.gnss.carrier` for one receiver position, compiled (numba).

PPK models the rover at a new position up to twice an epoch (`dgcal.pos.gnss.ppk.CarrierPair.rover_zd`); with
NumPy's per-call overhead on ~20 satellites that was the largest share of its time. These kernels evaluate,
satellite by satellite in one call, the formulas of `dgcal.pos.gnss.corrections` that the model uses: the
light-time loop with the Sagnac rotation (`sagnac_rotate`, as `carrier.satellite_geometry` iterates it),
`elevation_azimuth`, `saastamoinen_delay_m` and `klobuchar_delay_m` (at L1). Same formulas and operation order;
the results agree with the NumPy functions to rounding (tests/pos/gnss/test_gnss_models.py holds them together).
Positions ECEF m, angles radians unless named deg, times GPS s.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from dgcal.fields.constants import C_LIGHT, OMEGA_EARTH, SECONDS_PER_DAY, SECONDS_PER_WEEK

WGS84_A = 6378137.0                     # m, semi-major axis
WGS84_F = 1.0 / 298.257223563           # flattening


@njit(cache=True)
def _rotate(x, y, z, vx, vy, vz, tau, tau_dot):  # pragma: no cover - compiled
    """`corrections.sagnac_rotate` of one satellite: position and velocity (m, m/s) in the frame of reception."""
    th = OMEGA_EARTH * tau
    c, s = math.cos(th), math.sin(th)
    k = 1.0 - tau_dot
    w = OMEGA_EARTH * tau_dot
    return (c * x + s * y, -s * x + c * y, z,
            k * (c * vx + s * vy) + w * (-s * x + c * y), k * (-s * vx + c * vy) + w * (-c * x - s * y), k * vz)


@njit(cache=True)
def _dist(ax, ay, az, p):  # pragma: no cover - compiled
    """|a - p| (m)."""
    dx, dy, dz = ax - p[0], ay - p[1], az - p[2]
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def at_reception(p_tx: np.ndarray, v_tx: np.ndarray, p_rx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Satellite states at transmission (n,3) m, m/s rotated into the ECEF frame at reception by a receiver at
    p_rx: the travel time iterated twice, then the rotation with the travel time's rate (`satellite_geometry`)."""
    n = p_tx.shape[0]
    pos = np.empty((n, 3))
    vel = np.empty((n, 3))
    for i in range(n):
        x, y, z = p_tx[i, 0], p_tx[i, 1], p_tx[i, 2]
        vx, vy, vz = v_tx[i, 0], v_tx[i, 1], v_tx[i, 2]
        rng = _dist(x, y, z, p_rx)
        tau = rng / C_LIGHT
        for _ in range(2):
            qx, qy, qz, _a, _b, _c = _rotate(x, y, z, vx, vy, vz, tau, 0.0)
            tau = _dist(qx, qy, qz, p_rx) / C_LIGHT
        # range rate along the unrotated line of sight
        tau_dot = ((x - p_rx[0]) / rng * vx + (y - p_rx[1]) / rng * vy + (z - p_rx[2]) / rng * vz) / C_LIGHT
        r = _rotate(x, y, z, vx, vy, vz, tau, tau_dot)
        pos[i, 0], pos[i, 1], pos[i, 2] = r[0], r[1], r[2]
        vel[i, 0], vel[i, 1], vel[i, 2] = r[3], r[4], r[5]
    return pos, vel


@njit(cache=True)
def _saastamoinen(lat_deg, h_m, elev, humidity):  # pragma: no cover - compiled
    """`corrections.saastamoinen_delay_m` of one satellite (m)."""
    hgt = max(h_m, 0.0)
    pres = 1013.25 * (1.0 - 2.2557e-5 * hgt) ** 5.2568
    temp = 15.0 - 6.5e-3 * hgt + 273.16
    e = 6.108 * humidity * math.exp((17.15 * temp - 4684.0) / (temp - 38.45))
    cosz = math.sin(max(elev, 1e-3))
    lat = math.radians(lat_deg)
    dry = 0.0022768 * pres / (1.0 - 0.00266 * math.cos(2.0 * lat) - 0.00028 * hgt / 1e3) / cosz
    wet = 0.002277 * (1255.0 / temp + 0.05) * e / cosz
    if elev > 0 and -100.0 < h_m < 1e4:
        return dry + wet
    return 0.0


@njit(cache=True)
def _klobuchar_l1(t_gps, lat_deg, lon_deg, elev, azim, alpha, beta):  # pragma: no cover - compiled
    """`corrections.klobuchar_delay_m` of one satellite at L1 (m)."""
    el_sc = elev / math.pi
    psi = 0.0137 / (el_sc + 0.11) - 0.022
    phi_i = min(max(lat_deg / 180.0 + psi * math.cos(azim), -0.416), 0.416)
    lam_i = lon_deg / 180.0 + psi * math.sin(azim) / math.cos(phi_i * math.pi)
    phi_m = phi_i + 0.064 * math.cos((lam_i - 1.617) * math.pi)
    t_local = (43200.0 * lam_i + t_gps % SECONDS_PER_WEEK) % SECONDS_PER_DAY
    slant = 1.0 + 16.0 * (0.53 - el_sc) ** 3.0
    amp, per = 0.0, 0.0
    for q in range(4):
        pw = phi_m ** float(q)
        amp += pw * alpha[q]
        per += pw * beta[q]
    amp = max(amp, 0.0)
    per = max(per, 72000.0)
    x = 2.0 * math.pi * (t_local - 50400.0) / per
    cosine = 1.0 - x * x / 2.0 + x ** 4.0 / 24.0 if abs(x) < 1.57 else 0.0
    if elev > 0:
        return C_LIGHT * (slant * (5e-9 + amp * cosine))
    return 0.0


@njit(cache=True)
def geodetic(p: np.ndarray) -> tuple[float, float, float]:
    """Latitude, longitude (deg) and ellipsoidal height (m) of ECEF p (m), WGS84 (`fields.crs.ecef_to_geodetic`
    without pyproj's per-call cost): the fixed-point iteration on z + N e^2 sin(lat), to 1e-10 m."""
    e2 = WGS84_F * (2.0 - WGS84_F)
    r2 = p[0] * p[0] + p[1] * p[1]
    z, zk, v = p[2], 0.0, WGS84_A
    for _ in range(50):
        if abs(z - zk) < 1e-10:
            break
        zk = z
        sinp = z / math.sqrt(r2 + z * z)
        v = WGS84_A / math.sqrt(1.0 - e2 * sinp * sinp)
        z = p[2] + v * e2 * sinp
    if r2 > 1e-12:
        lat = math.atan(z / math.sqrt(r2))
    else:
        lat = math.pi / 2 if p[2] > 0.0 else -math.pi / 2
    return math.degrees(lat), math.degrees(math.atan2(p[1], p[0])), math.sqrt(r2 + z * z) - v


@njit(cache=True)
def receiver_terms(pos: np.ndarray, ok: np.ndarray, p_rx: np.ndarray, t_gps: np.ndarray, ion: np.ndarray,
                   has_ion: bool, humidity: float):
    """Per satellite (n rows) seen from p_rx: range (m), unit line of sight (n,3), elevation and azimuth (rad),
    Saastamoinen troposphere (m) and Klobuchar L1 ionosphere (m; `ion` the 2x4 alpha/beta, zero without
    `has_ion`) at times `t_gps` (n,); NaN where not `ok`, as `carrier.zero_difference`."""
    n = pos.shape[0]
    lat_deg, lon_deg, h_m = geodetic(p_rx)
    rho = np.empty(n)
    los = np.empty((n, 3))
    elev = np.full(n, np.nan)
    azim = np.full(n, np.nan)
    tropo = np.full(n, np.nan)
    iono = np.full(n, np.nan)
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    for i in range(n):
        dx, dy, dz = pos[i, 0] - p_rx[0], pos[i, 1] - p_rx[1], pos[i, 2] - p_rx[2]
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        rho[i] = r
        los[i, 0], los[i, 1], los[i, 2] = dx / r, dy / r, dz / r
        if not ok[i]:
            continue
        ux, uy, uz = los[i, 0], los[i, 1], los[i, 2]
        east = -so * ux + co * uy
        north = -sl * co * ux + -sl * so * uy + cl * uz
        up = cl * co * ux + cl * so * uy + sl * uz
        el = math.asin(min(max(up, -1.0), 1.0))
        az = math.atan2(east, north) % (2.0 * math.pi)
        elev[i], azim[i] = el, az
        tropo[i] = _saastamoinen(lat_deg, h_m, el, humidity)
        iono[i] = _klobuchar_l1(t_gps[i], lat_deg, lon_deg, el, az, ion[0], ion[1]) if has_ion else 0.0
    return rho, los, elev, azim, tropo, iono


@njit(cache=True)
def zero_difference_rows(pos: np.ndarray, clk: np.ndarray, ok: np.ndarray, P: np.ndarray, L: np.ndarray,
                         freq: np.ndarray, p_rx: np.ndarray, t_epoch: np.ndarray, ion: np.ndarray, has_ion: bool,
                         humidity: float):
    """`carrier.zero_difference` of E epochs of m satellites (n = E*m rows, epoch by epoch; `t_epoch` (E,) s) at
    one receiver position: `receiver_terms`, and per slot (P, L (n,F) code m, phase cycles; freq (m,F) Hz) the L1
    ionosphere scaled by (f_L1/f)^2, ``omc_code = P - (rho - c dt + T + I)``, ``omc_phase = lam L - (rho - c dt
    + T - I)`` (m); NaN where not `ok`."""
    n, F = P.shape
    m = freq.shape[0]
    t = np.empty(n)
    for i in range(n):
        t[i] = t_epoch[i // m]
    rho, los, elev, azim, tropo, iono1 = receiver_terms(pos, ok, p_rx, t, ion, has_ion, humidity)
    iono = np.full((n, F), np.nan)
    omc_code = np.full((n, F), np.nan)
    omc_phase = np.full((n, F), np.nan)
    for i in range(n):
        if not ok[i]:
            continue
        geo = rho[i] - C_LIGHT * clk[i] + tropo[i]
        for f in range(F):
            fr = freq[i % m, f]
            r = 1575.42e6 / fr
            io = iono1[i] * (r * r)
            iono[i, f] = io
            omc_code[i, f] = P[i, f] - (geo + io)
            omc_phase[i, f] = C_LIGHT / fr * L[i, f] - (geo - io)
    return rho, los, elev, azim, tropo, iono, omc_code, omc_phase
