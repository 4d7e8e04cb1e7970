"""The one pose type of dgcal: camera (or body) orientations and positions in the world frame of a problem.

Convention (docs/conventions.md, "Poses"): `Poses(R_world_to_cam, C_world, cov, frame)`, a rigid transform
world -> `frame` (COLMAP's `cam_from_world`, with the frame's name):
- `frame` is "cam" (the camera: x right, y down, z forward; the default) or "body" (the IMU body, FRD);
- `R_world_to_cam` (N,3,3) takes world vectors into the frame's axes (the stored name is the camera's; for any
  frame `R_world_to_frame`, for a body pose `R_world_to_body`): `X_cam = R_world_to_cam @ (X_world - C_world)`;
- `C_world` (N,3): projection centre (camera) or IMU origin (body) in the world frame, m.
- A pose error or update `d = [dC (3, m, world axes), dtheta (3, rad, the frame's axes)]` acts as
  `C <- C + dC`, `R_cam_to_world <- R_cam_to_world @ Exp(dtheta)` (body: `R_body_to_world <- R_body_to_world
  @ Exp(dtheta)`; equivalently `R_world_to_frame <- Exp(-dtheta) @ R_world_to_frame`): a right perturbation of
  the frame-to-world rotation, the rule of gtsam's Rot3, of the POS covariances (`World.pos_covariance_to_world`)
  and of the mounting residuals.
- Covariances are (N,6,6) in the order [C_world (m), dtheta (rad)].
The world is the one Cartesian frame of a problem: a local ENU frame at the block for aerial work
(`dgcal.fields.world`), the target field's frame for camera calibration. A camera on a body is the body pose
`mounted` with lever arm and boresight.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.fields.frames import skew

FRAMES = ("cam", "body")   # what a pose orients: a camera (x right, y down, z forward) or the IMU body (FRD)


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
    """N poses of one frame (`frame`: "cam", a camera, or "body", the IMU body) in one world frame, with optional
    (N,6,6) covariances [C_world (m), dtheta (rad, the frame's axes)].

    `R_world_to_cam` is the stored rotation, world -> the pose's frame, whatever the frame (the name is the
    camera's, kept for compatibility); `R_world_to_frame` / `R_frame_to_world` say it for any frame,
    `R_world_to_body` / `R_body_to_world` for body poses, `R_cam_to_world` for camera poses (each refuses the
    other frame)."""

    R_world_to_cam: np.ndarray
    C_world: np.ndarray
    cov: np.ndarray | None = None
    frame: str = "cam"

    def __post_init__(self) -> None:
        if self.frame not in FRAMES:
            raise ValueError(f"a pose's frame is one of {FRAMES}, not {self.frame!r}")
        self.R_world_to_cam = np.asarray(self.R_world_to_cam, float).reshape(-1, 3, 3)
        self.C_world = np.asarray(self.C_world, float).reshape(-1, 3)
        if self.cov is not None:
            self.cov = np.asarray(self.cov, float).reshape(-1, 6, 6)

    def __len__(self) -> int:
        return len(self.C_world)

    def __getitem__(self, idx) -> "Poses":
        return Poses(self.R_world_to_cam[idx], self.C_world[idx], None if self.cov is None else self.cov[idx],
                     self.frame)

    def _need(self, frame: str) -> None:
        if self.frame != frame:
            raise ValueError(f"these are {self.frame} poses, not {frame} poses")

    # --- rotations ---------------------------------------------------------------------------
    @property
    def R_world_to_frame(self) -> np.ndarray:
        """(N,3,3) world vectors into the pose's frame (camera or body axes)."""
        return self.R_world_to_cam

    @property
    def R_frame_to_world(self) -> np.ndarray:
        """(N,3,3) the pose's frame (camera or body axes) into the world frame."""
        return transpose(self.R_world_to_cam)

    @property
    def R_cam_to_world(self) -> np.ndarray:
        """(N,3,3) camera axes into the world frame (camera poses only)."""
        self._need("cam")
        return transpose(self.R_world_to_cam)

    @property
    def R_body_to_world(self) -> np.ndarray:
        """(N,3,3) body axes (FRD) into the world frame (body poses only)."""
        self._need("body")
        return transpose(self.R_world_to_cam)

    @property
    def R_world_to_body(self) -> np.ndarray:
        """(N,3,3) world vectors into body axes (body poses only)."""
        self._need("body")
        return self.R_world_to_cam

    @property
    def t_cam(self) -> np.ndarray:
        """(N,3) translation of `X_cam = R_world_to_cam @ X_world + t_cam`, m (camera poses only)."""
        self._need("cam")
        return -np.einsum("nij,nj->ni", self.R_world_to_cam, self.C_world)

    # --- construction ------------------------------------------------------------------------
    @classmethod
    def from_R_t(cls, R_world_to_cam: np.ndarray, t_cam: np.ndarray, cov: np.ndarray | None = None) -> "Poses":
        """Camera poses from `X_cam = R @ X_world + t` (OpenCV's rvec/tvec form)."""
        R = np.asarray(R_world_to_cam, float).reshape(-1, 3, 3)
        return cls(R, -np.einsum("nji,nj->ni", R, np.asarray(t_cam, float).reshape(-1, 3)), cov)

    @classmethod
    def from_cam_to_world(cls, R_cam_to_world: np.ndarray, C_world: np.ndarray,
                          cov: np.ndarray | None = None) -> "Poses":
        """Camera poses from camera-to-world rotations (N,3,3) and centres (N,3)."""
        return cls(transpose(np.asarray(R_cam_to_world, float)), C_world, cov)

    @classmethod
    def from_body_to_world(cls, R_body_to_world: np.ndarray, r_imu_world: np.ndarray,
                           cov: np.ndarray | None = None) -> "Poses":
        """Body poses from body-to-world rotations (N,3,3), IMU positions (N,3) (m) and covariances (N,6,6)
        [position (m), body-axes rotation error (rad)], as `World.pos_to_world` and `pos_covariance_to_world`
        give them: the same right perturbation, so the covariance is taken as it is."""
        return cls(transpose(np.asarray(R_body_to_world, float)), r_imu_world, cov, "body")

    # --- use ---------------------------------------------------------------------------------
    def to_frame(self, X_world: np.ndarray, index: np.ndarray | None = None) -> np.ndarray:
        """Coordinates (k,3) in the pose's frame of world points (k,3), by poses `index` (k,) (all if None)."""
        R = self.R_world_to_cam if index is None else self.R_world_to_cam[index]
        C = self.C_world if index is None else self.C_world[index]
        return np.einsum("nij,nj->ni", R, np.asarray(X_world, float) - C)

    def to_cam(self, X_world: np.ndarray, index: np.ndarray | None = None) -> np.ndarray:
        """Camera-frame coordinates (k,3) of world points (k,3) seen by poses `index` (k,) (all poses if None)."""
        self._need("cam")
        return self.to_frame(X_world, index)

    def mounted(self, lever_arm_m: np.ndarray, R_sensor_to_frame: np.ndarray, frame: str = "cam") -> "Poses":
        """Poses of a sensor rigidly mounted in this pose's frame (a camera on the body: lever arm and boresight
        `R_cam_to_body`): origin `C_world + R_frame_to_world @ lever_arm_m` (3,) (m, this frame's axes), axes
        `R_frame_to_world @ R_sensor_to_frame` (3,3); the covariances carried through, the mounting taken as
        exact: dC_sensor = dC - R_frame_to_world [lever]x dtheta, dtheta_sensor = R_sensor_to_frame^T dtheta."""
        lever = np.asarray(lever_arm_m, float).reshape(3)
        R_sensor_to_frame = np.asarray(R_sensor_to_frame, float).reshape(3, 3)
        R_frame_to_world = self.R_frame_to_world
        C_world = self.C_world + np.einsum("nij,j->ni", R_frame_to_world, lever)
        cov = None
        if self.cov is not None:
            G = np.zeros((len(self), 6, 6))
            G[:, :3, :3] = np.eye(3)
            G[:, :3, 3:] = -R_frame_to_world @ skew(lever)
            G[:, 3:, 3:] = R_sensor_to_frame.T
            cov = G @ self.cov @ transpose(G)
        return Poses(transpose(R_frame_to_world @ R_sensor_to_frame), C_world, cov, frame)

    def retract(self, d: np.ndarray) -> "Poses":
        """Poses moved by errors/updates d (N,6) = [dC (m), dtheta (rad)] under the perturbation rule above."""
        d = np.asarray(d, float).reshape(-1, 6)
        R_frame_to_world = self.R_frame_to_world @ so3_exp(d[:, 3:])
        return Poses(transpose(R_frame_to_world), self.C_world + d[:, :3], self.cov, self.frame)

    def difference(self, other: "Poses") -> np.ndarray:
        """d (N,6) with `other.retract(d) == self`: [C - C_other, Log(R_other_frame_to_world^T R_frame_to_world)]
        (poses of the same frame)."""
        other._need(self.frame)
        dtheta = so3_log(other.R_world_to_cam @ self.R_frame_to_world)
        return np.column_stack([self.C_world - other.C_world, dtheta])

    def sigmas(self) -> np.ndarray:
        """(N,6) standard deviations [C (m), dtheta (rad)] from the covariances (NaN without)."""
        if self.cov is None:
            return np.full((len(self), 6), np.nan)
        return np.sqrt(np.clip(np.einsum("nkk->nk", self.cov), 0.0, None))
