"""Direct georeferencing: events -> exposure times -> interpolated POS -> camera pose (world frame and map CRS).

    t_exposure   = t_event + delay_s
    C_world      = r_imu_world(t_exposure) + R_body_to_world(t_exposure) l_b
    R_cam_to_world    = R_body_to_world(t_exposure) R_cam_to_body
Covariances: POS errors (per image, independent) and mounting errors (common to all images, returned as
the sensitivity G = d pose / d [delay, lever arm, boresight angles] so correlations can be propagated).
Pose errors follow dgcal.fields.pose: [centre (m, world), camera rotation (rad, right perturbation of
R_cam_to_world)].
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from dgcal.calib.camera.files import load_camera
from dgcal.calib.camera.models import CameraModel
from dgcal.calib.mounting.common import MountingResult, PosSamples, pos_at_rows, pos_at_times, read_mounting_json
from dgcal.fields.crs import LocalENU, MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.frames import R_CAM_TO_BODY_NADIR
from dgcal.fields.io.formats import EOP, Events, Trajectory, read_events, read_trajectory
from dgcal.pos.events import read_any_events
from dgcal.pos.ins.sbet import read_any_trajectory
from dgcal.fields.pose import Poses
from dgcal.fields.world import World


@dataclass
class DGPoses:
    """Camera poses from DG in the world (`cam`, its covariance the per-image POS part (M,6,6) or None) and the
    mounting sensitivity G (M,6,7) with the mounting covariance (7,7)."""

    image: np.ndarray
    t_exposure: np.ndarray
    cam: Poses
    G_mount: np.ndarray
    cov_mount: np.ndarray
    pos: PosSamples


def dg_poses(world: World, traj: Trajectory, events: Events, mount: MountingResult,
             images: list[str] | None = None) -> DGPoses:
    """DG camera poses in the world of the event images (all, or `images`), with their error model."""
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
        pos = pos_at_rows(world, traj, np.array([tidx[k] for k in names], int)).moved_to(t_x)
    else:
        pos = pos_at_times(world, traj, t_x, names)
    lever_b, R_cam_to_body = mount.lever_arm_m, mount.R_cam_to_body
    R_body_to_world = pos.R_body_to_world
    n = len(rows)
    G = np.zeros((n, 6, 7))
    G[:, :3, 0] = pos.v_world + np.einsum("nij,nj->ni", R_body_to_world, np.cross(pos.omega_b, lever_b))
    G[:, :3, 1:4] = R_body_to_world
    G[:, 3:, 0] = pos.omega_b @ R_cam_to_body  # R_cam_to_body^T omega_b
    G[:, 3:, 4:7] = R_cam_to_body.T
    cam = pos.body.mounted(lever_b, R_cam_to_body)   # the POS covariance carried to the camera
    return DGPoses(np.array(names, dtype=object), t_x, cam, G, mount.cov, pos)


def dg_eop(grid: MapGrid, traj: Trajectory, events: Events, mount: MountingResult,
           images: list[str] | None = None, world: World | None = None) -> tuple[EOP, DGPoses, World]:
    """DG exterior orientations in the map CRS (PATB, m and deg) with sigmas and full covariances (POS + mounting)."""
    if world is None:
        world = World(grid, _mean_enu(traj))  # any level frame near the block works
    poses = dg_poses(world, traj, events, mount, images)
    cov_world = np.einsum("nij,jk,nlk->nil", poses.G_mount, poses.cov_mount, poses.G_mount)
    if poses.cam.cov is not None:
        cov_world = cov_world + poses.cam.cov
    xyz, opk, cov = world.poses_to_eop(replace(poses.cam, cov=cov_world))
    sigma = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
    return EOP(poses.image, xyz, opk, sigma, cov), poses, world


def _mean_enu(traj: Trajectory) -> LocalENU:
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
    events = read_any_events(opts.events)
    traj = read_any_trajectory(opts.trajectory, near_t=float(events.t[0]) if len(events) else None)
    eop, _, _ = dg_eop(grid, traj, events, mount)
    return DgFlight(eop, grid, camera)


def nominal_mounting(lever_arm_m=(0.0, 0.0, 0.0), R_cam_to_body: np.ndarray = R_CAM_TO_BODY_NADIR,
                     delay_s: float = 0.0) -> MountingResult:
    """A nominal mounting for approximate orientations (no calibration yet): by default a down-looking camera
    with the image top forward at the IMU origin (body FRD), no delay; sigmas 0 (it only starts an adjustment)."""
    return MountingResult("nominal", np.asarray(lever_arm_m, float), np.asarray(R_cam_to_body, float),
                          float(delay_s), np.zeros((7, 7)))


def approx_eop_from_pos(crs: str, trajectory: str | Path, events: str | Path,
                        mounting: str | Path | None = None) -> EOP:
    """Approximate EOPs (map CRS, PATB deg) for POS-assisted aerial triangulation: DG of every event with a
    mounting.json, or `nominal_mounting()` when none is given."""
    mount = read_mounting_json(mounting) if mounting is not None else nominal_mounting()
    eop, _, _ = dg_eop(MapGrid(crs), read_trajectory(trajectory), read_events(events), mount)
    return eop
