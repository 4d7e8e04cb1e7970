"""Shared pieces of the mounting calibration: POS and EOPs in the world frame, epoch matching, the rotation
mean and the result record.

POS samples (`PosSamples`) hold a body pose (`dgcal.fields.pose.Poses`, frame "body") with its kinematics; EOPs
are camera poses (`Poses`, frame "cam").

Frames (docs/conventions.md, docs/mounting.md): every position and rotation of an epoch is in the one world
frame of the block (`dgcal.fields.world.World`, a local ENU frame at the block centre), which handles meridian
convergence and earth curvature; body: IMU FRD; camera: x right, y down, z forward.
Rotation errors are right perturbations: `R_obs = R_true Exp(delta)` with `delta` in the rotated frame's source
axes (camera frame for `R_cam_to_world`, body frame for `R_body_to_world`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.formats import EOP, Events, Trajectory
from dgcal.fields.io.text_files import read_text
from dgcal.fields.pose import Poses
from dgcal.fields.world import World
from dgcal.pos.ins.interpolate import interpolate_trajectory

# The share (0-1) of the POS error variance common to every photo of a flight, added to the mounting sigmas (joint,
# iso), in every entry point (`dgcal mount`, `dgcal run`, the Python API): a smoothed MEMS trajectory's attitude
# error is mostly a bias over a flight (the accelerometer bias it cannot tell from tilt), which no number of photos
# averages down; 0 (the seed's independent errors) gave lever-arm z sigmas 4-5x too small (issue 27).
POS_COMMON_FRACTION = 1.0


def rotation_mean(R: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of rotation matrices (N,3,3)."""
    return Rotation.from_matrix(R).mean().as_matrix()


def _eop_map_covariance(eop: EOP, rows: np.ndarray) -> np.ndarray | None:
    """(N,6,6) covariances [position (m), omega, phi, kappa (deg)] of EOP rows: the file's, or diagonal from its
    sigmas; None without either."""
    if eop.cov is not None:
        return eop.cov[rows].copy()
    if eop.sigma is None:
        return None
    C = np.zeros((len(rows), 6, 6))
    C[:, np.arange(6), np.arange(6)] = eop.sigma[rows] ** 2
    return C


# --- POS at exposure/event times ----------------------------------------------------------------
@dataclass
class PosSamples:
    """POS samples at query times in the world: the body pose (`body`, `Poses` of frame "body": IMU position (m),
    R_body_to_world, covariance (N,6,6) [position (m), body-axes rotation error (rad)] or None, the pose rule of
    `dgcal.fields.pose`) and the kinematics: times (s), velocity (m/s, world), body angular rate relative to the
    earth (rad/s, body axes), geodetic lat, lon (deg), h (m) and roll/pitch/heading (deg) when known.
    `r_imu_world`, `R_body_to_world` and `cov` read the body pose."""

    t: np.ndarray
    body: Poses
    v_world: np.ndarray
    omega_b: np.ndarray
    geo: np.ndarray | None = None  # lat, lon, h
    rph: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.body.frame != "body":
            raise ValueError(f"POS samples hold body poses, not {self.body.frame} poses")

    def __len__(self) -> int:
        return len(self.t)

    @property
    def r_imu_world(self) -> np.ndarray:
        """(N,3) IMU positions in the world, m."""
        return self.body.C_world

    @property
    def R_body_to_world(self) -> np.ndarray:
        """(N,3,3) body axes into the world."""
        return self.body.R_body_to_world

    @property
    def cov(self) -> np.ndarray | None:
        """(N,6,6) covariances [position (m), body-axes rotation error (rad)] or None."""
        return self.body.cov

    def subset(self, mask: np.ndarray) -> "PosSamples":
        """The samples where `mask` is true (or at indices `mask`)."""
        return PosSamples(self.t[mask], self.body[mask], self.v_world[mask], self.omega_b[mask],
                          None if self.geo is None else self.geo[mask], None if self.rph is None else self.rph[mask])

    def moved_to(self, t: np.ndarray) -> "PosSamples":
        """The samples carried to times `t` (N,) (s) with their velocity, attitude and covariance held (no geodetic
        position or angles: they would be the old ones)."""
        t = np.asarray(t, float)
        body = Poses(self.body.R_world_to_body, self.r_imu_world + self.v_world * (t - self.t)[:, None],
                     self.body.cov, "body")
        return PosSamples(t, body, self.v_world, self.omega_b)


def _pos_samples(world: World, t, lat, lon, h, v_ned, rph, sigma, omega_b) -> PosSamples:
    r_imu_world, v_world, R_body_to_world = world.pos_to_world(lat, lon, h, v_ned, rph)
    cov = None if sigma is None else world.pos_covariance_to_world(lat, lon, rph, sigma)
    body = Poses.from_body_to_world(R_body_to_world, r_imu_world, cov)
    return PosSamples(np.asarray(t, float), body, v_world, np.asarray(omega_b, float), np.column_stack([lat, lon, h]),
                      np.asarray(rph, float))


def pos_at_times(world: World, traj: Trajectory, t_query: np.ndarray, names: np.ndarray | list | None = None,
                 max_gap_s: float | None = None) -> PosSamples:
    """POS interpolated at GPS times (s) by `dgcal.pos.ins.interpolate` (cubic Hermite position, cubic attitude,
    angular rate, variance-linear sigmas), in the world."""
    st = interpolate_trajectory(traj, np.asarray(t_query, float), names, max_gap_s=max_gap_s)
    # omega_eb_b: body rate relative to the earth in body axes, the rate of R_body_to_world (the world is earth-fixed)
    return _pos_samples(world, st.t, st.lat, st.lon, st.h, st.v_ned, st.rph, st.sigma, st.omega_eb_b)


def pos_at_rows(world: World, traj: Trajectory, rows: np.ndarray) -> PosSamples:
    """POS of trajectory rows (e.g. of an events-at-trajectory file), in the world, without angular rate."""
    return _pos_samples(world, traj.t[rows], traj.lat[rows], traj.lon[rows], traj.h[rows], traj.v_ned[rows],
                        traj.rph[rows], None if traj.sigma is None else traj.sigma[rows], np.zeros((len(rows), 3)))


def pos_at_events(world: World, traj: Trajectory, images: np.ndarray, t_event: np.ndarray) -> PosSamples:
    """POS at event times: interpolated from a trajectory, or read from an events-at-trajectory file by image."""
    if traj.image is None:
        return pos_at_times(world, traj, t_event, images)
    idx = {str(k): j for j, k in enumerate(traj.image)}
    return pos_at_rows(world, traj, np.array([idx[str(im)] for im in images], int))


# --- epochs -------------------------------------------------------------------------------------
@dataclass
class Epochs:
    """Matched calibration epochs in the world: the camera pose from the bundle (`eop`, with the EOP covariance
    [C_world (m), dtheta (rad)] or None) and the POS at the event time (`pos`: its body pose and kinematics)."""

    image: np.ndarray
    t_event: np.ndarray
    eop: Poses
    pos: PosSamples
    has_rate: bool
    warnings: list[str] = field(default_factory=list)
    skipped: dict[str, list[str]] = field(default_factory=dict)
    dt_ref: float = 0.0  # the POS in `pos` is at t_event + dt_ref
    world: World | None = field(default=None, repr=False)
    traj: Trajectory | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.image)

    @property
    def can_resample(self) -> bool:
        """True when the full trajectory is at hand, so the POS can be re-interpolated at t_event + delay."""
        return self.traj is not None and self.traj.image is None and self.world is not None

    def at_delay(self, dt: float) -> "Epochs":
        """The epochs with the POS re-interpolated at t_event + dt (s)."""
        pos = pos_at_times(self.world, self.traj, self.t_event + dt, self.image)
        return Epochs(self.image, self.t_event, self.eop, pos, self.has_rate, list(self.warnings),
                      dict(self.skipped), float(dt), self.world, self.traj)

    def subset(self, mask: np.ndarray) -> "Epochs":
        """Epochs where `mask` is true."""
        return Epochs(self.image[mask], self.t_event[mask], self.eop[mask], self.pos.subset(mask), self.has_rate,
                      list(self.warnings), dict(self.skipped), self.dt_ref, self.world, self.traj)


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


def build_epochs(world: World, eop: EOP, events: Events, traj: Trajectory) -> Epochs:
    """Match EOPs, events and POS by image name and express all of them in the world."""
    r_eop, r_ev, warnings, skipped = match_images(eop, events, traj)
    poses = world.eop_to_poses(eop.xyz[r_eop], eop.opk[r_eop], _eop_map_covariance(eop, r_eop))
    images = eop.image[r_eop]
    pos = pos_at_events(world, traj, images, events.t[r_ev])
    has_rate = traj.image is None
    if not has_rate:
        warnings.append("trajectory has one row per event: no angular rate, attitude is held fixed over the delay")
    return Epochs(images, events.t[r_ev], poses, pos, has_rate, warnings, skipped, 0.0, world, traj)


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
        R_cam_to_body = self.R_cam_to_body
        q = Rotation.from_matrix(R_cam_to_body).as_quat()  # x, y, z, w
        rpy = Rotation.from_matrix(R_cam_to_body).as_euler("ZYX", degrees=True)[::-1]
        corr = self.correlation()
        return {
            "method": self.method,
            **({"method_canonical": self.method_canonical} if self.method_canonical else {}),
            "lever_arm_m": [float(v) for v in self.lever_arm_m],
            "boresight_R_cam_to_body": [[float(v) for v in row] for row in R_cam_to_body],
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
            "boresight_opk_deg": [float(v) for v in Rotation.from_matrix(R_cam_to_body @ np.diag([1.0, -1.0, -1.0]))
                                  .as_euler("XYZ", degrees=True)],
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
        """A result from a `mounting.json` record (missing covariance: from the sigmas); every number checked
        (finite, a lever arm within +-1000 m, a delay within +-1 h, sigmas >= 0, a symmetric covariance with
        a non-negative diagonal, a rotation matrix) with an InputError naming the file and field."""
        if not isinstance(d, dict):
            raise InputError("not a mounting record: expected a JSON object", source)

        def req(key):
            if key not in d:
                raise InputError("not a mounting record: missing", source, field=key)
            return d[key]

        R_cam_to_body = validate.matrix(req("boresight_R_cam_to_body"), (3, 3), source, None, "boresight_R_cam_to_body")
        lever = validate.vector(req("lever_arm_m"), 3, source, None, "lever_arm_m", -validate.MAX_LEVER_ARM_M,
                                validate.MAX_LEVER_ARM_M)
        delay = validate.in_range(d.get("delay_s", 0.0), -validate.MAX_DELAY_S, validate.MAX_DELAY_S, source, None,
                                  "delay_s", "s")
        if "covariance" in d:
            cov = _covariance(d["covariance"], source, "covariance")
        else:
            s = np.r_[validate.non_negative(d.get("delay_sigma_s", 0.0), source, None, "delay_sigma_s",
                                            validate.MAX_DELAY_S),
                      validate.vector(d.get("lever_arm_sigma_m", [0, 0, 0]), 3, source, None, "lever_arm_sigma_m",
                                      0.0, validate.MAX_LEVER_ARM_M),
                      np.radians(validate.vector(d.get("boresight_sigma_deg", [0, 0, 0]), 3, source, None,
                                                 "boresight_sigma_deg", 0.0, 360.0))]
            cov = np.diag(s ** 2)
        if abs(np.linalg.det(R_cam_to_body) - 1) > 1e-3 \
                or np.max(np.abs(R_cam_to_body.T @ R_cam_to_body - np.eye(3))) > 1e-3:
            raise InputError("boresight_R_cam_to_body is not a rotation matrix", source,
                             field="boresight_R_cam_to_body")
        U, _, Vt = np.linalg.svd(R_cam_to_body)
        per_epoch = d.get("per_epoch") if isinstance(d.get("per_epoch"), dict) else {}
        if not isinstance(per_epoch.get("image", []), list):
            raise InputError("must be a list of image names", source, field="per_epoch.image")
        for key, values in per_epoch.items():    # the per-epoch diagnostics: numbers finite and bounded
            for i, x in enumerate(values if isinstance(values, list) and key != "image" else []):
                if isinstance(x, (int, float)) and not isinstance(x, bool) and x == x:   # NaN: an epoch left out
                    validate.in_range(x, -1e12, 1e12, source, None, f"per_epoch.{key}[{i}]")  # GPS s, map m
        extra = {}
        if "pos_common_fraction" in d:
            extra["pos_common_fraction"] = validate.in_range(d["pos_common_fraction"], 0.0, 1.0, source, None,
                                                             "pos_common_fraction")
        if "covariance_random" in d:
            extra["covariance_random"] = _covariance(d["covariance_random"], source, "covariance_random").tolist()
        lists = {}
        for key in ("rejected_epochs", "warnings"):
            v = d.get(key, [])
            if not isinstance(v, list):
                raise InputError("must be a list", source, field=key)
            lists[key] = [str(x) for x in v]
        n_epochs = validate.integer(d.get("n_epochs", 0), 0, 10 ** 9, source, None, "n_epochs")
        return cls(str(d.get("method", "unknown")), lever, U @ Vt, delay, cov, n_epochs,
                   lists["rejected_epochs"], lists["warnings"], per_epoch, extra, str(d.get("method_canonical", "")))

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


def _covariance(value, source, name: str) -> np.ndarray:
    """A 7x7 covariance of a mounting record: finite, |entries| <= 1e12, symmetric, diagonal >= 0."""
    C = validate.matrix(value, (7, 7), source, None, name)
    if np.max(np.abs(C)) > 1e12:
        raise InputError("implausibly large covariance entries (more than 1e12)", source, field=name)
    if np.any(np.diag(C) < 0):
        raise InputError("negative variance on the diagonal", source, field=name)
    if np.max(np.abs(C - C.T)) > 1e-9 * max(1.0, float(np.max(np.abs(C)))):
        raise InputError("the covariance is not symmetric", source, field=name)
    return C


def read_mounting_json(path: str | Path) -> MountingResult:
    """A mounting calibration from a `mounting.json` file (of `dgcal mount`); InputError naming the file (and
    the field: every number is checked, a NaN lever arm never reaches a comparison or a DG check)."""
    text = read_text(path)
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"cannot read mounting file (invalid JSON: {exc.msg})", path, exc.lineno) from None
    except (ValueError, RecursionError) as exc:   # a 5000-digit integer, nesting too deep
        raise InputError(f"cannot read mounting file (invalid JSON: {type(exc).__name__})", path) from None
    return MountingResult.from_json(d, str(path))
