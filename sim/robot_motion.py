"""A slow ground robot as a ROS log sees it: a consumer MEMS IMU at 30 Hz and NavSatFix fixes at 2.5 Hz (issue 27).

The motion (`robot_path`) is what a field or campus robot does: it stands still at the start, then drives legs of
0.3-1.5 m/s with gentle accelerations (0.3-0.8 m/s^2), some bending into gentle arcs (5-15 deg/s), stops for a few
seconds, and turns in place (45-180 deg at 20-45 deg/s) between legs. It stays level (body FRD z along the tangent
frame's down: flat ground). The profiles are smooth steps (`dgcal.sim.trajectory.SmoothSteps`) of speed and heading
rate, so the kinematics, the specific force and the angular rate are exact (J2 gravity, earth rate, Coriolis) and
the IMU increments their integrals (`dgcal.sim.trajectory.assemble_trajectory`); the IMU errors are those of a grade
(`dgcal.sim.imu.simulate_imu`, consumer by default).

The GNSS antenna (`lever_arm_b` from the IMU, body FRD m) is fixed at 2.5 Hz by a consumer receiver: first-order
Gauss-Markov position errors (metres, `tau_s` 60 s) plus a little white noise; each fix states its covariance as
such a receiver does (`position_covariance` diagonal in ENU, the error's per-axis sigma: hAcc^2, hAcc^2, vAcc^2).

`write_robot_dataset` writes it all as one ROS 1 or ROS 2 bag (`sensor_msgs/Imu` on /imu/data, FLU,
`sensor_msgs/NavSatFix` on /gps/fix) with truth.csv and truth.json (the `dgcal pos --mode lc` command), the path a
user takes with a real robot log.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dgcal.fields.crs import geodetic_to_ecef
from dgcal.fields.frames import R_ecef_to_ned
from dgcal.fields.io.csv_tables import atomic_write, staged_dir
from dgcal.fields.io.formats import write_trajectory
from dgcal.pos.gnss.solution_files import GnssSolution
from dgcal.pos.ins.imu_data import ImuData
from dgcal.pos.ros_bags import write_rosbag
from dgcal.sim.gnss import DEFAULT_T0_GPS
from dgcal.sim.imu import ImuErrorRealisation, simulate_imu
from dgcal.sim.trajectory import FlightProfile, Segment, SmoothSteps, TrueTrajectory, assemble_trajectory

NO_STEPS = ([1e9], [1.0], [0.0])     # a SmoothSteps that never acts


@dataclass
class RobotProfile(FlightProfile):
    """A level ground robot: speed `speed_steps` (m/s) along the heading, heading rate `turn` (rad/s), body FRD
    z down the tangent frame's vertical (flat ground), so it can turn in place."""

    speed_steps: SmoothSteps | None = None

    def controls(self, t: np.ndarray) -> dict:
        """Heading, rates, speed and accelerations (tangent frame l, NED) at sorted GPS times t."""
        tau = np.asarray(t, float) - self.t0
        psi_i, r, rdot, _ = self.turn.evaluate(tau)
        _, s, sd, sdd = self.speed_steps.evaluate(tau)
        psi = self.heading0 + psi_i
        z = np.zeros_like(psi)
        u = np.stack([np.cos(psi), np.sin(psi), z], -1)      # along the heading
        w = np.stack([-np.sin(psi), np.cos(psi), z], -1)     # to its right
        v_l = s[..., None] * u
        a_l = sd[..., None] * u + (s * r)[..., None] * w
        j_l = (sdd - s * r * r)[..., None] * u + (2 * sd * r + s * rdot)[..., None] * w
        return dict(psi=psi, r=r, rdot=rdot, height=z, vup=z, vupdot=z, v_l=v_l, a_l=a_l, j_l=j_l, speed=s)

    def attitude(self, c: dict) -> tuple[np.ndarray, np.ndarray]:
        """R_body_to_l (N,3,3) a rotation about down by the heading, omega_lb_b (N,3) rad/s the heading rate."""
        cp, sp = np.cos(c["psi"]), np.sin(c["psi"])
        R = np.zeros(cp.shape + (3, 3))
        R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = cp, -sp, sp, cp, 1.0
        z = np.zeros_like(cp)
        return R, np.stack([z, z, c["r"]], -1)


@dataclass
class _Plan:
    """Smooth steps of speed and heading rate (t from the start, s) and the named segments."""

    speed: list = field(default_factory=list)      # (start s, ramp s, delta m/s)
    turn: list = field(default_factory=list)       # (start s, ramp s, delta rad/s)
    segments: list = field(default_factory=list)   # (kind, start s, end s)
    t: float = 0.0

    def stand(self, seconds: float, kind: str = "stop") -> None:
        self.segments.append((kind, self.t, self.t + seconds))
        self.t += seconds

    def rate_pulse(self, t_start: float, angle: float, rate: float, ramp: float) -> float:
        """Heading rate up to `rate` (rad/s, sign of `angle`) and back, turning by `angle` rad; its end (s)."""
        hold = max(abs(angle) / rate - ramp, 0.0)
        r = np.sign(angle) * abs(angle) / (hold + ramp)
        self.turn += [(t_start, ramp, r), (t_start + ramp + hold, ramp, -r)]
        return t_start + 2 * ramp + hold

    def drive(self, speed: float, accel: float, hold: float, arc: tuple[float, float] | None) -> None:
        """Accelerate to `speed` (peak `accel` m/s^2), hold it `hold` s (bending by arc = (angle, rate) rad, rad/s
        in the middle), brake to a stop."""
        ramp = 1.875 * speed / accel                   # the smooth step's peak slope is 1.875 delta / T
        t0 = self.t
        self.speed += [(t0, ramp, speed), (t0 + ramp + hold, ramp, -speed)]
        kind = "drive"
        if arc is not None:
            angle, rate = arc
            need = abs(angle) / rate + 1.0
            if need < hold:
                self.rate_pulse(t0 + ramp + 0.5 * (hold - need), angle, rate, 1.0)
                kind = "arc"
        self.t = t0 + 2 * ramp + hold
        self.segments.append((kind, t0, self.t))

    def turn_in_place(self, angle: float, rate: float) -> None:
        t0 = self.t
        self.t = self.rate_pulse(t0, angle, rate, 0.7)
        self.segments.append(("turn", t0, self.t))


def _plan(rng: np.random.Generator, duration_s: float, speed_mps: tuple[float, float], static_s: float) -> _Plan:
    pl = _Plan()
    pl.stand(static_s, "static")
    while pl.t < duration_s - 5.0:
        u = rng.uniform()
        if u < 0.55:
            arc = None
            if rng.uniform() < 0.5:
                arc = (np.radians(rng.uniform(20.0, 90.0)) * rng.choice([-1.0, 1.0]), np.radians(rng.uniform(5, 15)))
            pl.drive(rng.uniform(*speed_mps), rng.uniform(0.3, 0.8), rng.uniform(8.0, 40.0), arc)
        elif u < 0.8:
            pl.turn_in_place(np.radians(rng.uniform(45.0, 180.0)) * rng.choice([-1.0, 1.0]),
                             np.radians(rng.uniform(20.0, 45.0)))
        else:
            pl.stand(rng.uniform(3.0, 15.0))
    pl.stand(max(duration_s - pl.t, 0.0) + 2.0)
    return pl


def _steps(terms: list) -> SmoothSteps:
    if not terms:
        return SmoothSteps(*NO_STEPS)
    a, T, d = zip(*terms)
    return SmoothSteps(a, T, d)


def robot_path(t0_gps: float, duration_s: float = 420.0, rate_hz: float = 30.0, seed: int = 0,
               lat0: float = 35.34, lon0: float = 139.52, h0: float = 45.0,
               speed_mps: tuple[float, float] = (0.3, 1.5), static_s: float = 20.0) -> TrueTrajectory:
    """The true motion of a slow ground robot (module doc) from `t0_gps` for `duration_s` at the IMU rate `rate_hz`:
    state, specific force, angular rate and exact increments (body FRD; `segments`: static, drive, arc, turn, stop)."""
    rng = np.random.default_rng(seed)
    pl = _plan(rng, duration_s, speed_mps, static_s)
    prof = RobotProfile(lat0, lon0, h0, float(t0_gps), np.zeros(3), 0.0, rng.uniform(0.0, 2 * np.pi),
                        _steps(pl.turn), SmoothSteps(*NO_STEPS), speed_steps=_steps(pl.speed))
    n = int(np.floor(duration_s * rate_hz + 1e-9)) + 1
    t = float(t0_gps) + np.arange(n) / rate_hz
    inc = prof.horizontal_increment(t[:-1], t[1:])
    p_l = np.zeros((n, 3))
    p_l[:, :2] = np.vstack([np.zeros(2), np.cumsum(inc, axis=0)])
    truth = assemble_trajectory(prof, t, p_l, with_increments=True, rate_hz=rate_hz)
    truth.segments = [Segment(k, a + t0_gps, min(b, duration_s) + t0_gps) for k, a, b in pl.segments if a < duration_s]
    return truth


def navsatfix_errors(n: int, dt: float, rng: np.random.Generator, sigma_h_m: float, sigma_v_m: float, tau_s: float,
                     white_m: float) -> np.ndarray:
    """(n,3) NED errors (m) of a consumer receiver's fixes every `dt` s: first-order Gauss-Markov (per horizontal
    axis sigma_h_m, vertical sigma_v_m, correlation time tau_s) plus white noise of white_m."""
    phi = np.exp(-dt / tau_s)
    sig = np.array([sigma_h_m, sigma_h_m, sigma_v_m])
    w = rng.standard_normal((n, 3)) * sig * np.sqrt(1.0 - phi ** 2)
    w[0] = rng.standard_normal(3) * sig
    e = np.empty((n, 3))
    e[0] = w[0]
    for k in range(1, n):
        e[k] = phi * e[k - 1] + w[k]
    return e + rng.standard_normal((n, 3)) * white_m


@dataclass
class RobotSimulation:
    """A simulated robot log: truth (IMU origin, body FRD), the IMU, its true errors, the fixes (antenna, GPS s,
    stated NED covariance, RTKLIB Q 5 = single) with their true NED errors, the lever arm and the settings."""

    truth: TrueTrajectory
    imu: ImuData
    imu_errors: ImuErrorRealisation
    fixes: GnssSolution
    fix_error_ned: np.ndarray
    lever_arm_b: np.ndarray
    settings: dict


def simulate_robot(seed: int = 0, duration_s: float = 420.0, imu_rate_hz: float = 30.0, gnss_hz: float = 2.5,
                   grade: str = "consumer", lever_arm_b=(0.10, 0.0, -0.35), sigma_h_m: float = 1.2,
                   sigma_v_m: float = 2.0, tau_s: float = 60.0, white_m: float = 0.15,
                   speed_mps: tuple[float, float] = (0.3, 1.5), static_s: float = 20.0,
                   t0_gps: float | None = None) -> RobotSimulation:
    """A slow ground robot (`robot_path`) with a `grade` IMU at `imu_rate_hz` and NavSatFix-like fixes at `gnss_hz`
    (`navsatfix_errors`); the site near 35.3 N 139.5 E moves with the seed."""
    rng = np.random.default_rng(seed + 1000)
    lat0, lon0 = 35.3 + rng.uniform(-0.05, 0.05), 139.5 + rng.uniform(-0.05, 0.05)
    t0 = float(DEFAULT_T0_GPS if t0_gps is None else t0_gps)
    truth = robot_path(t0, duration_s, imu_rate_hz, seed, lat0, lon0, 45.0, speed_mps, static_s)
    imu, err = simulate_imu(truth, grade, seed=seed + 1)
    step = int(round(imu_rate_hz / gnss_hz))
    if abs(step * gnss_hz - imu_rate_hz) > 1e-9:
        raise ValueError(f"the IMU rate {imu_rate_hz:g} Hz is not a multiple of the GNSS rate {gnss_hz:g} Hz")
    idx = np.arange(0, len(truth.t), step)
    lever = np.asarray(lever_arm_b, float)
    p_ant = truth.p_ecef[idx] + truth.R_body_to_ecef[idx] @ lever
    e = navsatfix_errors(len(idx), step / imu_rate_hz, rng, sigma_h_m, sigma_v_m, tau_s, white_m)
    R_ned_to_ecef = np.swapaxes(R_ecef_to_ned(truth.lat[idx], truth.lon[idx]), 1, 2)
    p = p_ant + np.einsum("nij,nj->ni", R_ned_to_ecef, e)
    s = np.hypot([sigma_h_m, sigma_h_m, sigma_v_m], white_m)
    cov = np.tile(np.diag(s ** 2), (len(idx), 1, 1))
    fixes = GnssSolution(truth.t[idx].copy(), p, cov, np.full(len(idx), 5), np.zeros(len(idx), int))
    speed = np.linalg.norm(truth.v_ned[:, :2], axis=1)
    kinds = [sg.kind for sg in truth.segments]
    settings = {"kind": "robot", "seed": seed, "duration_s": duration_s, "imu_rate_hz": imu_rate_hz,
                "gnss_hz": gnss_hz, "grade": err.grade.name, "lever_arm_b_m": lever.tolist(),
                "lat0": lat0, "lon0": lon0, "gnss_errors": {"sigma_h_m": sigma_h_m, "sigma_v_m": sigma_v_m,
                                                            "tau_s": tau_s, "white_m": white_m},
                "speed_mps": {"max": round(float(speed.max()), 3), "mean": round(float(speed.mean()), 3)},
                "segments": {k: kinds.count(k) for k in dict.fromkeys(kinds)},
                "gyro_bias_mean_deg_h": (np.degrees(err.gyro_bias.mean(0)) * 3600.0).round(1).tolist()}
    return RobotSimulation(truth, imu, err, fixes, e, lever, settings)


def write_robot_dataset(out, sim: RobotSimulation, ros_version: int = 2) -> dict:
    """Write robot.bag (ROS 1) or the robot_bag/ folder (ROS 2) with /imu/data and /gps/fix, truth.csv (the IMU's
    true trajectory at 10 Hz, dgcal trajectory CSV) and truth.json (settings, IMU errors, the `dgcal pos` command)
    into `out`, all or nothing; returns the truth dict."""
    bag = "robot.bag" if ros_version == 1 else "robot_bag"
    lever = " ".join(f"{x:g}" for x in sim.lever_arm_b)
    info = {**sim.settings, "imu_errors": sim.imu_errors.as_dict(),
            "files": {"bag": bag, "truth": "truth.csv", "imu_topic": "/imu/data", "fix_topic": "/gps/fix"},
            "segments_s": [{"kind": s.kind, "t_start": s.t_start, "t_end": s.t_end} for s in sim.truth.segments],
            "command_lc": (f"dgcal pos --mode lc --imu {bag} --gnss {bag} --gnss-format rosbag --imu-grade "
                           f"{sim.settings['grade']} --lever-arm {lever} --out OUT")}
    step = max(1, int(round(sim.truth.rate_hz / 10.0)))
    with staged_dir(out) as d:
        d = Path(d)
        write_rosbag(d / bag, sim.imu, sim.fixes, version=ros_version)
        write_trajectory(d / "truth.csv", sim.truth.as_trajectory(step))
        with atomic_write(d / "truth.json") as fh:
            json.dump(info, fh, indent=1, default=float)
    return info


def trajectory_honesty(truth: TrueTrajectory, traj, skip_s: float = 0.0) -> dict:
    """Errors of a dgcal trajectory (`dgcal.fields.io.formats.Trajectory` of the IMU origin, with sigmas) against
    the truth at its epochs after `skip_s` s: per axis N, E, D (m) and roll, pitch, heading (deg) the error RMS, the
    median sigma, error/sigma RMS and its largest |value|; angle errors wrapped to +-180 deg."""
    t = np.asarray(traj.t, float)
    keep = (t >= truth.t[0] + skip_s) & (t <= truth.t[-1])
    st = truth.at(t[keep])
    p = geodetic_to_ecef(traj.lat[keep], traj.lon[keep], traj.h[keep])
    d_ned = np.einsum("nij,nj->ni", R_ecef_to_ned(st.lat, st.lon), p - st.p_ecef)
    d_rph = (np.asarray(traj.rph, float)[keep] - st.rph + 180.0) % 360.0 - 180.0
    err = np.column_stack([d_ned, d_rph])
    sig = np.asarray(traj.sigma, float)[keep]
    z = err / sig
    names = ("north_m", "east_m", "down_m", "roll_deg", "pitch_deg", "heading_deg")
    return {n: {"rms": float(np.sqrt(np.mean(err[:, j] ** 2))), "sigma_median": float(np.median(sig[:, j])),
                "z_rms": float(np.sqrt(np.mean(z[:, j] ** 2))), "z_max": float(np.abs(z[:, j]).max())}
            for j, n in enumerate(names)}
