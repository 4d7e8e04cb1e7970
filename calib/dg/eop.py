"""Direct georeferencing: events -> exposure times -> interpolated POS -> camera pose (block frame L and map CRS).

    t_exposure   = t_event + delay_s
    C_world      = r_imu_world(t_exposure) + R_body_to_world(t_exposure) l_b
    R_cam_to_world    = R_body_to_world(t_exposure) R_cam_to_body
Covariances: POS errors (per image, independent) and mounting errors (common to all images, returned as
the sensitivity G = d pose / d [delay, lever arm, boresight angles] so correlations can be propagated).
Pose errors are [centre (m, L), camera rotation (rad, right perturbation in the camera frame)].
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dgcal.calib.camera.files import load_camera
from dgcal.calib.camera.models import CameraModel
from dgcal.calib.mounting.common import (BlockFrame, MountingResult, PoseAt, numeric_rot_jacobian, pos_covariance_world, pose_at_times, read_mounting_json)
from dgcal.fields.pose import transpose as T
from dgcal.fields.crs import LocalENU, MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import EOP, Events, Trajectory, read_events, read_trajectory
from dgcal.fields.frames import R_cam_to_map_from_opk, skew


@dataclass
class DGPoses:
    """Camera poses from DG in L with per-image POS covariance (M,6,6) and mounting sensitivity G (M,6,7)."""

    image: np.ndarray
    t_exposure: np.ndarray
    C_world: np.ndarray
    R_cam_to_world: np.ndarray
    cov_pos: np.ndarray | None
    G_mount: np.ndarray
    cov_mount: np.ndarray
    pos: PoseAt


def dg_poses(frame: BlockFrame, traj: Trajectory, events: Events, mount: MountingResult,
             images: list[str] | None = None) -> DGPoses:
    """DG camera poses in L of the event images (all, or `images`), with their error model."""
    idx = {str(k): j for j, k in enumerate(events.image)}
    names = [str(k) for k in events.image] if images is None else [str(k) for k in images]
    missing = [k for k in names if k not in idx]
    if missing:
        raise InputError(f"no event for image {missing[0]!r} ({len(missing)} missing)", events.path, field="image")
    rows = np.array([idx[k] for k in names], int)
    t_x = events.t[rows] + mount.delay_s
    if traj.image is not None:
        # events-at-trajectory file: propagate over the delay with the velocity (attitude held)
        tidx = {str(k): j for j, k in enumerate(traj.image)}
        tr = np.array([tidx[k] for k in names], int)
        p, v, R = frame.pos_to_world(traj.lat[tr], traj.lon[tr], traj.h[tr], traj.v_ned[tr], traj.rph[tr])
        p = p + v * (t_x - traj.t[tr])[:, None]
        cov = None if traj.sigma is None else pos_covariance_world(frame, traj.lat[tr], traj.lon[tr], traj.h[tr],
                                                               traj.rph[tr], traj.sigma[tr])
        pos = PoseAt(t_x, p, v, R, np.zeros((len(tr), 3)), cov)
    else:
        pos = pose_at_times(frame, traj, t_x, names)
    l_b, R_cb = mount.lever_arm_m, mount.R_cam_to_body
    R_b = pos.R_body_to_world
    r_cam = pos.r_imu_world + np.einsum("nij,j->ni", R_b, l_b)
    R_cv = R_b @ R_cb
    n = len(rows)
    G = np.zeros((n, 6, 7))
    G[:, :3, 0] = pos.v_world + np.einsum("nij,nj->ni", R_b, np.cross(pos.omega_b, l_b))
    G[:, :3, 1:4] = R_b
    G[:, 3:, 0] = pos.omega_b @ R_cb  # R_cb^T omega_b
    G[:, 3:, 4:7] = R_cb.T
    cov_pos = None
    if pos.cov is not None:
        Gp = np.zeros((n, 6, 6))
        Gp[:, :3, :3] = np.eye(3)
        Gp[:, :3, 3:] = -R_b @ skew(l_b)
        Gp[:, 3:, 3:] = R_cb.T
        cov_pos = Gp @ pos.cov @ T(Gp)
    return DGPoses(np.array(names, dtype=object), t_x, r_cam, R_cv, cov_pos, G, mount.cov, pos)


def pose_cov_to_map(frame: BlockFrame, xyz: np.ndarray, opk: np.ndarray, cov_world: np.ndarray) -> np.ndarray:
    """(N,6,6) covariance of map [X, Y, Z (m), omega, phi, kappa (deg)] from [centre L, camera rotation rad]."""
    Jr = numeric_rot_jacobian(lambda a: frame.R_grid_to_world_at(xyz) @ R_cam_to_map_from_opk(a[:, 0], a[:, 1], a[:, 2]),
                               opk, frame.R_grid_to_world_at(xyz) @ R_cam_to_map_from_opk(opk[:, 0], opk[:, 1], opk[:, 2]),
                               1e-5)
    H = np.zeros((len(xyz), 6, 6))
    H[:, :3, :3] = T(frame.R_grid_to_world_at(xyz))
    H[:, 3:, 3:] = np.linalg.inv(Jr)
    return H @ cov_world @ T(H)


def dg_eop(grid: MapGrid, traj: Trajectory, events: Events, mount: MountingResult,
           images: list[str] | None = None, frame: BlockFrame | None = None) -> tuple[EOP, DGPoses, BlockFrame]:
    """DG exterior orientations in the map CRS (PATB) with sigmas and full covariances (POS + mounting)."""
    if frame is None:
        frame = BlockFrame(grid, _first_local(traj))  # any level frame near the block works
    poses = dg_poses(frame, traj, events, mount, images)
    xyz, opk = frame.world_to_eop(poses.C_world, poses.R_cam_to_world)
    cov_world = np.einsum("nij,jk,nlk->nil", poses.G_mount, poses.cov_mount, poses.G_mount)
    if poses.cov_pos is not None:
        cov_world = cov_world + poses.cov_pos
    cov = pose_cov_to_map(frame, xyz, opk, cov_world)
    sigma = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
    return EOP(poses.image, xyz, opk, sigma, cov), poses, frame


def _first_local(traj: Trajectory) -> LocalENU:
    return LocalENU(float(np.mean(traj.lat)), float(np.mean(traj.lon)), float(np.mean(traj.h)))


@dataclass
class ExportOptions:
    """Inputs of `dgcal export`: a mounting.json, the mapping flight's trajectory and events, the map CRS and
    (for COLMAP) a camera file."""

    mounting: Path
    trajectory: Path
    events: Path
    crs: str
    camera: Path | None = None


@dataclass
class DgFlight:
    """DG EOPs of a flight in the map CRS (PATB, m and deg, with covariances), its grid and camera."""

    eop: EOP
    grid: MapGrid
    camera: CameraModel | None = None


def dg_eop_files(opts: ExportOptions) -> DgFlight:
    """`dgcal export`: DG exterior orientations of every event from the files of `opts` (see `dg_eop`)."""
    camera = load_camera(opts.camera) if opts.camera is not None else None
    mount = read_mounting_json(opts.mounting)
    grid = MapGrid(opts.crs)
    eop, _, _ = dg_eop(grid, read_trajectory(opts.trajectory), read_events(opts.events), mount)
    return DgFlight(eop, grid, camera)
