"""Rotations between the frames of dgcal: NED/ENU local level, IMU body (FRD), camera (CV and PATB).

Names say what a matrix does: `R_a_to_b @ v_a = v_b`.
- Attitude (roll, pitch, heading), degrees: Z-Y-X Euler angles of the rotation from local NED to body;
  `R_body_to_ned = Rz(heading) Ry(pitch) Rx(roll)`.
- EOP angles (omega, phi, kappa), degrees, PATB: `M = Rx(omega) Ry(phi) Rz(kappa)` is
  `R_photo_to_map`, with photogrammetric camera axes (x right, y up, z back) and map axes (E, N, Up).
- Camera frame of the computer-vision convention (x right, y down, z forward): `R_cam_to_photo = diag(1,-1,-1)`.
"""
from __future__ import annotations

import numpy as np

R_CV_TO_PHOTO = np.diag([1.0, -1.0, -1.0])
R_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
R_NED_TO_ENU = R_ENU_TO_NED.T  # the swap is its own inverse, .T keeps the intent readable
# the nominal mounting of a down-looking camera with the image top forward: camera x (right) = body y,
# camera y (down the image) = -body x, camera z (viewing direction) = body z (down)
R_CAM_TO_BODY_NADIR = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def _rotation():
    """scipy's Rotation class, imported at first use: scipy.spatial takes 0.15-0.35 s to import, and the ECEF/ENU
    rotations (all a single-point GNSS run needs here) use none of it."""
    from scipy.spatial.transform import Rotation   # why: see the docstring
    return Rotation


def R_body_to_ned_from_rph(roll_deg, pitch_deg, heading_deg) -> np.ndarray:
    """Body(FRD)-to-NED rotation(s) from roll, pitch, heading in degrees; shape (3,3) or (N,3,3)."""
    ang = np.stack(np.broadcast_arrays(heading_deg, pitch_deg, roll_deg), axis=-1)
    return _rotation().from_euler("ZYX", ang, degrees=True).as_matrix()


def rph_from_R_body_to_ned(R_body_to_ned: np.ndarray) -> np.ndarray:
    """Roll, pitch, heading (degrees, heading in [0, 360)) from body-to-NED rotation(s); shape (...,3)."""
    hpr = _rotation().from_matrix(R_body_to_ned).as_euler("ZYX", degrees=True)
    rph = hpr[..., ::-1].copy()
    rph[..., 2] = np.mod(rph[..., 2], 360.0)
    return rph


def R_photo_to_map_from_opk(omega_deg, phi_deg, kappa_deg) -> np.ndarray:
    """PATB matrix M = Rx(omega) Ry(phi) Rz(kappa) (photo axes to map E,N,Up); degrees in."""
    ang = np.stack(np.broadcast_arrays(omega_deg, phi_deg, kappa_deg), axis=-1)
    return _rotation().from_euler("XYZ", ang, degrees=True).as_matrix()


def opk_from_R_photo_to_map(R_photo_to_map: np.ndarray) -> np.ndarray:
    """Omega, phi, kappa in degrees (PATB) from photo-to-map rotation(s); shape (...,3)."""
    return _rotation().from_matrix(R_photo_to_map).as_euler("XYZ", degrees=True)


def R_cam_to_map_from_opk(omega_deg, phi_deg, kappa_deg) -> np.ndarray:
    """Rotation from the CV camera frame (x right, y down, z forward) to map (E,N,Up), from PATB angles."""
    return R_photo_to_map_from_opk(omega_deg, phi_deg, kappa_deg) @ R_CV_TO_PHOTO


def opk_from_R_cam_to_map(R_cam_to_map: np.ndarray) -> np.ndarray:
    """PATB omega, phi, kappa (degrees) from the CV-camera-to-map rotation(s)."""
    return opk_from_R_photo_to_map(R_cam_to_map @ R_CV_TO_PHOTO)


def R_ecef_to_enu(lat_deg, lon_deg) -> np.ndarray:
    """Rotation from ECEF to the local ENU frame at geodetic latitude/longitude (degrees); (3,3) or (N,3,3)."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(sl)
    R = np.array([[-so, co, z], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]], dtype=float)
    return np.moveaxis(R, (0, 1), (-2, -1)) if R.ndim > 2 else R


def R_ecef_to_ned(lat_deg, lon_deg) -> np.ndarray:
    """Rotation from ECEF to the local NED frame at geodetic latitude/longitude (degrees)."""
    return R_ENU_TO_NED @ R_ecef_to_enu(lat_deg, lon_deg)


def R_enu_to_grid(convergence_deg) -> np.ndarray:
    """Rotation from local ENU to grid-level axes (grid E, grid N, Up) given the meridian convergence.

    `convergence_deg` is the true azimuth of grid north (clockwise from true north), see
    `dgcal.fields.crs.MapGrid.convergence_deg`; a vector of true azimuth a has grid azimuth a - convergence.
    """
    c = np.asarray(convergence_deg, float)
    return _rotation().from_euler("z", c.reshape(-1, 1), degrees=True).as_matrix().reshape(c.shape + (3, 3))


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix [v]x of a 3-vector (or (N,3) stack)."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    S = np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                  np.stack([v[..., 2], z, -v[..., 0]], -1),
                  np.stack([-v[..., 1], v[..., 0], z], -1)], -2)
    return S
