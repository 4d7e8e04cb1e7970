"""The boresight as the reports show it: small rotation angles θx, θy, θz about the body axes from the nominal
mounting (the axis-aligned rotation nearest R_cam_to_body), R_cam_to_body = Exp(θ) R_nominal — the axes the
boresight sigmas of mounting.json are about (`boresight_sigma_axes`), so each angle stands beside its own sigma."""
from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial.transform import Rotation

CAPTION = ("Boresight: small rotations θx, θy, θz (°) about the body axes (x forward, y right, z down) that turn the "
           "nominal mounting R_nominal (the axis-aligned camera-to-body rotation nearest the estimate) into the "
           "estimate, R_cam_to_body = Exp(θ) R_nominal; the sigmas are about the same axes. Camera axes: x right, "
           "y down, z along the view (OpenCV).")


def _signed_permutations() -> np.ndarray:
    """The 24 axis-aligned rotation matrices (signed permutations with determinant +1)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            M = np.zeros((3, 3))
            M[range(3), perm] = signs
            if np.linalg.det(M) > 0:
                out.append(M)
    return np.array(out)


_AXIS_ALIGNED = _signed_permutations()


def nominal_mounting(R_cam_to_body) -> np.ndarray:
    """The axis-aligned rotation nearest `R_cam_to_body` (largest trace of R R_nominalᵀ: smallest angle)."""
    R = np.asarray(R_cam_to_body, float)
    return _AXIS_ALIGNED[int(np.argmax(np.einsum("ij,kij->k", R, _AXIS_ALIGNED)))]


def boresight_angles_deg(R_cam_to_body) -> tuple[np.ndarray, np.ndarray]:
    """(θ about body x, y, z in degrees, R_nominal): R_cam_to_body = Exp(θ) R_nominal."""
    R = np.asarray(R_cam_to_body, float)
    R_nom = nominal_mounting(R)
    return np.degrees(Rotation.from_matrix(R @ R_nom.T).as_rotvec()), R_nom


def matrix_text(R, decimals: int = 6) -> str:
    """A 3×3 matrix as 'r11, r12, r13; r21, …' (rows separated by '; ')."""
    return "; ".join(", ".join(f"{v:+.{decimals}f}" for v in row) for row in np.asarray(R, float))
