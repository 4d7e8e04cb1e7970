"""The one pose type of dgcal: camera (or body) orientations and positions in the world frame of a problem.

Convention (docs/conventions.md, "Poses"):
- `R_world_to_cam` (N,3,3) takes world vectors into camera axes (x right, y down, z forward):
  `X_cam = R_world_to_cam @ (X_world - C_world)`.
- `C_world` (N,3): projection centre (or body origin) in the world frame, m.
- A pose error or update `d = [dC (3, m, world axes), dtheta (3, rad, camera axes)]` acts as
  `C <- C + dC`, `R_cam_to_world <- R_cam_to_world @ Exp(dtheta)`
  (equivalently `R_world_to_cam <- Exp(-dtheta) @ R_world_to_cam`): a right perturbation of the
  camera-to-world rotation, the rule of gtsam's Rot3 and of the mounting residuals.
- Covariances are (N,6,6) in the order [C_world (m), dtheta (rad)].
The world is the one Cartesian frame of a problem: a local ENU frame at the block for aerial work
(`dgcal.fields.world`), the target field's frame for camera calibration.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.fields.frames import skew


def so3_exp(v: np.ndarray) -> np.ndarray:
    """Rotation matrices (...,3,3) of rotation vectors (...,3) (rad)."""
    v = np.asarray(v, float)
    return Rotation.from_rotvec(v.reshape(-1, 3)).as_matrix().reshape(v.shape[:-1] + (3, 3))


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (...,3) (rad) of rotation matrices (...,3,3)."""
    R = np.asarray(R, float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def so3_right_jacobian(phi: np.ndarray) -> np.ndarray:
    """(...,3,3) right Jacobian of SO(3) at rotation vectors phi (...,3): Exp(phi + d) ~ Exp(phi) Exp(Jr d)."""
    phi = np.asarray(phi, float)
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = skew(phi)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.where(th > 1e-6, (1 - np.cos(th)) / th**2, 0.5)
        b = np.where(th > 1e-6, (th - np.sin(th)) / th**3, 1.0 / 6.0)
    return np.eye(3) - a * K + b * (K @ K)


def so3_right_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """(...,3,3) inverse right Jacobian of SO(3) at rotation vectors phi (...,3):
    Log(Exp(phi) Exp(d)) ~ phi + Jr^-1 d."""
    phi = np.asarray(phi, float)
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = skew(phi)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(th > 1e-6, 1.0 / th**2 - (1 + np.cos(th)) / (2 * th * np.sin(th)), 1.0 / 12.0)
    return np.eye(3) + 0.5 * K + c * (K @ K)


def transpose(R: np.ndarray) -> np.ndarray:
    """Transpose of the last two axes (the inverse of stacked rotations)."""
    return np.swapaxes(R, -1, -2)


def numeric_rot_jacobian(fun, x0: np.ndarray, R0: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """d delta / d x (N,3,k) by central differences, where fun(x (N,k)) -> (N,3,3) and delta = Log(R0^T fun(x))
    is the right perturbation (rad) of R0 (N,3,3); x in the units of x0 (N,k)."""
    n, k = x0.shape
    J = np.empty((n, 3, k))
    for j in range(k):
        d = np.zeros(k)
        d[j] = step
        J[:, :, j] = (so3_log(transpose(R0) @ fun(x0 + d)) - so3_log(transpose(R0) @ fun(x0 - d))) / (2 * step)
    return J


@dataclass
class Poses:
    """N poses in one world frame, with optional (N,6,6) covariances [C_world (m), dtheta (rad)]."""

    R_world_to_cam: np.ndarray
    C_world: np.ndarray
    cov: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.R_world_to_cam = np.asarray(self.R_world_to_cam, float).reshape(-1, 3, 3)
        self.C_world = np.asarray(self.C_world, float).reshape(-1, 3)
        if self.cov is not None:
            self.cov = np.asarray(self.cov, float).reshape(-1, 6, 6)

    def __len__(self) -> int:
        return len(self.C_world)

    def __getitem__(self, idx) -> "Poses":
        return Poses(self.R_world_to_cam[idx], self.C_world[idx], None if self.cov is None else self.cov[idx])

    @property
    def R_cam_to_world(self) -> np.ndarray:
        """(N,3,3) camera axes into the world frame."""
        return transpose(self.R_world_to_cam)

    @property
    def t_cam(self) -> np.ndarray:
        """(N,3) translation of `X_cam = R_world_to_cam @ X_world + t_cam`, m."""
        return -np.einsum("nij,nj->ni", self.R_world_to_cam, self.C_world)

    @classmethod
    def from_R_t(cls, R_world_to_cam: np.ndarray, t_cam: np.ndarray, cov: np.ndarray | None = None) -> "Poses":
        """Poses from `X_cam = R @ X_world + t` (OpenCV's rvec/tvec form)."""
        R = np.asarray(R_world_to_cam, float).reshape(-1, 3, 3)
        return cls(R, -np.einsum("nji,nj->ni", R, np.asarray(t_cam, float).reshape(-1, 3)), cov)

    @classmethod
    def from_cam_to_world(cls, R_cam_to_world: np.ndarray, C_world: np.ndarray,
                          cov: np.ndarray | None = None) -> "Poses":
        """Poses from camera-to-world rotations (N,3,3) and centres (N,3)."""
        return cls(transpose(np.asarray(R_cam_to_world, float)), C_world, cov)

    def to_cam(self, X_world: np.ndarray, index: np.ndarray | None = None) -> np.ndarray:
        """Camera-frame coordinates (k,3) of world points (k,3) seen by poses `index` (k,) (all poses if None)."""
        R = self.R_world_to_cam if index is None else self.R_world_to_cam[index]
        C = self.C_world if index is None else self.C_world[index]
        return np.einsum("nij,nj->ni", R, np.asarray(X_world, float) - C)

    def retract(self, d: np.ndarray) -> "Poses":
        """Poses moved by errors/updates d (N,6) = [dC (m), dtheta (rad)] under the perturbation rule above."""
        d = np.asarray(d, float).reshape(-1, 6)
        R_c2w = self.R_cam_to_world @ so3_exp(d[:, 3:])
        return Poses(transpose(R_c2w), self.C_world + d[:, :3], self.cov)

    def difference(self, other: "Poses") -> np.ndarray:
        """d (N,6) with `other.retract(d) == self`: [C - C_other, Log(R_other_cam_to_world^T R_cam_to_world)]."""
        dtheta = so3_log(other.R_world_to_cam @ self.R_cam_to_world)
        return np.column_stack([self.C_world - other.C_world, dtheta])

    def sigmas(self) -> np.ndarray:
        """(N,6) standard deviations [C (m), dtheta (rad)] from the covariances (NaN without)."""
        if self.cov is None:
            return np.full((len(self), 6), np.nan)
        return np.sqrt(np.clip(np.einsum("nkk->nk", self.cov), 0.0, None))
