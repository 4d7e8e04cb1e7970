"""Shared pieces of the mounting calibration: the one local level frame, POS and EOP conversions into it,
epoch matching, SO(3) helpers and the result record.

Frames (docs/conventions.md, docs/mounting.md):
- `L`: a `LocalENU` frame at the block centre. Every position and rotation of an epoch is expressed in it,
  so meridian convergence (map grid vs true north) and earth curvature (ENU at the point vs ENU at the
  centre) are handled once, here.
- map: the EOP CRS; EOP angles are PATB relative to grid-level axes (grid E, grid N, Up) at the projection centre.
- body: IMU FRD; camera: CV (x right, y down, z forward).
Rotation errors are right perturbations: `R_obs = R_true Exp(delta)` with `delta` in the rotated frame's source
axes (camera frame for `R_cam_to_world`, body frame for `R_body_to_world`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.fields.crs import LocalENU, MapGrid
from dgcal.fields.pose import so3_log
from dgcal.fields.pose import transpose as T
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import EOP, Events, Trajectory
from dgcal.fields.frames import (R_NED_TO_ENU, R_ENU_TO_NED, R_body_to_ned_from_rph, R_cam_to_map_from_opk,
                           opk_from_R_cam_to_map, rph_from_R_body_to_ned)


# --- SO(3): dgcal.fields.pose holds the helpers; the rotation mean is the mounting's own ------------
def rotation_mean(R: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of rotation matrices (N,3,3)."""
    return Rotation.from_matrix(R).mean().as_matrix()


# --- the block frame ---------------------------------------------------------------------------
@dataclass
class BlockFrame:
    """The map grid of the EOPs and the local level frame `L` (ENU at the block centre) the adjustment works in."""

    grid: MapGrid
    local: LocalENU

    @classmethod
    def at_map_points(cls, grid: MapGrid, xyz_map: np.ndarray) -> "BlockFrame":
        """A block frame centred at the mean of map points (m)."""
        return cls(grid, grid.local_frame(np.mean(np.asarray(xyz_map, float).reshape(-1, 3), axis=0)))

    # map <-> L
    def R_grid_to_world_at(self, xyz_map: np.ndarray) -> np.ndarray:
        """Rotation from grid-level axes at map points to L (convergence, then curvature); (N,3,3)."""
        xyz = np.atleast_2d(np.asarray(xyz_map, float))
        geo = self.grid.to_geodetic(xyz)
        # dgcal.fields.frames.R_enu_to_grid takes one angle; build the stack here (R_enu_to_grid = Rz(convergence))
        conv = np.asarray(self.grid.convergence_deg(geo[:, 0], geo[:, 1]), float).reshape(-1, 1)
        R_enu_to_grid = Rotation.from_euler("z", conv, degrees=True).as_matrix().reshape(-1, 3, 3)
        return self.local.R_enu_here_to_local(geo[:, 0], geo[:, 1]) @ T(R_enu_to_grid)

    def map_to_world(self, xyz_map: np.ndarray) -> np.ndarray:
        """L coordinates (m) of map points."""
        return self.local.from_ecef(self.grid.to_ecef(np.atleast_2d(np.asarray(xyz_map, float))))

    def world_to_map(self, p_world: np.ndarray) -> np.ndarray:
        """Map coordinates of L points (m)."""
        return self.grid.from_ecef(self.local.to_ecef(np.atleast_2d(np.asarray(p_world, float))))

    def eop_to_world(self, xyz_map: np.ndarray, opk_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Projection centres in L (N,3) and `R_cam_to_world` (N,3,3) from map EOPs (PATB degrees)."""
        xyz = np.atleast_2d(np.asarray(xyz_map, float))
        opk = np.atleast_2d(np.asarray(opk_deg, float))
        R_cam_to_grid = R_cam_to_map_from_opk(opk[:, 0], opk[:, 1], opk[:, 2])
        return self.map_to_world(xyz), self.R_grid_to_world_at(xyz) @ R_cam_to_grid

    def world_to_eop(self, p_world: np.ndarray, R_cam_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map projection centres (N,3) and PATB omega/phi/kappa (N,3) degrees from L poses."""
        xyz = self.world_to_map(p_world)
        R_cam_to_grid = T(self.R_grid_to_world_at(xyz)) @ np.asarray(R_cam_to_world, float).reshape(-1, 3, 3)
        return xyz, opk_from_R_cam_to_map(R_cam_to_grid)

    # geodetic POS <-> L
    def pos_to_world(self, lat, lon, h, v_ned, rph) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """IMU position in L (N,3), velocity in L (N,3) and `R_body_to_world` (N,3,3) from geodetic POS samples."""
        lat, lon, h = (np.atleast_1d(np.asarray(a, float)) for a in (lat, lon, h))
        R_here_to_world = self.local.R_enu_here_to_local(lat, lon).reshape(-1, 3, 3)
        rph = np.atleast_2d(np.asarray(rph, float))
        R_body_to_ned = R_body_to_ned_from_rph(rph[:, 0], rph[:, 1], rph[:, 2]).reshape(-1, 3, 3)
        R_body_to_world = R_here_to_world @ R_NED_TO_ENU @ R_body_to_ned
        v_world = np.einsum("nij,nj->ni", R_here_to_world, np.atleast_2d(np.asarray(v_ned, float)) @ R_NED_TO_ENU.T)
        return self.local.from_geodetic(lat, lon, h).reshape(-1, 3), v_world, R_body_to_world

    def world_to_pos(self, p_world, v_world, R_body_to_world) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """lat, lon (deg), h (m), v_ned (N,3), rph (N,3) deg from L samples (inverse of `pos_to_world`)."""
        geo = self.local.to_geodetic(np.atleast_2d(np.asarray(p_world, float)))
        R_world_to_here = T(self.local.R_enu_here_to_local(geo[:, 0], geo[:, 1]).reshape(-1, 3, 3))
        R_body_to_ned = R_ENU_TO_NED @ R_world_to_here @ np.asarray(R_body_to_world, float).reshape(-1, 3, 3)
        v_ned = np.einsum("nij,nj->ni", R_world_to_here, np.atleast_2d(np.asarray(v_world, float))) @ R_ENU_TO_NED.T
        return geo[:, 0], geo[:, 1], geo[:, 2], v_ned, rph_from_R_body_to_ned(R_body_to_ned)


def numeric_rot_jacobian(fun, x0: np.ndarray, R0: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """d delta / d x (N,3,k) where fun(x) -> (N,3,3) and delta = Log(R0^T fun(x)) (right perturbation)."""
    n, k = x0.shape
    J = np.empty((n, 3, k))
    for j in range(k):
        d = np.zeros(k)
        d[j] = step
        J[:, :, j] = (so3_log(T(R0) @ fun(x0 + d)) - so3_log(T(R0) @ fun(x0 - d))) / (2 * step)
    return J


def eop_covariance_world(frame: BlockFrame, eop: EOP, rows: np.ndarray) -> np.ndarray | None:
    """(N,6,6) covariance of [position in L (m), camera-frame rotation error (rad)] of EOP rows, or None."""
    if eop.cov is None and eop.sigma is None:
        return None
    xyz, opk = eop.xyz[rows], eop.opk[rows]
    if eop.cov is not None:
        C_map = eop.cov[rows].copy()
    else:
        C_map = np.zeros((len(rows), 6, 6))
        C_map[:, np.arange(6), np.arange(6)] = eop.sigma[rows] ** 2
    _, R0 = frame.eop_to_world(xyz, opk)
    # d(rotation error, rad)/d(omega, phi, kappa, deg): the angle covariance is in deg^2
    Jr = numeric_rot_jacobian(lambda a: frame.eop_to_world(xyz, a)[1], opk, R0, 1e-5)
    G = np.zeros((len(rows), 6, 6))
    G[:, :3, :3] = frame.R_grid_to_world_at(xyz)
    G[:, 3:, 3:] = Jr
    return G @ C_map @ T(G)


def pos_covariance_world(frame: BlockFrame, lat, lon, h, rph, sigma: np.ndarray) -> np.ndarray:
    """(N,6,6) covariance of [IMU position in L (m), body-frame rotation error (rad)] from POS sigmas.

    `sigma` (N,6): s_lat_m (north), s_lon_m (east), s_h_m (m), s_roll, s_pitch, s_heading (deg)."""
    lat, lon, h = (np.atleast_1d(np.asarray(a, float)) for a in (lat, lon, h))
    rph = np.atleast_2d(np.asarray(rph, float))
    R_here_to_world = frame.local.R_enu_here_to_local(lat, lon).reshape(-1, 3, 3)
    C = np.zeros((len(lat), 6, 6))
    C_enu = np.zeros((len(lat), 3, 3))
    C_enu[:, 0, 0], C_enu[:, 1, 1], C_enu[:, 2, 2] = sigma[:, 1] ** 2, sigma[:, 0] ** 2, sigma[:, 2] ** 2
    C[:, :3, :3] = R_here_to_world @ C_enu @ T(R_here_to_world)

    def R_of(a):
        return R_body_to_ned_from_rph(a[:, 0], a[:, 1], a[:, 2]).reshape(-1, 3, 3)

    Jr = numeric_rot_jacobian(R_of, rph, R_of(rph), 1e-5)  # rad per degree
    C_rph = np.zeros((len(lat), 3, 3))
    C_rph[:, np.arange(3), np.arange(3)] = sigma[:, 3:] ** 2
    C[:, 3:, 3:] = Jr @ C_rph @ T(Jr)
    return C


# --- POS at exposure/event times ----------------------------------------------------------------
@dataclass
class PoseAt:
    """POS state at query times in L: IMU position, velocity, body-to-L rotation, body angular rate (rad/s),
    covariance (N,6,6) of [position, body rotation error] or None."""

    t: np.ndarray
    r_imu_world: np.ndarray
    v_world: np.ndarray
    R_body_to_world: np.ndarray
    omega_b: np.ndarray
    cov: np.ndarray | None = None
    geo: np.ndarray | None = None  # lat, lon, h
    rph: np.ndarray | None = None


def pose_at_times(frame: BlockFrame, traj: Trajectory, t_query: np.ndarray, names=None,
                  max_gap_s: float | None = None) -> PoseAt:
    """POS interpolated at GPS times (s) by `dgcal.pos.ins.interpolate` (cubic Hermite position, cubic attitude, angular
    rate, variance-linear sigmas), expressed in L."""
    from dgcal.pos.ins.interpolate import interpolate_trajectory
    st = interpolate_trajectory(traj, np.asarray(t_query, float), names, max_gap_s=max_gap_s)
    r, v, R = frame.pos_to_world(st.lat, st.lon, st.h, st.v_ned, st.rph)
    cov = None if st.sigma is None else pos_covariance_world(frame, st.lat, st.lon, st.h, st.rph, st.sigma)
    # omega_eb_b: body rate relative to the earth in body axes, the rate of R_body_to_world (L is earth-fixed)
    return PoseAt(st.t, r, v, R, np.asarray(st.omega_eb_b, float), cov, np.column_stack([st.lat, st.lon, st.h]),
                  st.rph)


def pose_at_events(frame: BlockFrame, traj: Trajectory, images: np.ndarray, t_event: np.ndarray) -> PoseAt:
    """POS at event times: interpolated from a trajectory, or read from an events-at-trajectory file by image."""
    if traj.image is None:
        return pose_at_times(frame, traj, t_event, images)
    idx = {str(k): j for j, k in enumerate(traj.image)}
    rows = np.array([idx[str(im)] for im in images], int)
    p_world, v_world, R_bL = frame.pos_to_world(traj.lat[rows], traj.lon[rows], traj.h[rows], traj.v_ned[rows], traj.rph[rows])
    cov = None
    if traj.sigma is not None:
        cov = pos_covariance_world(frame, traj.lat[rows], traj.lon[rows], traj.h[rows], traj.rph[rows], traj.sigma[rows])
    geo = np.column_stack([traj.lat[rows], traj.lon[rows], traj.h[rows]])
    return PoseAt(traj.t[rows], p_world, v_world, R_bL, np.zeros((len(rows), 3)), cov, geo, traj.rph[rows])


# --- epochs -------------------------------------------------------------------------------------
@dataclass
class Epochs:
    """Matched calibration epochs in L: camera pose from the bundle and POS at the event time."""

    image: np.ndarray
    t_event: np.ndarray
    C_world: np.ndarray
    R_cam_to_world: np.ndarray
    cov_eop: np.ndarray | None
    pos: PoseAt
    has_rate: bool
    warnings: list[str] = field(default_factory=list)
    skipped: dict[str, list[str]] = field(default_factory=dict)
    dt_ref: float = 0.0  # the POS in `pos` is at t_event + dt_ref
    frame: BlockFrame | None = field(default=None, repr=False)
    traj: Trajectory | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.image)

    @property
    def can_resample(self) -> bool:
        """True when the full trajectory is at hand, so the POS can be re-interpolated at t_event + delay."""
        return self.traj is not None and self.traj.image is None and self.frame is not None

    def at_delay(self, dt: float) -> "Epochs":
        """The epochs with the POS re-interpolated at t_event + dt (s)."""
        pos = pose_at_times(self.frame, self.traj, self.t_event + dt, self.image)
        return Epochs(self.image, self.t_event, self.C_world, self.R_cam_to_world, self.cov_eop, pos, self.has_rate,
                      list(self.warnings), dict(self.skipped), float(dt), self.frame, self.traj)

    def subset(self, mask: np.ndarray) -> "Epochs":
        """Epochs where `mask` is true."""
        p = self.pos
        pos = PoseAt(p.t[mask], p.r_imu_world[mask], p.v_world[mask], p.R_body_to_world[mask], p.omega_b[mask],
                     None if p.cov is None else p.cov[mask], None if p.geo is None else p.geo[mask],
                     None if p.rph is None else p.rph[mask])
        return Epochs(self.image[mask], self.t_event[mask], self.C_world[mask], self.R_cam_to_world[mask],
                      None if self.cov_eop is None else self.cov_eop[mask], pos, self.has_rate,
                      list(self.warnings), dict(self.skipped), self.dt_ref, self.frame, self.traj)


def match_images(eop: EOP, events: Events, traj: Trajectory) -> tuple[np.ndarray, np.ndarray, list[str], dict]:
    """Rows of EOP and events for images present in both (and in an events-at-trajectory file);
    warnings and the skipped image names per reason."""
    ev_idx = {str(k): j for j, k in enumerate(events.image)}
    eop_idx = {str(k): j for j, k in enumerate(eop.image)}
    traj_names = None if traj.image is None else {str(k) for k in traj.image}
    skipped = {"no_event": sorted(set(eop_idx) - set(ev_idx)), "no_eop": sorted(set(ev_idx) - set(eop_idx)),
               "not_in_trajectory": []}
    common = [k for k in (str(x) for x in eop.image) if k in ev_idx]
    if traj_names is not None:
        skipped["not_in_trajectory"] = [k for k in common if k not in traj_names]
        common = [k for k in common if k in traj_names]
    else:
        t0, t1 = traj.t[0], traj.t[-1]
        outside = [k for k in common if not (t0 <= events.t[ev_idx[k]] <= t1)]
        skipped["not_in_trajectory"] = outside
        common = [k for k in common if k not in set(outside)]
    warnings = []
    for reason, what in (("no_event", "EOP images without an event"), ("no_eop", "events without an EOP"),
                         ("not_in_trajectory", "images outside the trajectory")):
        if skipped[reason]:
            names = skipped[reason]
            warnings.append(f"{len(names)} {what} skipped: {', '.join(names[:10])}{' ...' if len(names) > 10 else ''}")
    if not common:
        raise InputError("no image is in both the EOP file and the events file", eop.path, field="image")
    return (np.array([eop_idx[k] for k in common], int), np.array([ev_idx[k] for k in common], int),
            warnings, skipped)


def build_epochs(frame: BlockFrame, eop: EOP, events: Events, traj: Trajectory) -> Epochs:
    """Match EOPs, events and POS by image name and express all of them in the block frame L."""
    r_eop, r_ev, warnings, skipped = match_images(eop, events, traj)
    C_world, R_cam_to_world = frame.eop_to_world(eop.xyz[r_eop], eop.opk[r_eop])
    images = eop.image[r_eop]
    pos = pose_at_events(frame, traj, images, events.t[r_ev])
    has_rate = traj.image is None
    if not has_rate:
        warnings.append("trajectory has one row per event: no angular rate, attitude is held fixed over the delay")
    return Epochs(images, events.t[r_ev], C_world, R_cam_to_world, eop_covariance_world(frame, eop, r_eop), pos,
                  has_rate, warnings, skipped, 0.0, frame, traj)


# --- result ------------------------------------------------------------------------------------
@dataclass
class MountingResult:
    """Lever arm (body, m), boresight `R_cam_to_body`, delay (s) with covariance of [dt, l(3), theta_b(3) rad]."""

    method: str
    lever_arm_m: np.ndarray
    R_cam_to_body: np.ndarray
    delay_s: float
    cov: np.ndarray  # 7x7: delay s, lever arm m, boresight small angles about body x,y,z (rad)
    n_epochs: int = 0
    rejected: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    per_epoch: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    method_canonical: str = ""  # the registry name of `method` (dgcal.calib.mounting.methods), when known

    PARAM_NAMES = ("delay", "lever_x", "lever_y", "lever_z", "boresight_x", "boresight_y", "boresight_z")

    @property
    def sigmas(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))

    def correlation(self) -> np.ndarray:
        """Correlation matrix of the 7 parameters (NaN where a parameter is fixed)."""
        s = self.sigmas
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.cov / np.outer(s, s)

    def to_json(self) -> dict:
        """The `mounting.json` record of INTERFACES.md plus extras."""
        s = self.sigmas
        R = self.R_cam_to_body
        q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
        rpy = Rotation.from_matrix(R).as_euler("ZYX", degrees=True)[::-1]
        corr = self.correlation()
        return {
            "method": self.method,
            **({"method_canonical": self.method_canonical} if self.method_canonical else {}),
            "lever_arm_m": [float(v) for v in self.lever_arm_m],
            "boresight_R_cam_to_body": [[float(v) for v in row] for row in R],
            "delay_s": float(self.delay_s),
            "lever_arm_sigma_m": [float(v) for v in s[1:4]],
            "boresight_sigma_deg": [float(np.degrees(v)) for v in s[4:7]],
            "delay_sigma_s": float(s[0]),
            "boresight_sigma_axes": "small rotations about body x, y, z: R_cam_to_body = Exp(theta_b) R_hat",
            "boresight_rpy_deg": [float(v) for v in rpy],
            "boresight_rpy_convention": "R_cam_to_body = Rz(yaw) Ry(pitch) Rx(roll)",
            "boresight_quaternion_wxyz": [float(q[3]), float(q[0]), float(q[1]), float(q[2])],
            # seed Table 1 style: PATB-like angles of the photo frame in the body frame, R_photo_to_body =
            # R_cam_to_body diag(1,-1,-1) = Rx(omega) Ry(phi) Rz(kappa)
            "boresight_opk_deg": [float(v) for v in
                                  Rotation.from_matrix(R @ np.diag([1.0, -1.0, -1.0])).as_euler("XYZ", degrees=True)],
            "parameters": list(self.PARAM_NAMES),
            "covariance": [[float(v) for v in row] for row in self.cov],
            "covariance_units": "s, m, m, m, rad, rad, rad",
            "correlation": [[None if not np.isfinite(v) else float(v) for v in row] for row in corr],
            "n_epochs": int(self.n_epochs),
            "rejected_epochs": list(self.rejected),
            "warnings": list(self.warnings),
            "per_epoch": self.per_epoch,
            **self.extra,
        }

    @classmethod
    def from_json(cls, d: dict, source: str | None = None) -> "MountingResult":
        """A result from a `mounting.json` record (missing covariance: from the sigmas)."""
        try:
            R = np.array(d["boresight_R_cam_to_body"], float).reshape(3, 3)
            lever = np.array(d["lever_arm_m"], float).reshape(3)
            delay = float(d.get("delay_s", 0.0))
            if "covariance" in d:
                cov = np.array(d["covariance"], float).reshape(7, 7)
            else:
                s = np.r_[d.get("delay_sigma_s", 0.0), d.get("lever_arm_sigma_m", [0, 0, 0]),
                          np.radians(d.get("boresight_sigma_deg", [0, 0, 0]))]
                cov = np.diag(np.asarray(s, float) ** 2)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"not a mounting record: {exc}", source) from None
        if abs(np.linalg.det(R) - 1) > 1e-3 or np.max(np.abs(R.T @ R - np.eye(3))) > 1e-3:
            raise InputError("boresight_R_cam_to_body is not a rotation matrix", source, field="boresight_R_cam_to_body")
        U, _, Vt = np.linalg.svd(R)
        per_epoch = d.get("per_epoch") if isinstance(d.get("per_epoch"), dict) else {}
        extra = {k: d[k] for k in ("pos_common_fraction", "covariance_random") if k in d}
        return cls(str(d.get("method", "unknown")), lever, U @ Vt, delay, cov, int(d.get("n_epochs", 0)),
                   list(d.get("rejected_epochs", [])), list(d.get("warnings", [])), per_epoch, extra,
                   str(d.get("method_canonical", "")))

    def covariance_for_flight(self, images) -> np.ndarray:
        """Mounting covariance to use for DG of `images`.

        The POS error common to the calibration flight is in the mounting covariance (see
        `pos_common_fraction`) and in every image's POS covariance. On the calibration flight itself it
        is counted once, through the per-image POS covariance (the mounting's random part only; a
        slight overestimate, since the mounting absorbed that error); on any other flight both count.
        """
        f = float(self.extra.get("pos_common_fraction", 0.0))
        cal_images = set(map(str, self.per_epoch.get("image", [])))
        if f > 0 and "covariance_random" in self.extra and cal_images and set(map(str, images)) <= cal_images:
            return np.array(self.extra["covariance_random"], float).reshape(7, 7)
        return self.cov


def read_mounting_json(path: str | Path) -> MountingResult:
    """A mounting calibration from a `mounting.json` file (of `dgcal mount`); InputError naming the file."""
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read mounting file ({exc})", path) from None
    return MountingResult.from_json(d, str(path))
