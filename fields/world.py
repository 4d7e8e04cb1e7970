"""The one world frame of a problem and every conversion into it: map points, EOPs, geodetic POS samples.

The world (docs/conventions.md, "Frames") is a local ENU frame (East, North, Up, m) tangent at a point of the
block (`dgcal.fields.crs.LocalENU`); triangulation, mounting calibration and DG all work in it, and this
module is the one place that converts into it and back:
- map points (grid E, grid N, height) <-> world points. Map heights are ellipsoidal, or orthometric with a
  geoid (`Geoid`: a constant undulation or a PROJ vertical grid), `h = H + N`;
- EOPs (map projection centre, PATB omega/phi/kappa relative to grid-level axes at the centre) <->
  `dgcal.fields.pose.Poses`, with covariances:
  `R_cam_to_grid(C) = R_enu_to_grid(gamma(C)) @ R_enu(C)_to_world^T @ R_cam_to_world`,
  which carries meridian convergence gamma and earth curvature;
- geodetic POS samples (lat, lon, h, v_ned, roll/pitch/heading) <-> world position, velocity and
  `R_body_to_world`, and POS sigmas -> world covariances.
An engineering world (no CRS, e.g. a MicMac ground frame): map = world + a constant shift, grid axes = world
axes, no geodetic link.

Covariances: poses [C_world (m), dtheta (rad)] with dtheta a right perturbation of R_cam_to_world
(`dgcal.fields.pose`); EOPs [position (m along grid E, grid N, Up at the centre; metres for a geographic CRS
too), omega, phi, kappa (deg)]; POS [r_imu_world (m), dtheta (rad)] with dtheta a right perturbation of
R_body_to_world (body axes): the pose rule, so `Poses.from_body_to_world(R_body_to_world, r_imu_world, cov)` is the
POS sample's body pose as it is. EOP and pose covariances are linked by one Jacobian (`World.eop_jacobian`), so
the two directions are inverses.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import pyproj

from dgcal.fields.crs import LocalENU, MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.frames import (R_ENU_TO_NED, R_NED_TO_ENU, R_body_to_ned_from_rph, R_cam_to_map_from_opk,
                                 R_enu_to_grid, opk_from_R_cam_to_map, rph_from_R_body_to_ned)
from dgcal.fields.pose import Poses, numeric_rot_jacobian, transpose

ENGINEERING_CRS = ("", "local", "none")  # CRS texts that mean "no CRS: an engineering frame"
_H_POS, _H_ROT = 1e-3, 1e-6               # steps (m, rad) of the EOP Jacobian's central differences


@dataclass(frozen=True)
class Geoid:
    """Geoid undulation N (m) over the ellipsoid: a constant, or a PROJ vertical grid file (`h = H + N`)."""

    constant: float | None = None
    grid_file: str | None = None

    @classmethod
    def parse(cls, spec: float | str | None, field: str = "--geoid") -> "Geoid | None":
        """A geoid from a number (constant N, m) or the path of a PROJ vertical grid; None for None."""
        if spec is None or isinstance(spec, Geoid):
            return spec
        try:
            return cls(constant=float(spec))
        except (TypeError, ValueError):
            pass
        if not Path(str(spec)).exists():
            raise InputError("geoid grid file not found", spec, field=field)
        return cls(grid_file=str(spec))

    @cached_property
    def _vgridshift(self) -> pyproj.Transformer:
        return pyproj.Transformer.from_pipeline(f"+proj=vgridshift +grids={self.grid_file} +multiplier=1")

    def undulation(self, lat_deg: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
        """N (m) at geodetic points (degrees)."""
        lat = np.atleast_1d(np.asarray(lat_deg, float))
        if self.constant is not None:
            return np.full(len(lat), self.constant)
        _, _, n = self._vgridshift.transform(np.atleast_1d(lon_deg), lat, np.zeros(len(lat)))
        return -np.asarray(n)   # vgridshift subtracts N from ellipsoidal heights


class World:
    """The world frame of a problem (a local ENU frame) and its links to a map CRS, EOPs and POS samples.

    `World(grid, enu)` for a map grid and a tangent frame; `World.from_crs` (user CRS text, engineering
    frames), `World.at_map_points` (tangent at the mean of map points) and `World.engineering` build one."""

    def __init__(self, grid: MapGrid | None, enu: LocalENU | None, *, geoid: Geoid | float | str | None = None,
                 origin_map: np.ndarray | None = None, crs_text: str | None = None):
        if (grid is None) != (enu is None):
            raise ValueError("a world needs both a map grid and an ENU frame, or neither (an engineering frame)")
        if grid is None and origin_map is None:
            raise ValueError("an engineering world needs origin_map, the map coordinates of its origin")
        self.grid = grid
        self.enu = enu
        self.geoid = None if grid is None else Geoid.parse(geoid)
        self.origin_map = None if origin_map is None else np.asarray(origin_map, float).reshape(3)
        self._crs_text = crs_text

    # --- construction -------------------------------------------------------------------------
    @classmethod
    def from_crs(cls, crs: str | None, centre_map: np.ndarray, geoid: Geoid | float | str | None = None,
                 source: str | Path | None = None) -> "World":
        """The world tangent at map point `centre_map` (m) of CRS text `crs`; None, "local", "none" or "" give an
        engineering world shifted by `centre_map`. InputError naming `source` when the centre is not valid there."""
        if crs is None or str(crs).strip().lower() in ENGINEERING_CRS:
            return cls.engineering(centre_map)
        return cls._tangent_at(MapGrid(str(crs)), centre_map, geoid, source, str(crs))

    @classmethod
    def at_map_points(cls, grid: MapGrid, xyz_map: np.ndarray, geoid: Geoid | float | str | None = None) -> "World":
        """The world tangent at the mean of map points (N,3) (m)."""
        return cls._tangent_at(grid, np.mean(np.asarray(xyz_map, float).reshape(-1, 3), axis=0), geoid)

    @classmethod
    def engineering(cls, origin_map: np.ndarray) -> "World":
        """An engineering world: map coordinates minus `origin_map` (m), axes unchanged, no CRS."""
        return cls(None, None, origin_map=origin_map)

    @classmethod
    def _tangent_at(cls, grid: MapGrid, centre_map, geoid, source=None, crs_text: str | None = None) -> "World":
        centre = np.asarray(centre_map, float).reshape(1, 3)
        gd = Geoid.parse(geoid)
        lat, lon, h = grid.to_geodetic(centre + [0.0, 0.0, _undulation(grid, gd, centre)[0]])[0]
        if not (np.isfinite([lat, lon, h]).all() and abs(lat) <= 90):
            raise InputError(f"the ground points are not valid coordinates in {crs_text or grid.crs.srs} "
                             f"(centre {centre[0].round(3).tolist()}): wrong --crs?", source, field="crs")
        return cls(grid, LocalENU(float(lat), float(lon), float(h)), geoid=gd, crs_text=crs_text)

    @property
    def local_only(self) -> bool:
        """True for an engineering world (no map CRS)."""
        return self.grid is None

    @property
    def crs_text(self) -> str | None:
        """The map CRS as the user gave it (None for an engineering world)."""
        if self.grid is None:
            return None
        return self._crs_text if self._crs_text is not None else self.grid.crs.srs

    # --- heights ------------------------------------------------------------------------------
    def undulation(self, xyz_map: np.ndarray) -> np.ndarray:
        """Geoid undulation N (m) at map points (N,3) (0 without a geoid)."""
        return _undulation(self.grid, self.geoid, np.atleast_2d(np.asarray(xyz_map, float)))

    def _to_ellipsoidal(self, xyz_map: np.ndarray) -> np.ndarray:
        xyz = np.array(np.atleast_2d(xyz_map), float)
        xyz[:, 2] += self.undulation(xyz) / getattr(self.grid, "z_unit_m", 1.0)   # N (m) in height units
        return xyz

    def _from_ellipsoidal(self, xyz_ell: np.ndarray) -> np.ndarray:
        xyz = np.array(np.atleast_2d(xyz_ell), float)
        xyz[:, 2] -= self.undulation(xyz) / getattr(self.grid, "z_unit_m", 1.0)   # N (m) in height units
        return xyz

    # --- points -------------------------------------------------------------------------------
    def to_world(self, xyz_map: np.ndarray) -> np.ndarray:
        """World coordinates (N,3) (m) of map points (N,3) (m; heights as the map's)."""
        xyz = np.atleast_2d(np.asarray(xyz_map, float))
        if self.local_only:
            return xyz - self.origin_map
        return self.enu.from_ecef(self.grid.to_ecef(self._to_ellipsoidal(xyz)))

    def to_map(self, p_world: np.ndarray) -> np.ndarray:
        """Map coordinates (N,3) (m) of world points (N,3) (m)."""
        p = np.atleast_2d(np.asarray(p_world, float))
        if self.local_only:
            return p + self.origin_map
        return self._from_ellipsoidal(self.grid.from_ecef(self.enu.to_ecef(p)))

    def R_world_to_grid_at(self, p_world: np.ndarray) -> np.ndarray:
        """(N,3,3) rotations from world axes to grid-level axes (grid E, grid N, Up) at world points (N,3) (m):
        earth curvature, then meridian convergence."""
        p = np.atleast_2d(np.asarray(p_world, float))
        if self.local_only:
            return np.tile(np.eye(3), (len(p), 1, 1))
        g = self.enu.to_geodetic(p)
        R_here_to_world = self.enu.R_enu_here_to_local(g[:, 0], g[:, 1])
        gamma = np.asarray(self.grid.convergence_deg(g[:, 0], g[:, 1]), float)
        return R_enu_to_grid(gamma).reshape(-1, 3, 3) @ transpose(R_here_to_world)

    # --- EOPs <-> poses -----------------------------------------------------------------------
    def eop_to_poses(self, xyz_map: np.ndarray, opk_deg: np.ndarray, cov_map: np.ndarray | None = None) -> Poses:
        """World poses from map EOPs: centres (N,3) (m), PATB omega/phi/kappa (N,3) (deg) and optional (N,6,6) EOP
        covariances [position (m, grid-level axes), omega, phi, kappa (deg)] (into [C_world (m), dtheta (rad)])."""
        C = self.to_world(xyz_map)
        o = np.atleast_2d(np.asarray(opk_deg, float))
        R_cam_to_grid = R_cam_to_map_from_opk(o[:, 0], o[:, 1], o[:, 2]).reshape(-1, 3, 3)
        poses = Poses.from_cam_to_world(transpose(self.R_world_to_grid_at(C)) @ R_cam_to_grid, C)
        if cov_map is not None:
            Jinv = np.linalg.inv(self.eop_jacobian(poses))
            poses.cov = Jinv @ np.asarray(cov_map, float).reshape(-1, 6, 6) @ transpose(Jinv)
        return poses

    def poses_to_eop(self, poses: Poses) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Map centres (N,3) (m), PATB omega/phi/kappa (N,3) (deg) and, when `poses.cov` is set, (N,6,6) EOP
        covariances [position (m, grid-level axes), omega, phi, kappa (deg)] of world poses (inverse of
        `eop_to_poses`)."""
        C_world, R_cam_to_world = poses.C_world, poses.R_cam_to_world
        xyz, opk = self.to_map(C_world), self._opk(C_world, R_cam_to_world)
        cov = None
        if poses.cov is not None:
            J = self.eop_jacobian(poses)
            cov = J @ poses.cov @ transpose(J)
        return xyz, opk, cov

    def eop_jacobian(self, poses: Poses) -> np.ndarray:
        """(N,6,6) d[EOP position (m along grid E, grid N, Up), omega, phi, kappa (deg)] / d[C_world (m), dtheta (rad)]
        at world poses, dtheta a right perturbation of R_cam_to_world.

        Position errors are metres along the grid-level axes at the centre, for a geographic CRS too (the map's
        scale factor, < 1e-3, is not applied): `R_world_to_grid_at(C)`. The angles' derivatives (convergence and
        curvature move with C) by central differences."""
        C_world, R_cam_to_world = poses.C_world, poses.R_cam_to_world
        R_world_to_grid = self.R_world_to_grid_at(C_world)
        J = np.zeros((len(C_world), 6, 6))
        J[:, :3, :3] = R_world_to_grid
        for j in range(3):
            dC = np.zeros(3)
            dC[j] = _H_POS
            op, om = (self._opk(C_world + s * dC, R_cam_to_world) for s in (1.0, -1.0))
            J[:, 3:, j] = _wrap_deg(op - om) / (2 * _H_POS)
            d = np.zeros((len(C_world), 6))
            d[:, 3 + j] = _H_ROT
            op, om = (self._opk(C_world, poses.retract(s * d).R_cam_to_world, R_world_to_grid) for s in (1.0, -1.0))
            J[:, 3:, 3 + j] = _wrap_deg(op - om) / (2 * _H_ROT)
        return J

    def _opk(self, C_world: np.ndarray, R_cam_to_world: np.ndarray,
             R_world_to_grid: np.ndarray | None = None) -> np.ndarray:
        """PATB omega/phi/kappa (N,3) (deg) of world orientations at world centres."""
        R_world_to_grid = self.R_world_to_grid_at(C_world) if R_world_to_grid is None else R_world_to_grid
        R_cam_to_grid = R_world_to_grid @ np.asarray(R_cam_to_world, float).reshape(-1, 3, 3)
        return np.atleast_2d(opk_from_R_cam_to_map(R_cam_to_grid))

    # --- geodetic POS samples <-> world -------------------------------------------------------
    def _geodetic(self) -> None:
        if self.local_only:
            raise InputError("geodetic POS samples need a map CRS (this world is an engineering frame)",
                             field="crs")

    def pos_to_world(self, lat_deg: np.ndarray, lon_deg: np.ndarray, h_m: np.ndarray, v_ned: np.ndarray,
                     rph_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """IMU positions (N,3) (m), velocities (N,3) (m/s) in the world and R_body_to_world (N,3,3) from geodetic
        POS samples: lat, lon (deg), ellipsoidal h (m), v_ned (N,3) (m/s), roll/pitch/heading (N,3) (deg)."""
        self._geodetic()
        lat, lon, h = (np.atleast_1d(np.asarray(a, float)) for a in (lat_deg, lon_deg, h_m))
        R_here_to_world = self.enu.R_enu_here_to_local(lat, lon).reshape(-1, 3, 3)
        rph = np.atleast_2d(np.asarray(rph_deg, float))
        R_body_to_ned = R_body_to_ned_from_rph(rph[:, 0], rph[:, 1], rph[:, 2]).reshape(-1, 3, 3)
        R_body_to_world = R_here_to_world @ R_NED_TO_ENU @ R_body_to_ned
        v_world = np.einsum("nij,nj->ni", R_here_to_world, np.atleast_2d(np.asarray(v_ned, float)) @ R_NED_TO_ENU.T)
        return self.enu.from_geodetic(lat, lon, h).reshape(-1, 3), v_world, R_body_to_world

    def world_to_pos(self, r_world: np.ndarray, v_world: np.ndarray, R_body_to_world: np.ndarray,
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """lat, lon (deg), ellipsoidal h (m), v_ned (N,3) (m/s), roll/pitch/heading (N,3) (deg) of world IMU
        positions (m), velocities (m/s) and R_body_to_world (inverse of `pos_to_world`)."""
        self._geodetic()
        geo = self.enu.to_geodetic(np.atleast_2d(np.asarray(r_world, float)))
        R_world_to_here = transpose(self.enu.R_enu_here_to_local(geo[:, 0], geo[:, 1]).reshape(-1, 3, 3))
        R_body_to_ned = R_ENU_TO_NED @ R_world_to_here @ np.asarray(R_body_to_world, float).reshape(-1, 3, 3)
        v_ned = np.einsum("nij,nj->ni", R_world_to_here, np.atleast_2d(np.asarray(v_world, float))) @ R_ENU_TO_NED.T
        return geo[:, 0], geo[:, 1], geo[:, 2], v_ned, rph_from_R_body_to_ned(R_body_to_ned)

    def pos_covariance_to_world(self, lat_deg: np.ndarray, lon_deg: np.ndarray, rph_deg: np.ndarray,
                                sigma: np.ndarray) -> np.ndarray:
        """(N,6,6) covariances of [IMU position in the world (m), body-axes rotation error (rad)] of geodetic POS
        samples from their sigmas (N,6): s_lat_m (north), s_lon_m (east), s_h_m (m), s_roll, s_pitch,
        s_heading (deg)."""
        self._geodetic()
        lat, lon = (np.atleast_1d(np.asarray(a, float)) for a in (lat_deg, lon_deg))
        rph = np.atleast_2d(np.asarray(rph_deg, float))
        sigma = np.atleast_2d(np.asarray(sigma, float))
        R_here_to_world = self.enu.R_enu_here_to_local(lat, lon).reshape(-1, 3, 3)
        C = np.zeros((len(lat), 6, 6))
        C_enu = np.zeros((len(lat), 3, 3))
        C_enu[:, 0, 0], C_enu[:, 1, 1], C_enu[:, 2, 2] = sigma[:, 1] ** 2, sigma[:, 0] ** 2, sigma[:, 2] ** 2
        C[:, :3, :3] = R_here_to_world @ C_enu @ transpose(R_here_to_world)

        def R_body_to_ned_of(a):
            return R_body_to_ned_from_rph(a[:, 0], a[:, 1], a[:, 2]).reshape(-1, 3, 3)

        # a right perturbation of R_body_to_ned is the same body-axes perturbation of R_body_to_world
        Jr = numeric_rot_jacobian(R_body_to_ned_of, rph, R_body_to_ned_of(rph), 1e-5)  # rad per degree
        C_rph = np.zeros((len(lat), 3, 3))
        C_rph[:, np.arange(3), np.arange(3)] = sigma[:, 3:] ** 2
        C[:, 3:, 3:] = Jr @ C_rph @ transpose(Jr)
        return C


def _undulation(grid: MapGrid | None, geoid: Geoid | None, xyz_map: np.ndarray) -> np.ndarray:
    """N (m) at map points (N,3) of `grid` (0 without a geoid)."""
    if geoid is None:
        return np.zeros(len(xyz_map))
    if geoid.constant is not None:
        return np.full(len(xyz_map), geoid.constant)
    g = grid.to_geodetic(np.column_stack([xyz_map[:, :2], np.zeros(len(xyz_map))]))
    return geoid.undulation(g[:, 0], g[:, 1])


def _wrap_deg(d_deg: np.ndarray) -> np.ndarray:
    return (np.asarray(d_deg) + 180.0) % 360.0 - 180.0
