"""The smoother's navigation frame: a fixed NED tangent plane at the flight centre (earth-fixed, rotating).

Poses in the factor graph are `R_body_to_nav`, `p_nav` with nav = NED axes at the origin. Because the
plane is fixed, local level tilts away from it by distance/R_earth (0.009 deg per km); outputs are
rotated into the local NED frame of each point (`to_world`). Gravity is taken constant (normal gravity at
the origin along nav Down), which is exact at the origin and drifts by g*d/R (0.15 mg per km) away from
it — flights are expected to span a few km at most (see docs/pos_smoother.md).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import gtsam
import numpy as np

from dgcal.fields.constants import A_WGS84, OMEGA_EARTH
from dgcal.fields.crs import ecef_to_geodetic, geodetic_to_ecef
from dgcal.fields.frames import R_ecef_to_ned


def normal_gravity(lat_deg: float | np.ndarray, h_m: float | np.ndarray) -> float | np.ndarray:
    """Normal gravity magnitude (m/s^2) on the WGS84 ellipsoid (Somigliana) with free-air height term; latitude
    (deg) and ellipsoidal height (m) scalars (a float back) or arrays."""
    s2 = np.sin(np.radians(lat_deg)) ** 2
    g0 = 9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - 0.00669437999013 * s2)
    g = g0 * (1 - 2 * np.asarray(h_m, float) / A_WGS84 * (1 + 1 / 298.257223563 + 0.00344978600308
                                                         - 2 / 298.257223563 * s2) + 3 * np.asarray(h_m, float) ** 2
              / A_WGS84 ** 2)
    return float(g) if np.ndim(g) == 0 else g


@dataclass(frozen=True)
class NavFrame:
    """NED tangent frame at geodetic origin (degrees, ellipsoidal m)."""

    lat0: float
    lon0: float
    h0: float

    @classmethod
    def at_ecef(cls, p_ecef: np.ndarray) -> "NavFrame":
        """Frame at the ECEF point (m), e.g. the mean of the flight's positions."""
        lat, lon, h = ecef_to_geodetic(np.asarray(p_ecef, float))
        return cls(float(lat), float(lon), float(h))

    @cached_property
    def origin_ecef(self) -> np.ndarray:
        return geodetic_to_ecef(self.lat0, self.lon0, self.h0)

    @cached_property
    def R_nav_to_ecef(self) -> np.ndarray:
        return R_ecef_to_ned(self.lat0, self.lon0).T

    @cached_property
    def gravity(self) -> float:
        """Normal gravity magnitude at the origin (m/s^2), acting along nav Down."""
        return normal_gravity(self.lat0, self.h0)

    @cached_property
    def omega_ie_nav(self) -> np.ndarray:
        """Earth rotation rate in nav (NED) axes, rad/s."""
        lat = np.radians(self.lat0)
        return OMEGA_EARTH * np.array([np.cos(lat), 0.0, -np.sin(lat)])

    def ecef_T_nav(self):
        """gtsam Pose3 taking nav coordinates to ECEF (for the GNSS factors)."""
        return gtsam.Pose3(gtsam.Rot3(self.R_nav_to_ecef), self.origin_ecef)

    def to_ecef(self, p_nav) -> np.ndarray:
        """ECEF (m) of nav-frame points (m), shape (...,3)."""
        return np.asarray(p_nav, float) @ self.R_nav_to_ecef.T + self.origin_ecef

    def from_ecef(self, p_ecef) -> np.ndarray:
        """Nav-frame coordinates (m) of ECEF points (m), shape (...,3)."""
        return (np.asarray(p_ecef, float) - self.origin_ecef) @ self.R_nav_to_ecef

    def R_nav_to_local_ned(self, p_nav) -> np.ndarray:
        """Rotation(s) from nav axes to the local NED axes at nav points (earth curvature); (...,3,3)."""
        g = ecef_to_geodetic(self.to_ecef(p_nav))
        return R_ecef_to_ned(g[..., 0], g[..., 1]) @ self.R_nav_to_ecef
