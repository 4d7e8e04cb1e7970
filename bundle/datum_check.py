"""Is a given block (e.g. another program's answer) at the least-squares datum of a set of control points?

Frames: cameras as projection centres `C_world` (M,3) and rotations `R_cam_to_world` (M,3,3) in a Cartesian world
frame; control points `X_world` (n,3) observed at OpenCV pixels `uv` (n,2). The block's shape is kept: only a
7-parameter similarity of the whole block (rotation and scale about the centroid of the centres, then a
translation) is fitted to the control-point pixel residuals. Tie points do not enter: their image residuals
are invariant under a similarity of cameras and tie points together, so any bundle adjustment whose control
points are image observations ends at a block where this step is zero. A non-zero, significant step means the
block was not adjusted to these control measurements with those weights.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation


@dataclass
class DatumStep:
    """Similarity that moves the block to the control points' least-squares datum, with its covariance.

    rotvec_rad (3,) in world axes about `centre_world`, translation_m (3,), log_scale; cov (7,7) of
    [rotvec, translation, log_scale] from the pixel sigmas scaled by the fit's sigma0^2 when above 1;
    chi2 = step' cov^-1 step (7 dof); RMS pixel residuals before/after; the moved block R_cam_to_world, C_world."""

    rotvec_rad: np.ndarray
    translation_m: np.ndarray
    log_scale: float
    centre_world: np.ndarray
    cov: np.ndarray
    chi2: float
    rms_before_px: float
    rms_after_px: float
    R_cam_to_world: np.ndarray
    C_world: np.ndarray

    @property
    def angle_deg(self) -> float:
        """Rotation of the step (deg)."""
        return float(np.degrees(np.linalg.norm(self.rotvec_rad)))


def _apply(p: np.ndarray, R_cam_to_world: np.ndarray, C_world: np.ndarray, centre: np.ndarray):
    """The block moved by similarity p = [rotvec (rad, world axes), translation (m), log scale]: R_cam_to_world,
    C_world after the step."""
    R_step = Rotation.from_rotvec(p[:3]).as_matrix()   # world axes before the step -> after it
    C_moved = centre + np.exp(p[6]) * (C_world - centre) @ R_step.T + p[3:6]
    return np.einsum("ij,njk->nik", R_step, R_cam_to_world), C_moved


def gcp_datum_step(camera, R_cam_to_world: np.ndarray, C_world: np.ndarray, obs_image: np.ndarray, X_world: np.ndarray,
                   uv: np.ndarray, sigma_px: np.ndarray | float = 1.0) -> DatumStep:
    """Similarity (rad, m, log-scale) taking the block to the least-squares datum of control points `X_world`
    (n,3, fixed) measured at pixels `uv` (n,2) in images `obs_image` (n,), pixel sigmas `sigma_px`."""
    R_cam_to_world = np.asarray(R_cam_to_world, float)
    C_world = np.asarray(C_world, float)
    k = np.asarray(obs_image, int)
    X_world = np.asarray(X_world, float).reshape(-1, 3)
    uv = np.asarray(uv, float).reshape(-1, 2)
    sig = np.broadcast_to(np.asarray(sigma_px, float), uv.shape) if np.ndim(sigma_px) < 2 else sigma_px
    centre = C_world.mean(0)

    def residual(p):
        R_cam_to_world_p, C_world_p = _apply(p, R_cam_to_world, C_world, centre)
        X_cam = np.einsum("nji,nj->ni", R_cam_to_world_p[k], X_world - C_world_p[k])
        return ((camera.project(X_cam) - uv) / sig).ravel()

    r0 = residual(np.zeros(7))
    sol = least_squares(residual, np.zeros(7), method="lm", x_scale=np.r_[1e-3 * np.ones(3), 1e-2 * np.ones(3),
                                                                          1e-3])
    J = sol.jac
    dof = max(r0.size - 7, 1)
    s0sq = float(sol.fun @ sol.fun) / dof
    cov = np.linalg.pinv(J.T @ J) * max(s0sq, 1.0)
    R_cam_to_world_moved, C_world_moved = _apply(sol.x, R_cam_to_world, C_world, centre)
    chi2 = float(sol.x @ np.linalg.solve(cov, sol.x))
    def px(r):
        return float(np.sqrt(np.mean((r.reshape(-1, 2) * sig) ** 2)))
    return DatumStep(sol.x[:3].copy(), sol.x[3:6].copy(), float(sol.x[6]), centre, cov, chi2,
                     px(r0), px(sol.fun), R_cam_to_world_moved, C_world_moved)
