"""The link between a map CRS and the local Cartesian frame of the adjustment, for points and EOPs.

The adjustment runs in a local ENU frame at the field centre (`dgcal.fields.crs.LocalENU`). Map coordinates
are (grid E, grid N, height); heights are ellipsoidal unless a geoid is given, in which case map
heights are orthometric and `h = H + N` with N from a constant or a PROJ vertical grid.
EOP angles (PATB omega/phi/kappa) refer to grid-level axes at the projection centre (docs/conventions.md):
`R_cam_to_grid(C) = R_enu_to_grid(gamma(C)) @ R_enu(C)_to_local^T @ R_cam_to_world`, which carries both
meridian convergence and earth curvature. With `crs=None` the map frame *is* the local frame (an
engineering frame such as a MicMac ground frame), shifted only to keep numbers small.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dgcal.fields.crs import LocalENU, MapGrid, parse_crs
from dgcal.fields.errors import InputError
from dgcal.fields.frames import R_cam_to_map_from_opk, R_enu_to_grid, opk_from_R_cam_to_map


class Georef:
    """Map CRS <-> local adjustment frame, for points, heights and camera orientations."""

    def __init__(self, crs: str | None, centre_map: np.ndarray, geoid: float | str | None = None,
                 source: str | Path | None = None):
        self.local_only = crs is None or str(crs).strip().lower() in ("", "local", "none")
        self.crs_text = None if self.local_only else str(crs)
        self.centre_map = np.asarray(centre_map, float).reshape(3)
        self._geoid_const = None
        self._geoid_tf = None
        if geoid is not None and not self.local_only:
            try:
                self._geoid_const = float(geoid)
            except (TypeError, ValueError):
                import pyproj
                if not Path(str(geoid)).exists():
                    raise InputError("geoid grid file not found", geoid, field="--geoid") from None
                self._geoid_tf = pyproj.Transformer.from_pipeline(f"+proj=vgridshift +grids={geoid} +multiplier=1")
        if self.local_only:
            self.grid = None
            self.frame = None
        else:
            self.grid = MapGrid(parse_crs(self.crs_text))
            lat, lon, h = self.grid.to_geodetic(self._to_ellipsoidal(self.centre_map[None]))[0]
            if not (np.isfinite([lat, lon, h]).all() and abs(lat) <= 90):
                raise InputError(f"the ground points are not valid coordinates in {self.crs_text} "
                                 f"(centre {self.centre_map.round(3).tolist()}): wrong --crs?", source, field="--crs")
            self.frame = LocalENU(float(lat), float(lon), float(h))

    # --- heights ----------------------------------------------------------------------------
    def undulation(self, xyz_map: np.ndarray) -> np.ndarray:
        """Geoid undulation N (m) at map points (0 without a geoid)."""
        xyz = np.atleast_2d(xyz_map)
        if self._geoid_const is not None:
            return np.full(len(xyz), self._geoid_const)
        if self._geoid_tf is not None:
            g = self.grid.to_geodetic(np.column_stack([xyz[:, :2], np.zeros(len(xyz))]))
            _, _, n = self._geoid_tf.transform(g[:, 1], g[:, 0], np.zeros(len(xyz)))
            return -np.asarray(n)   # vgridshift subtracts N from ellipsoidal heights
        return np.zeros(len(xyz))

    def _to_ellipsoidal(self, xyz_map):
        xyz = np.array(np.atleast_2d(xyz_map), float)
        xyz[:, 2] += self.undulation(xyz)
        return xyz

    def _from_ellipsoidal(self, xyz_ell):
        xyz = np.array(np.atleast_2d(xyz_ell), float)
        xyz[:, 2] -= self.undulation(xyz)
        return xyz

    # --- points -----------------------------------------------------------------------------
    def to_world(self, xyz_map: np.ndarray) -> np.ndarray:
        """Local ENU (m) of map points (m)."""
        xyz = np.atleast_2d(np.asarray(xyz_map, float))
        if self.local_only:
            return xyz - self.centre_map
        return self.frame.from_ecef(self.grid.to_ecef(self._to_ellipsoidal(xyz)))

    def to_map(self, p_local: np.ndarray) -> np.ndarray:
        """Map coordinates of local ENU points."""
        p = np.atleast_2d(np.asarray(p_local, float))
        if self.local_only:
            return p + self.centre_map
        return self._from_ellipsoidal(self.grid.from_ecef(self.frame.to_ecef(p)))

    def R_world_to_grid_at(self, p_local: np.ndarray) -> np.ndarray:
        """Rotation (N,3,3) from local-frame axes to grid-level axes (grid E, grid N, Up) at local points."""
        p = np.atleast_2d(np.asarray(p_local, float))
        if self.local_only:
            return np.tile(np.eye(3), (len(p), 1, 1))
        g = self.frame.to_geodetic(p)
        R_here_to_local = self.frame.R_enu_here_to_local(g[:, 0], g[:, 1])
        gamma = self.grid.convergence_deg(g[:, 0], g[:, 1])
        # (N,1) angles: dgcal.fields.frames.R_enu_to_grid passes them to scipy's from_euler as one axis each
        return R_enu_to_grid(np.asarray(gamma)[:, None]).reshape(-1, 3, 3) @ np.swapaxes(R_here_to_local, -1, -2)

    # --- orientations -----------------------------------------------------------------------
    def eop_to_map(self, R_world_to_cam: np.ndarray, C_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map projection centres (N,3) and PATB omega/phi/kappa (N,3, deg) from local orientations."""
        C = np.atleast_2d(C_world)
        R_cam_to_world = np.swapaxes(np.asarray(R_world_to_cam).reshape(-1, 3, 3), -1, -2)
        R_cam_to_grid = self.R_world_to_grid_at(C) @ R_cam_to_world
        return self.to_map(C), np.atleast_2d(opk_from_R_cam_to_map(R_cam_to_grid))

    def eop_to_world(self, xyz_map: np.ndarray, opk_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local orientations (R_world_to_cam (N,3,3), C_world (N,3)) from map EOPs."""
        C = self.to_world(xyz_map)
        o = np.atleast_2d(opk_deg)
        R_cam_to_grid = R_cam_to_map_from_opk(o[:, 0], o[:, 1], o[:, 2])
        R_cam_to_world = np.swapaxes(self.R_world_to_grid_at(C), -1, -2) @ R_cam_to_grid
        return np.swapaxes(R_cam_to_world, -1, -2), C

    def eop_covariance_to_map(self, R_world_to_cam: np.ndarray, C_world: np.ndarray, cov_pose: np.ndarray,
                              ) -> np.ndarray:
        """6x6 covariances of (X, Y, Z m, omega, phi, kappa deg) from pose covariances [C_world (m), dtheta (rad)]
        (dgcal.fields.pose: dtheta a right perturbation of R_cam_to_world), by numerical Jacobians."""
        from scipy.spatial.transform import Rotation
        R = np.asarray(R_world_to_cam).reshape(-1, 3, 3)
        C = np.atleast_2d(C_world)
        n = len(C)
        xyz0, opk0 = self.eop_to_map(R, C)
        J = np.zeros((n, 6, 6))
        h_pos, h_rot = 1e-3, 1e-6
        for j in range(3):
            dC = np.zeros(3)
            dC[j] = h_pos
            xp, op_ = self.eop_to_map(R, C + dC)
            xm, om = self.eop_to_map(R, C - dC)
            J[:, :3, j] = (xp - xm) / (2 * h_pos)
            J[:, 3:, j] = _wrap(op_ - om) / (2 * h_pos)
            d = np.zeros(3)
            d[j] = h_rot
            # R_cam_to_world Exp(+-d)  <=>  R_world_to_cam <- Exp(-+d) R_world_to_cam
            Rp = Rotation.from_rotvec(-d).as_matrix() @ R
            Rm = Rotation.from_rotvec(d).as_matrix() @ R
            xp, op_ = self.eop_to_map(Rp, C)
            xm, om = self.eop_to_map(Rm, C)
            J[:, :3, 3 + j] = (xp - xm) / (2 * h_rot)
            J[:, 3:, 3 + j] = _wrap(op_ - om) / (2 * h_rot)
        return J @ np.asarray(cov_pose) @ np.swapaxes(J, -1, -2)


def _wrap(d_deg: np.ndarray) -> np.ndarray:
    return (np.asarray(d_deg) + 180.0) % 360.0 - 180.0
