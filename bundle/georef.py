"""`Georef`: the world of a triangulation (`dgcal.fields.world.World`) under the constructor and the
(rotation, centre) tuple helpers that bundle/triangulation.py calls; it goes when triangulation uses
`World` and `Poses` directly.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dgcal.fields.pose import Poses
from dgcal.fields.world import World


class Georef(World):
    """`World.from_crs(crs, centre_map, geoid, source)` with EOP helpers on loose (R_world_to_cam, C_world) arrays."""

    def __init__(self, crs: str | None, centre_map: np.ndarray, geoid: float | str | None = None,
                 source: str | Path | None = None):
        w = World.from_crs(crs, centre_map, geoid, source)
        super().__init__(w.grid, w.enu, geoid=w.geoid, origin_map=w.origin_map, crs_text=w.crs_text)

    def eop_to_map(self, R_world_to_cam: np.ndarray, C_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map centres (N,3) (m) and PATB omega/phi/kappa (N,3) (deg) of world poses (`World.poses_to_eop`)."""
        return self.poses_to_eop(Poses(R_world_to_cam, C_world))[:2]

    def eop_to_world(self, xyz_map: np.ndarray, opk_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (R_world_to_cam (N,3,3), C_world (N,3) (m)) of map EOPs (m, deg) (`World.eop_to_poses`)."""
        p = self.eop_to_poses(xyz_map, opk_deg)
        return p.R_world_to_cam, p.C_world

    def eop_covariance_to_map(self, R_world_to_cam: np.ndarray, C_world: np.ndarray,
                              cov_pose: np.ndarray) -> np.ndarray:
        """(N,6,6) EOP covariances (m, deg) of pose covariances [C_world (m), dtheta (rad)] (`World.poses_to_eop`)."""
        return self.poses_to_eop(Poses(R_world_to_cam, C_world, cov_pose))[2]
