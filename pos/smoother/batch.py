"""Batch GNSS/INS smoother (gtsam): CombinedImuFactor between 1 Hz keyframes, TC pseudorange + Doppler or
LC position + velocity factors, receiver clock process, Levenberg-Marquardt over the whole flight and
covariances from `gtsam.Marginals`.

Frames: states live in a fixed NED tangent frame at the flight centre (`dgcal.pos.ins.nav_frame.NavFrame`); the pose
key holds R_body_to_nav (body FRD) and the IMU origin's position; the GNSS antenna sits at `lever_arm_b`.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from dgcal.fields.constants import C_LIGHT
from dgcal.pos.ins.error_model import ImuErrorModel, imu_grade
from dgcal.pos.ins.nav_frame import NavFrame
from dgcal.pos.gnss.dd import CarrierInput
from dgcal.pos.smoother.carrier import (atmosphere_position_covariance, dd_residuals, keyframe_dd_factors,
                                       keyframe_poses, linear_dd_factors)
from dgcal.pos.smoother.code_bias import CB, CodeBiasArcs, bias_estimates, bias_process_factors, code_bias_arcs, \
    insert_initial
from dgcal.pos.smoother.covariance import smoothed_covariances, variance_factors
from dgcal.pos.smoother.fix_velocity import shifted_velocities, velocity_latency, velocity_mode
from dgcal.pos.smoother.fix_errors import (LcFixModel, error_estimates, fix_factors, fix_residuals, lc_fix_model,
                                          process_factors, set_white_share)
from dgcal.pos.smoother.fix_errors import insert_initial as insert_fix_errors
from dgcal.pos.smoother.linearised import KeyframeBlocks, KeyframeRows, keyframe_rows
from dgcal.pos.smoother.slow_attitude import slow_platform_attitude
from dgcal.pos.smoother.static import static_ends, static_white_noise, zero_motion_factors
from dgcal.pos.smoother.factors import (B, CLK, DRIFT, FE, V, X, ZERO, clock_factors, doppler_factors, position_factor,
                                  pseudorange_factors, velocity_factor)
from dgcal.pos.smoother.preintegration import (ImuSegments, bias_moved, interval_gravity, interval_params,
                                               preintegrate, preintegration_params, set_gravity, split_at_keyframes)
from dgcal.pos.smoother.heading_budget import HEADING_SPEED_MPS, HEADING_UNKNOWN_SIGMA_DEG, add_heading_budget
from dgcal.pos.smoother.initial import (GnssFixes, anchor_attitude, initial_clocks, initial_track,
                               propagate_attitude)
from dgcal.pos.smoother.integrity import (assemble_graph, factor_table, reject_outliers, screen_fixes,
                                          whitened_errors, with_bridges)


@dataclass
class SmootherOptions:
    """Tuning of the smoother; defaults suit a code-only receiver on a UAV.

    lever_arm_b: IMU origin -> GNSS antenna phase centre, body FRD, m.
    clock_bias_rw_m / clock_drift_rw_mps: receiver clock process densities (m/sqrt(s), m/s/sqrt(s)).
    huber_k: Huber threshold (in sigmas) of the GNSS factors; None for plain least squares.
    gnss_outlier_sigma: GNSS screening (dgcal.pos.smoother.integrity): fixes the IMU's acceleration bound makes
    impossible are rejected before the graph is built, and factors whose post-fit residual fails the chi-square
    test at this many sigmas after the first pass; None: neither.
    """

    lever_arm_b: np.ndarray = field(default_factory=lambda: np.zeros(3))
    use_doppler: bool = True
    earth_rotation: bool = True
    huber_k: float | None = 1.345
    clock_bias_rw_m: float = 0.1
    clock_drift_rw_mps: float = 0.2
    prior_rot_sigma_deg: tuple = (10.0, 10.0, 30.0)
    prior_pos_sigma_m: float = 20.0
    prior_vel_sigma_mps: float = 2.0
    lc_velocity: str = "auto"       # LC: the fixes' velocities: auto (when their latency is known), true, false
    max_iterations: int = 30
    covariances: bool = True
    dd_outlier_sigma: float = 5.0   # TC with a base: double differences beyond this (normalised) are dropped
    zupt: bool = True               # a static start/end of the data as zero-motion information (smoother.static)
    static_noise: bool = True       # raise the IMU white noise to what the static start/end shows
    gnss_outlier_sigma: float | None = 5.0   # GNSS epoch screening and post-fit rejection (None: off)
    code_bias: bool = True          # TC: each satellite's slow pseudorange error as a Gauss-Markov state
    code_bias_tau_s: float = 1800.0  # its correlation time (s; broadcast orbit, clock and atmosphere errors)
    motion_noise: bool = True       # LC: raise the IMU white noise to what its factors' residuals show in motion
    lc_fix_tau_s: float | None = 60.0   # LC: the fixes' time-correlated errors as Gauss-Markov states (None: white)
    lc_fix_white_share: float | None = None  # LC: the white share of the fixes' stated variance (None: estimated)


@dataclass
class NavSolution:
    """Keyframe states in the nav frame with covariances (gtsam tangent conventions, see docs/pos_smoother.md).

    cov_pose (K,6,6): [rotation (body, rad), position (body axes, m)] as gtsam's Pose3; cov_vel (K,3,3) nav.
    bias (K,6): accelerometer m/s^2 then gyro rad/s. clock: constellation -> (K,) s; drift (K,) s/s.
    """

    frame: NavFrame
    t: np.ndarray
    p_nav: np.ndarray
    v_nav: np.ndarray
    R_body_to_nav: np.ndarray
    bias: np.ndarray
    clock: dict
    drift: np.ndarray
    cov_pose: np.ndarray | None = None
    cov_vel: np.ndarray | None = None
    cov_block: np.ndarray | None = None
    n_sat: np.ndarray | None = None
    gnss_update: np.ndarray | None = None
    residuals: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    code_bias: dict = field(default_factory=dict)  # TC: sat -> (keyframes, estimated pseudorange bias m)
    fix_error: tuple | None = None  # LC: (keyframes (n,), the fixes' estimated correlated error (n,3) nav m)
    imu_noise: object = None        # the IMU model smoothed with (ImuErrorModel: raised to what rest and motion show)
    problem: object = field(default=None, repr=False)  # the Problem it came from (forward pass, outputs)
    values: object = field(default=None, repr=False)  # its gtsam Values (the linearisation point)
    rows: object = field(default=None, repr=False)    # the problem linearised at `values` (linearised.KeyframeRows)

    @property
    def cov_p_nav(self) -> np.ndarray:
        """Position covariance (K,3,3) in nav axes, m^2."""
        R_body_to_nav = self.R_body_to_nav
        return R_body_to_nav @ self.cov_pose[:, 3:, 3:] @ np.swapaxes(R_body_to_nav, 1, 2)


@dataclass
class Problem:
    """A built factor graph with its initial values and the bookkeeping needed to read it back."""

    graph: object
    values: object
    frame: NavFrame
    t_key: np.ndarray
    systems: list
    pims: list
    epoch_factors: list  # per keyframe: (kind, factor, sigma) of its measurements (sigma: of pr/dop, else None)
    imu_factors: list
    clock_factor_groups: list
    prior_factors: list
    n_sat: np.ndarray
    gnss_update: np.ndarray
    omega_b: np.ndarray
    params: object = None
    huber_k: float | None = None     # the Huber threshold of the robust GNSS factors (pr, dop, LC positions)
    iterations: int = 0
    lm_lambda: float | None = None   # the damping the last optimisation ended with
    seg: ImuSegments | None = None   # the IMU pieces of every keyframe interval (what the IMU factors integrated)
    interval_params: list = field(default_factory=list)  # per interval: its preintegration parameters (gravity)
    bias_hat: np.ndarray | None = None  # (K-1,6) the bias each interval's preintegration is linearised about
    dd: dict = field(default_factory=dict)  # keyframe -> DDFactorData (TC with a base station)
    lever_arm_b: np.ndarray | None = None
    carrier: CarrierInput | None = None
    code_bias: CodeBiasArcs | None = None   # TC: the satellites' code-bias arcs (dgcal.pos.smoother.code_bias)
    bias_factor_groups: list = field(default_factory=list)  # per keyframe: the code-bias process factors ending there
    dd_lin: tuple | None = None   # the poses (R_body_to_nav (K,3,3), p (K,3)) the DD factors are linearised at
    lc: LcFixModel | None = None  # LC: the fixes with their error states (dgcal.pos.smoother.fix_errors)
    _blocks: KeyframeBlocks | None = field(default=None, repr=False)

    def ordering(self) -> gtsam.Ordering:
        """Elimination order: keyframe by keyframe (each block's variables together), the pinned ZERO last."""
        where = self.blocks().where
        o = gtsam.Ordering()
        for _, _, key in sorted((loc[0], loc[1], key) for key, loc in where.items() if loc is not None):
            o.push_back(key)
        if self.values.exists(ZERO()):
            o.push_back(ZERO())
        return o

    def blocks(self, K: int | None = None, first: int = 0) -> KeyframeBlocks:
        """The keyframe block layout of this problem (all keyframes, or K of them from `first`)."""
        if K is None and first == 0:
            # the whole problem's layout is asked for by the ordering, the covariances and the forward pass
            if self._blocks is None:
                self._blocks = KeyframeBlocks(len(self.t_key), self.systems, 0, self.code_bias, self.fix_span)
            return self._blocks
        return KeyframeBlocks(len(self.t_key) if K is None else K, self.systems, first, self.code_bias, self.fix_span)

    @property
    def fix_span(self) -> tuple | None:
        """LC with the fixes' error states: their first and last keyframe."""
        return self.lc.span if self.lc is not None else None


def _imu_rate_at(imu, t: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(imu.t, t, side="left"), 0, len(imu.t) - 1)
    return imu.gyro_rad_s[i]


def build_problem(imu, frame: NavFrame, t_key: np.ndarray, fixes: GnssFixes, imu_noise: ImuErrorModel,
                  opts: SmootherOptions, mode: str = "tc", epochs_at_key: list | None = None,
                  lc_fixes: GnssFixes | None = None, carrier: CarrierInput | None = None,
                  static: np.ndarray | None = None) -> Problem:
    """Assemble the factor graph: priors, IMU (zero biases), GNSS (TC epochs or LC fixes) and clock factors;
    with `carrier` (TC with a base) the double differences replace the pseudoranges of their keyframes."""
    K = len(t_key)
    lever = np.asarray(opts.lever_arm_b, float)
    params = preintegration_params(imu_noise, frame, opts.earth_rotation)
    seg = split_at_keyframes(imu.t, imu.gyro_rad_s, imu.accel_m_s2, t_key, imu.dt[0])
    biases = [gtsam.imuBias.ConstantBias()] * (K - 1)
    per_interval = with_bridges(interval_params(imu_noise, frame, seg, opts.earth_rotation), imu, imu_noise, frame,
                                t_key, opts.earth_rotation)
    p_ant, v_ant = initial_track(t_key, fixes, frame)
    # gravity along the initial track; the second pass moves it to the solved one (`refine_imu`)
    set_gravity(per_interval, interval_gravity(frame, p_ant))
    pims = preintegrate(params, seg, biases, per_interval)

    a, R_body_to_nav_anchor = anchor_attitude(t_key, v_ant)
    R_body_to_nav = propagate_attitude(pims, a, R_body_to_nav_anchor, p_ant, v_ant)
    slow = not np.any(np.hypot(v_ant[:, 0], v_ant[:, 1]) > HEADING_SPEED_MPS)
    if slow:
        # no course above HEADING_SPEED_MPS: the gyros' unknown biases drift the propagated guess (slow_attitude)
        R_body_to_nav = slow_platform_attitude(imu, t_key, R_body_to_nav, p_ant,
                                               float(np.median(fixes.sigma_ned[:, :2])))
    p_imu = p_ant - np.einsum("kij,j->ki", R_body_to_nav, lever)
    omega_b = _imu_rate_at(imu, t_key)

    values = gtsam.Values()
    for k in range(K):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(R_body_to_nav[k]), p_imu[k]))
        values.insert(V(k), v_ant[k].copy())
        values.insert(B(k), biases[min(k, K - 2)])

    prior = []
    rs = np.radians(opts.prior_rot_sigma_deg)
    if slow:
        # no course to take the heading from (static, slow): it starts as good as unknown, so its sigma says so
        rs = rs.copy()
        rs[2] = np.radians(HEADING_UNKNOWN_SIGMA_DEG)
    prior.append(gtsam.PriorFactorPose3(X(0), values.atPose3(X(0)), gtsam.noiseModel.Diagonal.Sigmas(
        np.r_[rs, [opts.prior_pos_sigma_m] * 3])))
    prior.append(gtsam.PriorFactorPoint3(V(0), v_ant[0], gtsam.noiseModel.Isotropic.Sigma(3, opts.prior_vel_sigma_mps)))
    prior.append(gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Diagonal.Sigmas(
        np.r_[[imu_noise.accel_bias_sigma] * 3, [imu_noise.gyro_bias_sigma] * 3])))

    imu_factors = [gtsam.CombinedImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), B(k + 1), pims[k])
                   for k in range(K - 1)]

    epoch_factors: list = [[] for _ in range(K)]
    clock_groups = []
    n_sat = np.zeros(K, int)
    gnss_update = np.zeros(K, bool)
    systems: list = []
    dd: dict = {}
    arcs: CodeBiasArcs | None = None
    bias_groups: list = []
    lc_model: LcFixModel | None = None
    if mode == "tc" and carrier is not None:
        dd = keyframe_dd_factors(t_key, carrier.at(t_key), lever, frame, carrier.phase_corr, carrier.code_corr, X,
                                 values)
    if mode == "tc":
        systems = sorted({str(s) for ep in epochs_at_key if ep is not None for s in ep.system},
                         key=lambda s: "GECJRIS".find(s))
        ecef_T_nav = frame.ecef_T_nav()
        clk, drift = initial_clocks(t_key, epochs_at_key, p_ant, frame, systems)
        for k in range(K):
            for s in systems:
                values.insert(CLK(s, k), float(clk[s][k]))
            values.insert(DRIFT(k), float(drift[k]))
        for s in systems:
            prior.append(gtsam.PriorFactorDouble(CLK(s, 0), float(clk[s][0]),
                                                 gtsam.noiseModel.Isotropic.Sigma(1, 1e3 / C_LIGHT)))
        prior.append(gtsam.PriorFactorDouble(DRIFT(0), float(drift[0]),
                                             gtsam.noiseModel.Isotropic.Sigma(1, 100.0 / C_LIGHT)))
        if opts.use_doppler:
            values.insert(ZERO(), 0.0)
            prior.append(gtsam.PriorFactorDouble(ZERO(), 0.0, gtsam.noiseModel.Isotropic.Sigma(1, 1e-3 / C_LIGHT)))
        for k in range(K - 1):
            clock_groups.append(clock_factors(systems, k, t_key[k + 1] - t_key[k], opts.clock_bias_rw_m,
                                              opts.clock_drift_rw_mps, values))
        if opts.code_bias:
            arcs = code_bias_arcs(t_key, epochs_at_key, opts.code_bias_tau_s, skip=set(dd))
            if len(arcs):
                insert_initial(arcs, values)
                bias_groups = [[] for _ in range(K)]
                for k, f in bias_process_factors(arcs, t_key, values):
                    bias_groups[k].append(f)
        for k, ep in enumerate(epochs_at_key):
            if k in dd:
                f, data = dd[k]
                epoch_factors[k].append(("dd", f, None))
                n_sat[k] = len(set(data.cur.sat.tolist()) | set(data.cur.ref.tolist()))
                gnss_update[k] = True
            if ep is None or ep.n == 0:
                continue
            r_approx = frame.to_ecef(p_ant[k])
            if k not in dd:
                n_sat[k] = ep.n
                gnss_update[k] = True
                fs, sg = pseudorange_factors(k, ep, r_approx, lever, ecef_T_nav, opts.huber_k,
                                             bias_key=arcs.key if arcs is not None else None, with_sigma=True)
                epoch_factors[k] += [("pr", f, sig) for f, sig in zip(fs, sg)]
            if opts.use_doppler:
                fs, sg = doppler_factors(k, ep, r_approx, lever, omega_b[k], ecef_T_nav, opts.huber_k,
                                         with_sigma=True)
                epoch_factors[k] += [("dop", f, sig) for f, sig in zip(fs, sg)]
    else:
        lc = lc_fixes if lc_fixes is not None else fixes
        idx = np.clip(np.searchsorted(t_key, lc.t - 1e-3), 0, K - 1)
        use = (np.abs(t_key[idx] - lc.t) <= 1e-3) & np.all(np.isfinite(lc.p_ecef), axis=1)
        use[np.flatnonzero(use)[1:][np.diff(idx[use]) == 0]] = False     # one fix per keyframe
        rows = np.flatnonzero(use)
        C = lc.cov_ned[rows] if lc.cov_ned is not None else np.einsum("ni,ij->nij", lc.sigma_ned[rows] ** 2, np.eye(3))
        z = frame.from_ecef(lc.p_ecef[rows]) if len(rows) else np.zeros((0, 3))
        if opts.lc_fix_tau_s and len(rows) >= 2:
            share = opts.lc_fix_white_share if opts.lc_fix_white_share is not None else LC_WHITE_SHARE_START
            lc_model = lc_fix_model(t_key, idx[rows], z, C, share, opts.lc_fix_tau_s, lever)
            insert_fix_errors(lc_model, values)
            bias_groups = [[] for _ in range(K)]
            for k, f in process_factors(lc_model, values):
                bias_groups[k].append(f)
            lc_model.lin = keyframe_poses(values, K)
            for k, f in fix_factors(lc_model, values, *lc_model.lin).items():
                epoch_factors[k].append(("pos", f, None))
        else:
            for i, k in enumerate(idx[rows]):
                epoch_factors[k].append(("pos", position_factor(k, z[i], C[i], lever, opts.huber_k), None))
        gnss_update[idx[rows]] = True
        n_sat[idx[rows]] = 1
        vmode = velocity_mode(opts.lc_velocity)
        if lc.v_ecef is not None and (vmode == "true" or (vmode == "auto" and lc.velocity_on_time)):
            add_lc_velocities(epoch_factors, lc, t_key, frame, R_body_to_nav, omega_b, lever)

    if static is not None and static.any():
        for k, kind, f in zero_motion_factors(static, t_key):
            epoch_factors[k].append((kind, f, None))
    problem = Problem(None, values, frame, t_key, systems, pims, epoch_factors, imu_factors, clock_groups, prior,
                      n_sat, gnss_update, omega_b, params, huber_k=opts.huber_k, seg=seg, interval_params=per_interval,
                      bias_hat=np.zeros((K - 1, 6)), dd={k: v[1] for k, v in dd.items()}, lever_arm_b=lever,
                      carrier=carrier, code_bias=arcs if arcs is not None and len(arcs) else None,
                      bias_factor_groups=bias_groups, dd_lin=keyframe_poses(values, K) if dd else None,
                      lc=lc_model)
    problem.graph = assemble_graph(problem)
    return problem


def _lc_fix_keyframes(lc: GnssFixes, t_key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fixes of `lc` at keyframes (rows, keyframes)."""
    K = len(t_key)
    idx = np.clip(np.searchsorted(t_key, lc.t - 1e-3), 0, K - 1)
    use = np.abs(t_key[idx] - lc.t) <= 1e-3
    rows = np.flatnonzero(use)
    return rows, idx[rows]


def add_lc_velocities(epoch_factors: list, lc: GnssFixes, t_key: np.ndarray, frame: NavFrame,
                      R_body_to_nav: np.ndarray, omega_b: np.ndarray, lever: np.ndarray, latency_s: float = 0.0,
                      latency_sigma_s: float = 0.0, accel_nav: np.ndarray | None = None) -> int:
    """Velocity factors of the LC fixes (`epoch_factors` per keyframe, in place): the antenna velocity minus the
    lever arm's rate, each fix's velocity taken `latency_s` later (`dgcal.pos.smoother.fix_velocity`), with the
    latency's uncertainty `latency_sigma_s` as noise along the antenna's acceleration `accel_nav` (K,3) nav m/s^2
    (a velocity late by delta is off by delta a). Returns the number added."""
    rows, ks = _lc_fix_keyframes(lc, t_key)
    v = lc.v_ecef if not latency_s else shifted_velocities(lc.t, lc.v_ecef, latency_s)
    n = 0
    for j, k in zip(rows, ks):
        if not (np.all(np.isfinite(v[j])) and np.all(np.isfinite(lc.sigma_v_ned[j]))):
            continue
        v_nav = v[j] @ frame.R_nav_to_ecef
        v_lever = R_body_to_nav[k] @ np.cross(omega_b[k], lever)
        noise = lc.sigma_v_ned[j]
        if latency_sigma_s and accel_nav is not None:
            noise = np.diag(noise ** 2) + latency_sigma_s ** 2 * np.outer(accel_nav[k], accel_nav[k])
        epoch_factors[k].append(("vel", velocity_factor(k, v_nav - v_lever, noise), None))
        n += 1
    return n


def lc_velocities_auto(problem: Problem, values, lc: GnssFixes) -> dict:
    """LC, `lc_velocity` "auto": the fixes' velocity latency against the solution at `values`
    (`dgcal.pos.smoother.fix_velocity.velocity_latency`) and their velocity factors with it: a latency the data
    determine and show is removed, and what is not known of it is noise along the acceleration (graph rebuilt).
    Returns what was found."""
    sol = read_states(problem, values)
    lever = problem.lever_arm_b
    v_ant = sol.v_nav + np.einsum("kij,kj->ki", sol.R_body_to_nav, np.cross(problem.omega_b, lever))
    rows, ks = _lc_fix_keyframes(lc, problem.t_key)
    R_nav_to_ecef = problem.frame.R_nav_to_ecef
    lat = velocity_latency(problem.t_key, v_ant, ks, lc.v_ecef[rows] @ R_nav_to_ecef, lc.sigma_v_ned[rows])
    out = lat.as_dict()
    out["factors"] = add_lc_velocities(problem.epoch_factors, lc, problem.t_key, problem.frame, sol.R_body_to_nav,
                                       problem.omega_b, lever, lat.shift_s, lat.sigma_left_s,
                                       np.gradient(v_ant, problem.t_key, axis=0))
    problem.graph = assemble_graph(problem)
    return out


def update_gravity(problem: Problem, p_nav: np.ndarray, share: float = 0.0) -> np.ndarray:
    """Each interval's gravity at the track p_nav (K,3) m, in place (gtsam reads it from the parameters at every
    evaluation: no new preintegration), where it changes the interval's velocity increment by more than `share`
    of its white noise; returns those intervals."""
    seg = problem.seg
    T = np.add.reduceat(seg.dt, seg.start[:-1])
    g = interval_gravity(problem.frame, p_nav)
    old = np.array([p.n_gravity for p in problem.interval_params])
    noise = np.sqrt(np.array([p.getAccelerometerCovariance()[0, 0] for p in problem.interval_params]) * T)
    moved = np.flatnonzero(np.linalg.norm(g - old, axis=1) * T > share * noise)
    set_gravity([problem.interval_params[k] for k in moved], g[moved])
    return moved


def refine_imu(problem: Problem, imu_noise: ImuErrorModel, first: NavSolution, share: float = 0.01) -> bool:
    """The second pass's IMU factors, in place, where they change materially (an interval's velocity increment by
    more than `share` of its white noise): the interval's gravity at `first`'s track (`update_gravity`), and the
    preintegration about `first`'s biases where the bias moved from its linearisation point
    (`dgcal.pos.smoother.preintegration.bias_moved`; elsewhere gtsam's first-order bias correction holds). True if
    anything changed: the solution must then be re-optimised."""
    seg = problem.seg
    moved_g = update_gravity(problem, first.p_nav, share)
    which = np.flatnonzero(bias_moved(imu_noise, seg, problem.bias_hat, first.bias[:-1], share))
    if len(which):
        biases = {int(k): gtsam.imuBias.ConstantBias(first.bias[k, :3], first.bias[k, 3:]) for k in which}
        for k, pim in zip(which, preintegrate(problem.params, seg, biases, problem.interval_params, which)):
            problem.pims[k] = pim
            problem.imu_factors[k] = gtsam.CombinedImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), B(k + 1), pim)
            problem.bias_hat[k] = first.bias[k]
        problem.graph = assemble_graph(problem)
    return bool(len(moved_g) or len(which))


def screen_dd(problem: Problem, values, threshold: float) -> int:
    """Drop the double differences whose residual at `values` exceeds `threshold` sigmas (an undetected slip or a
    wrong integer: phase rows of that arc pair are dropped at every keyframe) and rebuild the keyframes' double
    difference factors in place; returns the number of rows dropped."""
    if not problem.dd:
        return 0
    bad_rows: dict = {}
    n_bad: dict = {}
    iono, tropo = problem.carrier.atmosphere
    for k, data in problem.dd.items():
        e, sig = dd_residuals(data, values, X, problem.lever_arm_b, problem.frame)
        absolute = data.cur.mode == 0
        sig[absolute] = np.sqrt(sig[absolute] ** 2 + np.diag(data.cur.atmosphere_covariance(iono, tropo))[absolute])
        bad = np.abs(e / sig) > threshold
        if bad.any():
            bad_rows[k] = bad
            for tr, b in zip(data.cur.track, bad):
                if b and tr[0] in (0, 2):
                    n_bad[tr] = n_bad.get(tr, 0) + 1
    if not bad_rows:
        return 0
    # a phase track failing at three keyframes or more has a slip or a wrong integer: it goes altogether
    bad_tracks = {tr for tr, n in n_bad.items() if n >= 3}
    dd_at_key = [None] * len(problem.t_key)
    dropped = 0
    for k, data in problem.dd.items():
        keep = np.array([tr not in bad_tracks for tr in data.cur.track], bool)
        if k in bad_rows:
            keep &= ~bad_rows[k]
        dropped += int((~keep).sum())
        dd_at_key[k] = data.cur.subset(keep) if keep.any() else None
    c = problem.carrier
    new = keyframe_dd_factors(problem.t_key, dd_at_key, problem.lever_arm_b, problem.frame, c.phase_corr,
                              c.code_corr, X, values)
    for k in range(len(problem.t_key)):
        fl = [e for e in problem.epoch_factors[k] if e[0] != "dd"]
        if k in new:
            fl.insert(0, ("dd", new[k][0], None))
        problem.epoch_factors[k] = fl
    problem.dd = {k: v[1] for k, v in new.items()}
    problem.dd_lin = keyframe_poses(values, len(problem.t_key))
    problem.graph = assemble_graph(problem)
    return dropped


def lc_rows(problem: Problem) -> np.ndarray:
    """The rows of `problem.lc` whose fix is still in the graph (the post-fit screening removes some)."""
    lc = problem.lc
    has = np.array([any(e[0] == "pos" for e in problem.epoch_factors[k]) for k in lc.k], bool)
    return np.flatnonzero(has)


def relinearise_lc(problem: Problem, values, force: bool = False) -> bool:
    """Re-linearise the LC fix factors (`dgcal.pos.smoother.fix_errors`) at `values` when a keyframe pose moved from
    their linearisation point by more than DD_RELINEARISE_M or DD_RELINEARISE_RAD (or `force`: the model changed);
    the graph is rebuilt. True if it was."""
    lc = problem.lc
    if lc is None:
        return False
    K = len(problem.t_key)
    R_body_to_nav, p = keyframe_poses(values, K)
    if not force and lc.lin is not None and not _moved(lc.lin, R_body_to_nav, p, lc.k):
        return False
    new = fix_factors(lc, values, R_body_to_nav, p, lc_rows(problem))
    for k, f in new.items():
        problem.epoch_factors[k] = [("pos", f, None) if e[0] == "pos" else e for e in problem.epoch_factors[k]]
    lc.lin = (R_body_to_nav, p)
    problem.graph = assemble_graph(problem)
    return True


def _moved(lin: tuple, R_body_to_nav: np.ndarray, p: np.ndarray, k: np.ndarray | None = None) -> bool:
    """Whether a keyframe pose (of keyframes `k`, all if None) moved from `lin` beyond the re-linearisation
    thresholds."""
    R0, p0 = lin
    if k is not None:
        R0, p0, R_body_to_nav, p = R0[k], p0[k], R_body_to_nav[k], p[k]
    cos = np.clip((np.einsum("kij,kij->k", R_body_to_nav, R0) - 1.0) / 2.0, -1.0, 1.0)
    return bool(np.max(np.linalg.norm(p - p0, axis=1)) > DD_RELINEARISE_M
                or np.max(np.arccos(cos)) > DD_RELINEARISE_RAD)


def relinearise(problem: Problem, values) -> bool:
    """Re-linearise the problem's linearised factors (double differences, LC fixes) where the poses moved."""
    a = relinearise_dd(problem, values)
    b = relinearise_lc(problem, values)
    return a or b


DD_RELINEARISE_M = 1.0       # position move (m) beyond which the double differences are re-linearised
DD_RELINEARISE_RAD = 5e-4    # attitude move (rad, 0.03 deg)


def relinearise_dd(problem: Problem, values) -> bool:
    """Re-linearise the double-difference factors at `values` when a keyframe pose moved from their
    linearisation point by more than DD_RELINEARISE_M or DD_RELINEARISE_RAD (`dgcal.pos.smoother.carrier.
    linear_dd_factor`); the graph is rebuilt. True if it was."""
    if not problem.dd:
        return False
    K = len(problem.t_key)
    R_body_to_nav, p = keyframe_poses(values, K)
    if problem.dd_lin is not None and not _moved(problem.dd_lin, R_body_to_nav, p):
        return False
    new = linear_dd_factors(problem.dd, problem.lever_arm_b, problem.frame, values, X, R_body_to_nav, p)
    for k, f in new.items():
        problem.epoch_factors[k] = [("dd", f, None) if e[0] == "dd" else e for e in problem.epoch_factors[k]]
    problem.dd_lin = (R_body_to_nav, p)
    problem.graph = assemble_graph(problem)
    return True


def lm_params(problem: Problem, max_iterations: int = 30, lambda_initial: float | None = None):
    """The smoother's Levenberg-Marquardt settings."""
    p = gtsam.LevenbergMarquardtParams()
    p.setMaxIterations(max_iterations)
    if lambda_initial is not None:
        p.setlambdaInitial(lambda_initial)
    # stop when the cost changes by less than 1e-5 relative: with costs of 1e3-1e5 that is a chi-square change far
    # below one, i.e. nothing the covariances could resolve (1e-7 bought two more iterations)
    p.setRelativeErrorTol(REL_TOL)
    p.setAbsoluteErrorTol(ABS_TOL)
    # a navigation-grade IMU makes the normal equations so stiff that only heavily damped steps succeed:
    # let lambda grow past gtsam's default bound (1e5) instead of stopping without a single step
    p.setlambdaUpperBound(1e12)
    # eliminate keyframe by keyframe: the graph is a chain of keyframe blocks, and COLAMD, blind to that, takes
    # more iterations once the satellites' code biases add thousands of scalar variables
    p.setOrdering(problem.ordering())
    return p


REL_TOL, ABS_TOL = 1e-5, 1e-7


def optimize(problem: Problem, max_iterations: int = 30, hook=None, resume: bool = False):
    """Levenberg-Marquardt over the whole graph from `problem.values`, stepped as gtsam's own loop does (until the
    cost changes by less than `REL_TOL` relative or `ABS_TOL` absolute, or `max_iterations`); returns the values.

    `hook(n, values)` runs after iteration n and returns True when it changed parameters of the graph in place
    (gravity): gtsam's optimiser still holds the cost under the old ones, which its next step is accepted against,
    so it goes on only when that cost moved by less than a tenth of the last step's decrease, else a new optimiser
    starts there. `resume`: continue the last optimiser of this graph (the graph unchanged since): a new optimiser's
    first iteration costs twice a later one (it builds the elimination structure the later ones reuse)."""
    last = getattr(problem, "_lm", None)
    if resume and last is not None and last[0] is problem.graph:
        opt = last[1]
    else:
        opt = gtsam.LevenbergMarquardtOptimizer(problem.graph, problem.values, lm_params(problem, max_iterations))
    graph = problem.graph
    cur = opt.error()
    n = 0
    while n < max_iterations:
        opt.iterate()
        n += 1
        new = opt.error()
        if not np.isfinite(new) or cur - new <= ABS_TOL or (cur - new) / cur <= REL_TOL:
            break
        if hook is not None and hook(n, opt.values()):
            e = problem.graph.error(opt.values())
            # a rebuilt graph (new factors) needs a new optimiser: the old one holds the old factors
            if problem.graph is not graph or abs(e - new) > 0.1 * (cur - new):
                opt = gtsam.LevenbergMarquardtOptimizer(problem.graph, opt.values(),
                                                        lm_params(problem, max_iterations, opt.lambda_()))
                graph = problem.graph
            new = e
        cur = new
    problem.iterations = n
    problem.lm_lambda = opt.lambda_()
    problem._lm = (problem.graph, opt)
    return opt.values()


def read_states(problem: Problem, values) -> NavSolution:
    """Keyframe states from gtsam Values (no covariances)."""
    K = len(problem.t_key)
    # the problem's only Pose3 variables are X(k), extracted in key (= keyframe) order, as are the velocities V(k)
    R_body_to_nav, p = keyframe_poses(values, K)
    v = gtsam.utilities.extractVectors(values, "v").reshape(K, 3)
    b = np.array([values.atConstantBias(B(k)).vector() for k in range(K)])
    clock = {s: np.array([values.atDouble(CLK(s, k)) for k in range(K)]) for s in problem.systems}
    drift = (np.array([values.atDouble(DRIFT(k)) for k in range(K)]) if problem.systems
             else np.zeros(K))
    sol = NavSolution(problem.frame, problem.t_key.copy(), p, v, R_body_to_nav, b, clock, drift,
                      n_sat=problem.n_sat.copy(), gnss_update=problem.gnss_update.copy())
    if problem.code_bias is not None:
        sol.code_bias = bias_estimates(problem.code_bias, values)
    if problem.lc is not None:
        sol.fix_error = error_estimates(problem.lc, values)
    return sol


def gnss_residuals(problem: Problem, values, rows: KeyframeRows) -> dict:
    """Post-fit residuals of the GNSS factors: kind -> (keyframe index (M,), residual (M,) m or m/s, sigma (M,)).

    `rows`: the graph linearised at `values` (`dgcal.pos.smoother.linearised.keyframe_rows`); the factors whose
    sigma was recorded (pseudorange, Doppler) take their errors from it, the few others are evaluated."""
    tab = factor_table(problem)
    z = whitened_errors(rows, tab)
    out: dict = {}      # kind -> [(keyframe, residuals, sigmas) per factor]
    for i, (kd, sig) in enumerate(zip(tab.kinds, tab.sigma)):
        if kd is None or np.isfinite(sig):
            continue
        kind, k = kd
        if kind == "pos" and problem.lc is not None:
            continue    # below, all at once
        if kind == "dd":
            data = problem.dd[k]
            e, s = dd_residuals(data, values, X, problem.lever_arm_b, problem.frame)
            for name, m in (("ddp", (data.cur.kind != 1) & (data.cur.mode != 1)),
                            ("ddp_float", (data.cur.kind != 1) & (data.cur.mode == 1)), ("ddc", data.cur.kind == 1)):
                if m.any():
                    out.setdefault(name, []).append((np.full(m.sum(), k), e[m], s[m]))
            continue
        f = problem.graph.at(i)
        e = np.atleast_1d(f.unwhitenedError(values))
        w = np.atleast_1d(f.whitenedError(values))
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(w != 0, e / np.where(w != 0, w, 1.0), np.nan)
        out.setdefault(kind, []).append((np.full(len(e), k), e, s))
    if problem.lc is not None:
        rows_lc = lc_rows(problem)
        if len(rows_lc):
            k, e, s = fix_residuals(problem.lc, values, *keyframe_poses(values, len(problem.t_key)), rows_lc)
            out["pos"] = [(np.repeat(k, 3), e.ravel(), s.ravel())]
    res = {kind: tuple(np.concatenate(c) for c in zip(*r)) for kind, r in out.items()}
    # the recorded kinds (one row per factor): whitened error times sigma
    rec = np.flatnonzero(np.isfinite(tab.sigma))
    names = np.array([tab.kinds[i][0] for i in rec])
    ks = np.array([tab.kinds[i][1] for i in rec], int)
    for kind in dict.fromkeys(names.tolist()):
        m = names == kind
        i = rec[m]
        res[kind] = (ks[m], z[tab.start[i]] * tab.sigma[i], tab.sigma[i].copy())
    return res


def add_marginals(sol: NavSolution, problem: Problem, values, rows: KeyframeRows | None = None,
                  P: np.ndarray | None = None) -> None:
    """Fill cov_pose / cov_vel (and the full keyframe block `cov_block`) from the linearised graph (`rows`: already
    linearised at `values`; `P`: the keyframe blocks' covariances if already computed)."""
    if P is None:
        P = smoothed_covariances(problem.graph, values, problem.blocks(), rows)
    sol.cov_pose = P[:, :6, :6].copy()
    sol.cov_vel = P[:, 6:9, 6:9].copy()
    sol.cov_block = P


STEP_LEFT = 0.1   # the largest Gauss-Newton step left at the solution, in sigmas of the state it moves


def step_left(P: np.ndarray, dx: np.ndarray) -> float:
    """The largest |step| / sigma over every keyframe state, from the covariances P (K,n,n) and the Gauss-Newton step
    dx (K,n) of the linearised problem (`dgcal.pos.smoother.covariance.smoothed_covariances`)."""
    sig = np.sqrt(np.maximum(np.einsum("kii->ki", P), 1e-300))
    return float(np.max(np.abs(dx) / sig)) if dx.size else 0.0


def add_atmosphere_budget(sol: NavSolution, problem: Problem) -> None:
    """Add the position covariance that the differential atmosphere left in the double differences causes
    (`dgcal.pos.smoother.carrier.atmosphere_position_covariance`; nearly constant per satellite, so no amount
    of smoothing averages it out) to the keyframes' pose (and block) covariances, body axes."""
    iono, tropo = problem.carrier.atmosphere
    P = atmosphere_position_covariance(problem.dd, sol, problem.lever_arm_b, iono, tropo)
    if P is None:
        return
    Pb = np.swapaxes(sol.R_body_to_nav, 1, 2) @ P @ sol.R_body_to_nav
    sol.cov_pose[:, 3:, 3:] += Pb
    if sol.cov_block is not None:
        sol.cov_block[:, 3:6, 3:6] += Pb
    sol.info["atmosphere_budget_m"] = np.sqrt(np.median(np.einsum("kii->ki", P), axis=0)).round(4).tolist()


# share of the accelerometer triad's misalignment variance left in roll and pitch: the tilt it causes (gravity seen
# leaning) looks much like an accelerometer bias, which the smoother estimates, so most of it is taken up there. The
# share is calibrated on simulated flights with carrier phase, where roll and pitch are otherwise known to a
# hundredth of a degree (a misaligned ADIS16488-class IMU, 20 flights: roll/pitch error/sigma RMS 1.38/1.34 without,
# 1.01/0.92 with it; the whole variance would make them 0.65/0.68). The same share holds for LC and code-only TC,
# where it limits roll and pitch on long flights (20-minute UAV flights, 8 seeds each: LC on PPK positions
# 1.71/1.28 without, 1.08/0.86 with it; TC code 1.32/1.09 without, 1.00/0.86 with it); on 5-minute ones the turn
# noise's sigmas are larger and it adds little
TILT_SHARE = 1.0 / 3.0


def add_tilt_budget(sol: NavSolution, noise: ImuErrorModel) -> None:
    """Add the tilt an accelerometer triad's misalignment leaves in roll and pitch (its z axis leaning towards x or
    y by `accel_misalign_sigma`, rad: no GNSS sees it), `TILT_SHARE` of its variance, to the keyframes' rotation
    variances about body x and y (every mode)."""
    s2 = TILT_SHARE * float(noise.accel_misalign_sigma) ** 2
    if s2 <= 0:
        return
    for C in (sol.cov_pose, sol.cov_block):
        if C is not None:
            C[:, 0, 0] += s2
            C[:, 1, 1] += s2
    sol.info["tilt_budget_deg"] = round(float(np.degrees(np.sqrt(s2))), 4)


def solution_values(sol: NavSolution, problem: Problem):
    """gtsam Values holding the states of a NavSolution (keys as in the problem)."""
    vals = gtsam.Values()
    for k in range(len(sol.t)):
        vals.insert(X(k), gtsam.Pose3(gtsam.Rot3(sol.R_body_to_nav[k]), sol.p_nav[k]))
        vals.insert(V(k), sol.v_nav[k].copy())
        vals.insert(B(k), gtsam.imuBias.ConstantBias(sol.bias[k, :3], sol.bias[k, 3:]))
        for s in problem.systems:
            vals.insert(CLK(s, k), float(sol.clock[s][k]))
        if problem.systems:
            vals.insert(DRIFT(k), float(sol.drift[k]))
    arcs = problem.code_bias
    for a in range(len(arcs) if arcs is not None else 0):
        ks, bias = sol.code_bias[arcs.sat[a]]
        for k in range(arcs.k0[a], arcs.k1[a] + 1):
            vals.insert(CB(arcs.slot[a], k), -float(bias[np.searchsorted(ks, k)]))
    if problem.lc is not None:
        for k, e in zip(*sol.fix_error):
            vals.insert(FE(int(k)), -e)
    if problem.values.exists(ZERO()):
        vals.insert(ZERO(), 0.0)
    return vals


LC_WHITE_SHARE_START = 1.0    # LC: the white share of the fixes' stated variance the first pass assumes


# the IMU noise floor of the coarse first pass (ADIS16488-class): densities below it are raised to it
_COARSE_FLOOR = dict(gyro_arw=8.7e-5, accel_vrw=4.8e-4, gyro_bias_rw=1.3e-6, accel_bias_rw=4.4e-5,
                     gyro_bias_sigma=1.7e-4, accel_bias_sigma=2e-2)


def _coarse_noise(noise: ImuErrorModel) -> ImuErrorModel | None:
    """`noise` with every density raised to at least `_COARSE_FLOOR`, or None if it is not below it anywhere."""
    low = {k: v for k, v in _COARSE_FLOOR.items() if getattr(noise, k) < 0.5 * v}
    return dataclasses.replace(noise, **{k: max(getattr(noise, k), v) for k, v in _COARSE_FLOOR.items()}) \
        if low else None


def _static_spans(t_key: np.ndarray, static: np.ndarray | None) -> list:
    """[start, end] (s from the first keyframe) of the static start and end runs."""
    if static is None or not static.any():
        return []
    k = np.nonzero(static)[0]
    cut = np.nonzero(np.diff(k) > 1)[0]
    runs = np.split(k, cut + 1)
    return [[round(float(t_key[r[0]] - t_key[0]), 2), round(float(t_key[r[-1]] - t_key[0]), 2)] for r in runs]


def keyframe_times(imu, t_obs: np.ndarray) -> np.ndarray:
    """Keyframes (GPS s): the GNSS epochs inside the IMU span, gaps filled at the median epoch interval."""
    t0 = imu.t[0] - imu.dt[0]
    t = np.unique(np.asarray(t_obs, float))
    t = t[(t >= t0 + 1e-6) & (t <= imu.t[-1] + 1e-6)]
    if len(t) < 2:
        raise ValueError("fewer than two GNSS epochs inside the IMU time span")
    dt = float(np.median(np.diff(t)))
    grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-6)) + 1)
    near = _nearest_gap(grid, t)
    return np.union1d(t, grid[near > 0.25 * dt])


def _nearest_gap(grid: np.ndarray, t: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(t, grid), 1, len(t) - 1)
    return np.minimum(np.abs(grid - t[i - 1]), np.abs(grid - t[i]))


def _screen_inputs(imu, fixes: GnssFixes, lc_fixes: GnssFixes | None, mode: str, k_sigma: float):
    """`screen_fixes` on the initialising fixes and (when they are other fixes) on the LC measurements; the
    rejections say which input they came from ('initial track' for fixes that only initialise)."""
    same = lc_fixes is None or lc_fixes is fixes
    out = []
    clean, rej = screen_fixes(fixes, imu, k_sigma)
    for r in rej:
        r["input"] = "gnss" if (mode == "lc" and same) else "initial track"
    out += rej
    if not same:
        lc_fixes, rej = screen_fixes(lc_fixes, imu, k_sigma)
        for r in rej:
            r["input"] = "gnss"
        out += rej
    else:
        lc_fixes = clean if lc_fixes is not None else None
    return clean, lc_fixes, out


@dataclass
class Setup:
    """What the smoother starts from: the first problem (built, not yet optimised), the IMU noise it carries (raised
    to what a static start/end shows), the screened fixes and what the screening rejected, and the keyframes."""

    problem: Problem
    noise: ImuErrorModel
    fixes: GnssFixes
    lc_fixes: GnssFixes | None
    epochs: list | None            # TC: the GNSS epoch at each keyframe (None where there is none)
    static: np.ndarray | None      # (K,) bool: static start/end keyframes
    measured: tuple | None         # white noise measured at rest (gyro rad/sqrt(s), accel m/s/sqrt(s))
    rejected: list
    build_s: float = 0.0


def setup_problem(imu, fixes: GnssFixes, grade: str | ImuErrorModel, opts: SmootherOptions | None = None,
                  mode: str = "tc", gnss=None, lc_fixes: GnssFixes | None = None, frame: NavFrame | None = None,
                  carrier: CarrierInput | None = None) -> Setup:
    """The smoother's first problem (arguments as `smooth`): fixes screened, nav frame, keyframes, static
    start/end and its noise, the graph with its initial values."""
    opts = opts or SmootherOptions()
    noise = imu_grade(grade).smoother_noise()
    rejected: list = []
    if opts.gnss_outlier_sigma:
        fixes, lc_fixes, rejected = _screen_inputs(imu, fixes, lc_fixes, mode, opts.gnss_outlier_sigma)
    if frame is None:
        ok = np.all(np.isfinite(fixes.p_ecef), axis=1)
        frame = NavFrame.at_ecef(fixes.p_ecef[ok].mean(axis=0))
    if mode == "tc":
        if gnss is None:
            raise ValueError("TC mode needs GNSS observations")
        t_all = gnss.t_gps
        t_key = keyframe_times(imu, t_all)
        j = np.clip(np.searchsorted(t_all, t_key), 0, len(t_all) - 1)
        epochs = [gnss.epochs[i] if abs(t_all[i] - t) < 1e-3 else None for i, t in zip(j, t_key)]
    elif mode == "lc":
        t_key = keyframe_times(imu, (lc_fixes or fixes).t)
        epochs = None
    else:
        raise ValueError(f"unknown mode {mode!r}")
    t0 = time.perf_counter()
    static = static_ends(imu, t_key, lc_fixes or fixes if mode == "lc" else fixes) if opts.zupt else None
    measured = static_white_noise(imu, t_key, static) if opts.static_noise else None
    if measured is not None and (measured[0] > noise.gyro_arw or measured[1] > noise.accel_vrw):
        # the IMU is noisier at rest than its model (vibration): never smooth with less noise than it shows
        noise = dataclasses.replace(noise, gyro_arw=max(noise.gyro_arw, measured[0]),
                                    accel_vrw=max(noise.accel_vrw, measured[1]))
    problem = build_problem(imu, frame, t_key, fixes, noise, opts, mode, epochs, lc_fixes, carrier, static)
    return Setup(problem, noise, fixes, lc_fixes, epochs, static, measured, rejected, time.perf_counter() - t0)


def _dd_converged(problem: Problem, values, max_iterations: int, iterations: list, rounds: int = 3):
    """`values` once the double differences are linearised where the solution is: re-linearised and re-optimised
    while the poses moved beyond the thresholds of `relinearise_dd` (at most `rounds` times)."""
    for _ in range(rounds):
        if not relinearise(problem, values):
            break
        problem.values = values
        values = optimize(problem, max_iterations)
        iterations.append(problem.iterations)
    return values


VCE_ROUNDS = 3      # LC: re-estimations of the noise (fixes' white share, IMU white noise) at most
VCE_TOL = 0.15      # ... until their variance factors are within this of one (relative)
MAX_IMU_VARIANCE_STEP = 16.0   # the IMU's white noise variance is raised by at most this factor per round


def _noise_groups(problem: Problem) -> np.ndarray:
    """The variance-component group of every row of the problem's graph: 0 the LC fixes with error states, 1 the IMU
    factors, -1 the rest."""
    tab = factor_table(problem)
    group = np.full(int(tab.start[-1]), -1, np.int64)
    i0 = len(problem.prior_factors)
    group[tab.start[i0]:tab.start[i0 + len(problem.imu_factors)]] = 1
    if problem.lc is not None:
        for i, kd in enumerate(tab.kinds):
            if kd is not None and kd[0] == "pos":
                group[tab.start[i]:tab.start[i + 1]] = 0
    return group


def set_imu_noise(problem: Problem, imu, noise: ImuErrorModel, earth_rotation: bool = True) -> None:
    """The IMU factors preintegrated again with the noise model `noise` (each interval's gravity and linearisation
    bias kept; scale/misalignment turn noise and the bridges' noise added as when built), in place."""
    frame, seg = problem.frame, problem.seg
    per = with_bridges(interval_params(noise, frame, seg, earth_rotation), imu, noise, frame, problem.t_key,
                       earth_rotation)
    set_gravity(per, np.array([p.n_gravity for p in problem.interval_params]))
    problem.interval_params = per
    problem.params = preintegration_params(noise, frame, earth_rotation)
    biases = [gtsam.imuBias.ConstantBias(b[:3], b[3:]) for b in problem.bias_hat]
    problem.pims = preintegrate(problem.params, seg, biases, per)
    problem.imu_factors = [gtsam.CombinedImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), B(k + 1), pim)
                           for k, pim in enumerate(problem.pims)]
    problem.graph = assemble_graph(problem)


def _variance_components(problem: Problem, values, rows: KeyframeRows, P: np.ndarray, opts: SmootherOptions,
                         iterations: list, imu, noise: ImuErrorModel):
    """LC: the noise the data show (Helmert's variance components, `dgcal.pos.smoother.covariance.variance_factors`),
    re-solved until it fits (within VCE_TOL, at most VCE_ROUNDS times): the fixes' white share
    (`dgcal.pos.smoother.fix_errors`, unless `opts.lc_fix_white_share` fixes it), and the IMU's white noise in
    motion, raised (never lowered) when the IMU factors' residuals exceed their model beyond its own uncertainty (a
    vehicle's vibration on the road; the static start and end show the engine's, `static_white_noise`). Returns the
    values, rows and covariances of the final solution, the IMU noise model and what was estimated."""
    lc = problem.lc
    K = len(problem.t_key)
    est_fix = lc is not None and opts.lc_fix_white_share is None
    est_imu = opts.motion_noise
    shares = [lc.white_share] if lc is not None else []
    imu_scale = 1.0
    f = np.ones(2)
    red = np.zeros(2)
    for _ in range(VCE_ROUNDS):
        ss, red = variance_factors(problem.graph, values, problem.blocks(), rows, _noise_groups(problem), 2)
        f = np.where(red > 0.5, ss / np.maximum(red, 0.5), 1.0)
        fix_moves = est_fix and abs(f[0] - 1.0) > VCE_TOL
        imu_moves = est_imu and f[1] > 1.0 + max(VCE_TOL, 3.0 * np.sqrt(2.0 / max(red[1], 1.0)))
        if not (fix_moves or imu_moves):
            break
        if fix_moves:
            set_white_share(lc, lc.white_share * f[0])
            shares.append(lc.white_share)
            problem.bias_factor_groups = [[] for _ in range(K)]
            for k, fac in process_factors(lc, values):
                problem.bias_factor_groups[k].append(fac)
            relinearise_lc(problem, values, force=True)
        if imu_moves:
            s = float(np.sqrt(min(f[1], MAX_IMU_VARIANCE_STEP)))
            imu_scale *= s
            noise = dataclasses.replace(noise, gyro_arw=noise.gyro_arw * s, accel_vrw=noise.accel_vrw * s)
            set_imu_noise(problem, imu, noise, opts.earth_rotation)
        problem.values = values
        values = optimize(problem, opts.max_iterations)
        iterations.append(problem.iterations)
        values = _dd_converged(problem, values, opts.max_iterations, iterations)
        rows = keyframe_rows(problem.graph, values, problem.blocks())
        P = smoothed_covariances(problem.graph, values, problem.blocks(), rows)
    info = {"imu_white_noise_scale": round(imu_scale, 3), "imu_variance_factor": round(float(f[1]), 3),
            "imu_redundancy": round(float(red[1]), 1)}
    if lc is not None:
        info["lc_fix_errors"] = {"white_share": [round(float(x), 4) for x in shares],
                                 "variance_factor": round(float(f[0]), 3), "redundancy": round(float(red[0]), 1),
                                 "tau_s": lc.tau_s}
    return values, rows, P, noise, info


def smooth(imu, fixes: GnssFixes, grade: str | ImuErrorModel, opts: SmootherOptions | None = None,
           mode: str = "tc", gnss=None, lc_fixes: GnssFixes | None = None, frame: NavFrame | None = None,
           second_pass: bool = True, carrier: CarrierInput | None = None) -> NavSolution:
    """Smoothed trajectory over the whole flight.

    imu: `dgcal.pos.ins.imu_data.ImuData` (body FRD increments). fixes: GNSS positions to initialise (SPP) and, in LC
    mode, the measurements unless `lc_fixes` is given. gnss: `GnssObservations` (TC mode). grade: an
    `ImuErrorModel` or a preset name (the smoother carries its `smoother_noise()`). The keyframes are the
    GNSS epochs (TC) or fix times (LC) in the IMU span. carrier: double differences against a base station
    (TC): they replace the pseudoranges of their keyframes (`dgcal.pos.smoother.carrier`).
    """
    opts = opts or SmootherOptions()
    su = setup_problem(imu, fixes, grade, opts, mode, gnss, lc_fixes, frame, carrier)
    problem, noise, static, measured, rejected = su.problem, su.noise, su.static, su.measured, su.rejected
    fixes, lc_fixes, epochs, frame, t_key = su.fixes, su.lc_fixes, su.epochs, problem.frame, problem.t_key
    timing = {"build_s": su.build_s}
    iterations = []
    coarse = _coarse_noise(noise)
    if coarse is not None:
        # a very precise IMU makes the initial attitude error (the pseudo-attitude's pitch misses the angle of
        # attack by degrees) a huge, badly conditioned residual on which LM stalls at iteration 0: solve with
        # tactical-grade noise first and start the real model from there
        t0 = time.perf_counter()
        p0 = build_problem(imu, frame, t_key, fixes, coarse, opts, mode, epochs, lc_fixes, carrier, static)
        problem.values = optimize(p0, opts.max_iterations)
        iterations.append(p0.iterations)
        timing["coarse_pass_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    # gravity follows the track: the initial track can be far off between fixes (an SPP gap is interpolated, the
    # pseudo-attitude misplaces the IMU), but after two iterations the positions are within a metre of where the
    # GNSS puts them; each interval's gravity is set there before the iterations go on (so the second pass rarely
    # finds gravity to change)
    def gravity_at_track(n: int, vals) -> bool:
        if n != 2:
            return False
        update_gravity(problem, read_states(problem, vals).p_nav)
        relinearise(problem, vals)
        return True
    values = optimize(problem, opts.max_iterations, gravity_at_track)
    iterations.append(problem.iterations)
    values = _dd_converged(problem, values, opts.max_iterations, iterations)
    velocity_info = None
    lc_v = (lc_fixes if lc_fixes is not None else fixes) if mode == "lc" else None
    if lc_v is not None and lc_v.v_ecef is not None and velocity_mode(opts.lc_velocity) == "auto":
        velocity_info = lc_velocities_auto(problem, values, lc_v) if not lc_v.velocity_on_time else {"on_time": True}
    timing["optimize_s"] = time.perf_counter() - t0
    sol = read_states(problem, values)
    t0 = time.perf_counter()
    # one linearisation at the solution serves the outlier test, the residuals, the covariances and the forward
    # pass, unless the second pass moves the solution
    rows = keyframe_rows(problem.graph, values, problem.blocks())
    dropped = screen_dd(problem, values, opts.dd_outlier_sigma) if opts.dd_outlier_sigma else 0
    post = reject_outliers(problem, rows, opts.gnss_outlier_sigma) if opts.gnss_outlier_sigma else []
    rejected += post
    reoptimise = False
    added = bool(velocity_info and velocity_info.get("factors"))
    if (dropped or post or added) and not second_pass:
        problem.values = values
        values = _dd_converged(problem, optimize(problem, opts.max_iterations), opts.max_iterations, iterations)
        sol = read_states(problem, values)
        rows = None
    if second_pass:
        # gravity along the solved track and the biases, from pass one; re-optimised when they (or the rejections)
        # changed the problem materially
        reoptimise = refine_imu(problem, noise, sol) or dropped or post or added
        if reoptimise:
            problem.values = values
            values = optimize(problem, opts.max_iterations)
            iterations.append(problem.iterations)
            values = _dd_converged(problem, values, opts.max_iterations, iterations)
            sol = read_states(problem, values)
            rows = None
    if rows is None:
        rows = keyframe_rows(problem.graph, values, problem.blocks())
    timing["second_pass_s"] = time.perf_counter() - t0
    P = None
    vce_info: dict = {}
    if opts.covariances:
        t0 = time.perf_counter()
        P, dx = smoothed_covariances(problem.graph, values, problem.blocks(), rows, step=True)
        if step_left(P, dx) > STEP_LEFT:
            # gtsam stops on the cost's relative change (1e-5); a step still material somewhere sends it on
            problem.values = values
            values = optimize(problem, opts.max_iterations, resume=True)
            iterations.append(problem.iterations)
            values = _dd_converged(problem, values, opts.max_iterations, iterations)
            sol = read_states(problem, values)
            rows = keyframe_rows(problem.graph, values, problem.blocks())
            P = smoothed_covariances(problem.graph, values, problem.blocks(), rows)
        if mode == "lc":
            values, rows, P, noise, vce_info = _variance_components(problem, values, rows, P, opts, iterations, imu,
                                                                    noise)
            sol = read_states(problem, values)
        timing["covariance_s"] = time.perf_counter() - t0
    sol.residuals = gnss_residuals(problem, values, rows)
    sol.info = {"mode": mode, "keyframes": len(t_key), "factors": problem.graph.size(),
                "error_final": problem.graph.error(values), "systems": problem.systems,
                "lm_iterations": iterations, "second_pass_reoptimised": bool(second_pass and reoptimise),
                "dd_rows_dropped": dropped,
                "static_keyframes": int(static.sum()) if static is not None else 0,
                "static_white_noise": None if measured is None else
                {"gyro_arw_deg_rt_h": round(float(np.degrees(measured[0]) * 60.0), 4),
                 "accel_vrw_m_s_rt_h": round(float(measured[1] * 60.0), 4)},
                "imu_noise_used": {"gyro_arw_deg_rt_h": round(float(np.degrees(noise.gyro_arw) * 60.0), 4),
                                   "accel_vrw_m_s_rt_h": round(float(noise.accel_vrw * 60.0), 4)},
                "static_start_end_s": _static_spans(t_key, static), "gnss_rejected": rejected}
    if problem.lc is not None:
        sol.info["lc_fix_errors"] = {"white_share": [problem.lc.white_share], "tau_s": problem.lc.tau_s}
    sol.info.update(vce_info)
    if velocity_info is not None:
        sol.info["lc_velocity"] = velocity_info
    if opts.covariances:
        add_marginals(sol, problem, values, rows, P)
        if problem.dd and problem.carrier is not None:
            add_atmosphere_budget(sol, problem)
        add_tilt_budget(sol, noise)
        add_heading_budget(sol, noise)
    sol.info["timing"] = {k: round(v, 2) for k, v in timing.items()}
    sol.problem, sol.values, sol.rows, sol.imu_noise = problem, values, rows, noise
    return sol
