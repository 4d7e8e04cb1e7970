"""Coordinate reference systems with pyproj: map grids, ECEF/geodetic, local ENU frames, convergence.

WGS84 ECEF <-> geodetic of finite points is computed here by PROJ's own formulas (its `cart` conversion, PROJ 9)
with the C library's trigonometry, which gives pyproj's numbers without importing pyproj (0.05 s of a process:
positioning from RINEX needs no CRS). pyproj is imported on first use of a CRS (`parse_crs`, `MapGrid`), and for
arrays larger than `DIRECT_MAX_POINTS` or with non-finite or out-of-range values (PROJ's own handling of those).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from dgcal.fields.constants import A_WGS84
from dgcal.fields.errors import InputError
from dgcal.fields.frames import R_ecef_to_enu, R_ecef_to_ned, R_enu_to_grid

if TYPE_CHECKING:
    import pyproj

ECEF = "EPSG:4978"
GEODETIC = "EPSG:4979"  # lat, lon, ellipsoidal height


def _pyproj():
    import pyproj  # why: 0.05 s to import, needed by CRS work only, not by WGS84 ECEF <-> geodetic (module doc)
    return pyproj


def parse_crs(text: str, source: str = "--crs") -> pyproj.CRS:
    """A pyproj CRS from user text (EPSG code, PROJ string, WKT); InputError naming `source` if invalid."""
    pyproj = _pyproj()
    try:
        return pyproj.CRS.from_user_input(text)
    except pyproj.exceptions.CRSError as exc:
        raise InputError(f"not a CRS pyproj understands: {text!r} ({exc})", field=source) from None


def _transformer(src, dst) -> pyproj.Transformer:
    return _pyproj().Transformer.from_crs(src, dst, always_xy=True)


# WGS84 ECEF <-> geodetic without pyproj (module doc): the ellipsoid as PROJ derives it from ellps=WGS84 (a and 1/f;
# pj_calc_ellipsoid_params), its degree, and the C library's functions applied element by element (numpy's own
# vectorised ones may differ from them in the last bit)
DIRECT_MAX_POINTS = 50_000   # larger arrays go through pyproj, whose loop is compiled
_F = 1.0 / 298.257223563
_ES = 2 * _F - _F * _F                                  # first eccentricity squared
_E2S = math.tan(math.asin(math.sqrt(_ES))) ** 2         # second eccentricity squared
_RA = 1.0 / A_WGS84
_B_DIV_A = 1.0 - _F
_DEG_TO_RAD = 0.017453292519943296
_RAD_TO_DEG = 1.0 / _DEG_TO_RAD
_sin, _cos = np.frompyfunc(math.sin, 1, 1), np.frompyfunc(math.cos, 1, 1)
_atan, _atan2 = np.frompyfunc(math.atan, 1, 1), np.frompyfunc(math.atan2, 2, 1)


def _libm(f, *args) -> np.ndarray:
    return np.asarray(f(*args), dtype=float)


def geodetic_to_ecef(lat_deg, lon_deg, h_m) -> np.ndarray:
    """ECEF (m, WGS84) from latitude, longitude (degrees) and ellipsoidal height (m); shape (...,3)."""
    lat, lon, h = np.asarray(lat_deg, float), np.asarray(lon_deg, float), np.asarray(h_m, float)
    if not (lat.shape == lon.shape == h.shape and lat.size <= DIRECT_MAX_POINTS and np.all(np.abs(lat) <= 90.0)
            and np.all(np.abs(lon) <= 180.0) and np.all(np.isfinite(h))):
        x, y, z = _tf(GEODETIC, ECEF).transform(lon, lat, h)
        return np.stack([x, y, z], axis=-1)
    # PROJ's unitconvert deg -> rad, then its cart forward (HM 5-27)
    phi, lam = lat * _DEG_TO_RAD, lon * _DEG_TO_RAD
    sinphi, cosphi = _libm(_sin, phi), _libm(_cos, phi)
    n = A_WGS84 / np.sqrt(1 - _ES * sinphi * sinphi)
    return np.stack([(n + h) * cosphi * _libm(_cos, lam), (n + h) * cosphi * _libm(_sin, lam),
                     (n * (1 - _ES) + h) * sinphi], axis=-1)


def ecef_to_geodetic(p_ecef) -> np.ndarray:
    """Latitude, longitude (degrees) and ellipsoidal height (m) from ECEF (m); shape (...,3)."""
    p = np.asarray(p_ecef, float)
    if p.shape[-1:] != (3,) or p[..., 0].size > DIRECT_MAX_POINTS or not np.all(np.isfinite(p)):
        lon, lat, h = _tf(ECEF, GEODETIC).transform(p[..., 0], p[..., 1], p[..., 2])
        return np.stack([lat, lon, h], axis=-1)
    # PROJ's cart inverse (Bowring 1976, as PROJ 9 writes it), then its unitconvert rad -> deg
    x, y, z = p[..., 0] * _RA, p[..., 1] * _RA, p[..., 2] * _RA
    r = np.sqrt(x * x + y * y)
    rb = r * _B_DIV_A
    norm = np.sqrt(z * z + rb * rb)
    inv = 1.0 / np.where(norm != 0, norm, 1.0)
    c, s = np.where(norm != 0, rb * inv, 1.0), np.where(norm != 0, z * inv, 0.0)
    y_phi = z + _E2S * _B_DIV_A * s * s * s
    x_phi = r - _ES * c * c * c
    norm_phi = np.sqrt(y_phi * y_phi + x_phi * x_phi)
    inv_phi = 1.0 / np.where(norm_phi != 0, norm_phi, 1.0)
    cosphi = np.where(norm_phi != 0, x_phi * inv_phi, 1.0)
    sinphi = np.where(norm_phi != 0, y_phi * inv_phi, 0.0)
    north = p[..., 2] >= 0
    axis = x_phi <= 0        # at the centre of the earth: no single solution, PROJ's clamp to a pole
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(axis, np.where(north, math.pi / 2, -math.pi / 2), _libm(_atan, y_phi / x_phi))
    cosphi = np.where(axis, 0.0, cosphi)
    sinphi = np.where(axis, np.where(north, 1.0, -1.0), sinphi)
    lam = _libm(_atan2, y, x) + 0.0   # + 0.0: a longitude of -0.0 is 0.0 out of PROJ
    c2, s2, b2 = cosphi * cosphi, sinphi * sinphi, _B_DIV_A * _B_DIV_A
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(cosphi < 1e-6,                      # poleward of 89.99994 deg: z minus the geocentric radius
                     np.abs(p[..., 2]) - A_WGS84 * np.sqrt((c2 + b2 * (b2 * s2)) / (c2 + b2 * s2)),
                     A_WGS84 * r / cosphi - A_WGS84 / np.sqrt(1 - _ES * sinphi * sinphi))
    return np.stack([phi * _RAD_TO_DEG, lam * _RAD_TO_DEG, h], axis=-1)


def R_ecef_to_enu_at(p_ecef) -> np.ndarray:
    """Rotation from ECEF to the local ENU frame at ECEF point(s) (m): (3,3) for one point (3,), (N,3,3) for (N,3).

    ENU vectors of ECEF differences from a reference point: ``(p - ref) @ R_ecef_to_enu_at(ref).T``.
    """
    geo = ecef_to_geodetic(p_ecef)
    return R_ecef_to_enu(geo[..., 0], geo[..., 1])


def R_ecef_to_ned_at(p_ecef) -> np.ndarray:
    """Rotation from ECEF to the local NED frame at ECEF point(s) (m): (3,3) for one point (3,), (N,3,3) for (N,3)."""
    geo = ecef_to_geodetic(p_ecef)
    return R_ecef_to_ned(geo[..., 0], geo[..., 1])


_TF_CACHE: dict[tuple[str, str], pyproj.Transformer] = {}


def _tf(src: str, dst: str) -> pyproj.Transformer:
    key = (str(src), str(dst))
    if key not in _TF_CACHE:
        _TF_CACHE[key] = _transformer(src, dst)
    return _TF_CACHE[key]


@dataclass(frozen=True)
class LocalENU:
    """A local tangent-plane frame (East, North, Up, metres) with its origin at a geodetic point."""

    lat0: float
    lon0: float
    h0: float

    @cached_property
    def origin_ecef(self) -> np.ndarray:
        return geodetic_to_ecef(self.lat0, self.lon0, self.h0)

    @cached_property
    def R_ecef_to_enu(self) -> np.ndarray:
        return R_ecef_to_enu(self.lat0, self.lon0)

    def from_ecef(self, p_ecef) -> np.ndarray:
        """ENU coordinates (m) of ECEF points (m)."""
        return (np.asarray(p_ecef, float) - self.origin_ecef) @ self.R_ecef_to_enu.T

    def to_ecef(self, p_enu) -> np.ndarray:
        """ECEF coordinates (m) of ENU points (m)."""
        return np.asarray(p_enu, float) @ self.R_ecef_to_enu + self.origin_ecef

    def from_geodetic(self, lat_deg, lon_deg, h_m) -> np.ndarray:
        """ENU (m) of geodetic points (degrees, ellipsoidal m)."""
        return self.from_ecef(geodetic_to_ecef(lat_deg, lon_deg, h_m))

    def to_geodetic(self, p_enu) -> np.ndarray:
        """Latitude, longitude (degrees), ellipsoidal height (m) of ENU points."""
        return ecef_to_geodetic(self.to_ecef(p_enu))

    def R_enu_here_to_local(self, lat_deg, lon_deg) -> np.ndarray:
        """Rotation from the ENU frame at (lat, lon) to this frame's axes (earth curvature); (3,3) or (N,3,3)."""
        return self.R_ecef_to_enu @ np.swapaxes(R_ecef_to_enu(lat_deg, lon_deg), -1, -2)


def height_unit_factor(crs: pyproj.CRS) -> float:
    """Metres per unit of the heights that go with a CRS: a 2-D projected CRS's heights are in its own linear
    unit (a US-survey-foot State Plane grid has heights in US survey feet); 1 for geographic CRS and for 3-D or
    compound CRS, whose vertical axis names its unit (pyproj converts it)."""
    if not crs.is_projected or len(crs.axis_info) != 2:
        return 1.0
    f = crs.axis_info[0].unit_conversion_factor
    return float(f) if f and np.isfinite(f) and f > 0 else 1.0


class MapGrid:
    """A map CRS (projected or geographic, 3-D with ellipsoidal heights) and its link to ECEF.

    Heights (z) are ellipsoidal, in the CRS's height unit (`height_unit_factor`: metres for geographic and
    metric grids, feet for a 2-D grid in feet)."""

    def __init__(self, crs: str | pyproj.CRS):
        self.crs = parse_crs(crs) if isinstance(crs, str) else crs
        self.z_unit_m = height_unit_factor(self.crs)
        self._to_ecef = _transformer(self.crs.to_3d(), ECEF)
        self._from_ecef = _transformer(ECEF, self.crs.to_3d())
        self._to_geo = _transformer(self.crs.to_3d(), GEODETIC)
        self._from_geo = _transformer(GEODETIC, self.crs.to_3d())

    def to_ecef(self, xyz) -> np.ndarray:
        """ECEF (m) of map coordinates (x=E, y=N, z=ellipsoidal height in the CRS's height unit)."""
        p = np.asarray(xyz, float)
        return np.stack(self._to_ecef.transform(p[..., 0], p[..., 1], p[..., 2] * self.z_unit_m), axis=-1)

    def from_ecef(self, p_ecef) -> np.ndarray:
        """Map coordinates (E, N, h) of ECEF points (m)."""
        p = np.asarray(p_ecef, float)
        x, y, z = self._from_ecef.transform(p[..., 0], p[..., 1], p[..., 2])
        return np.stack([x, y, np.asarray(z) / self.z_unit_m], axis=-1)

    def to_geodetic(self, xyz) -> np.ndarray:
        """Latitude, longitude (degrees), ellipsoidal height (m) of map coordinates."""
        p = np.asarray(xyz, float)
        lon, lat, h = self._to_geo.transform(p[..., 0], p[..., 1], p[..., 2] * self.z_unit_m)
        return np.stack([lat, lon, h], axis=-1)

    def from_geodetic(self, lat_deg, lon_deg, h_m) -> np.ndarray:
        """Map coordinates of geodetic points (degrees, ellipsoidal m)."""
        x, y, z = self._from_geo.transform(np.asarray(lon_deg, float), np.asarray(lat_deg, float),
                                           np.asarray(h_m, float))
        return np.stack([x, y, np.asarray(z) / self.z_unit_m], axis=-1)

    def convergence_deg(self, lat_deg, lon_deg) -> np.ndarray:
        """True azimuth of grid north (degrees, clockwise from true north) at geodetic points.

        Computed from the projection itself (a short step along the meridian) so the sign can't be
        confused; 0 for geographic CRS.
        """
        if self.crs.is_geographic:
            return np.zeros(np.shape(lat_deg))
        lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
        d = 1e-5
        p0 = self.from_geodetic(lat, lon, 0.0 * lat)
        p1 = self.from_geodetic(lat + d, lon, 0.0 * lat)
        dE, dN = p1[..., 0] - p0[..., 0], p1[..., 1] - p0[..., 1]
        # the meridian's grid azimuth is atan2(dE, dN); grid north's true azimuth is its negative
        return -np.degrees(np.arctan2(dE, dN))

    def R_enu_to_grid_at(self, xyz) -> np.ndarray:
        """Rotation from the local ENU frame at map points to grid-level axes (grid E, grid N, Up)."""
        g = self.to_geodetic(xyz)
        return R_enu_to_grid(self.convergence_deg(g[..., 0], g[..., 1]))

    def local_frame(self, xyz) -> LocalENU:
        """A local ENU frame with its origin at map point `xyz`."""
        lat, lon, h = self.to_geodetic(np.asarray(xyz, float))
        return LocalENU(float(lat), float(lon), float(h))
