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
from dgcal.pos.smoother.carrier import atmosphere_position_covariance, dd_residuals, keyframe_dd_factors
from dgcal.pos.smoother.code_bias import CB, CodeBiasArcs, bias_estimates, bias_process_factors, code_bias_arcs, \
    insert_initial
from dgcal.pos.smoother.covariance import KeyframeBlocks, smoothed_covariances
from dgcal.pos.smoother.static import static_ends, static_white_noise, zero_motion_factors
from dgcal.pos.smoother.factors import (B, CLK, DRIFT, V, X, ZERO, clock_factors, doppler_factors, position_factor,
                                  pseudorange_factors, velocity_factor)
from dgcal.pos.smoother.preintegration import (gravity_correction_b, interval_params, preintegrate,
                                               preintegration_params, split_at_keyframes)
from dgcal.pos.smoother.initial import (GnssFixes, anchor_attitude, initial_clocks, initial_track,
                               propagate_attitude)
from dgcal.pos.smoother.integrity import assemble_graph, reject_outliers, screen_fixes, with_bridges


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
    lc_velocity: bool = True
    max_iterations: int = 30
    covariances: bool = True
    dd_outlier_sigma: float = 5.0   # TC with a base: double differences beyond this (normalised) are dropped
    zupt: bool = True               # a static start/end of the data as zero-motion information (smoother.static)
    static_noise: bool = True       # raise the IMU white noise to what the static start/end shows
    gnss_outlier_sigma: float | None = 5.0   # GNSS epoch screening and post-fit rejection (None: off)
    code_bias: bool = True          # TC: each satellite's slow pseudorange error as a Gauss-Markov state
    code_bias_tau_s: float = 1800.0  # its correlation time (s; broadcast orbit, clock and atmosphere errors)


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
    problem: object = field(default=None, repr=False)  # the Problem it came from (forward pass, outputs)
    values: object = field(default=None, repr=False)  # its gtsam Values (the linearisation point)

    @property
    def cov_p_nav(self) -> np.ndarray:
        """Position covariance (K,3,3) in nav axes, m^2."""
        R = self.R_body_to_nav
        return R @ self.cov_pose[:, 3:, 3:] @ np.swapaxes(R, 1, 2)


@dataclass
class Problem:
    """A built factor graph with its initial values and the bookkeeping needed to read it back."""

    graph: object
    values: object
    frame: NavFrame
    t_key: np.ndarray
    systems: list
    pims: list
    epoch_factors: list  # per keyframe: list of (kind, sat, factor) GNSS factors
    imu_factors: list
    clock_factor_groups: list
    prior_factors: list
    n_sat: np.ndarray
    gnss_update: np.ndarray
    omega_b: np.ndarray
    params: object = None
    iterations: int = 0
    accel: np.ndarray | None = None  # the (gravity-corrected) accelerometer rates the IMU factors used
    dd: dict = field(default_factory=dict)  # keyframe -> DDFactorData (TC with a base station)
    lever_arm_b: np.ndarray | None = None
    carrier: CarrierInput | None = None
    code_bias: CodeBiasArcs | None = None   # TC: the satellites' code-bias arcs (dgcal.pos.smoother.code_bias)
    bias_factor_groups: list = field(default_factory=list)  # per keyframe: the code-bias process factors ending there

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
        return KeyframeBlocks(len(self.t_key) if K is None else K, self.systems, first, self.code_bias)


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
    pims = preintegrate(params, seg, biases, per_interval)

    p_ant, v_ant = initial_track(t_key, fixes, frame)
    a, R_a = anchor_attitude(t_key, v_ant)
    R = propagate_attitude(pims, a, R_a, p_ant, v_ant)
    p_imu = p_ant - np.einsum("kij,j->ki", R, lever)
    omega_b = _imu_rate_at(imu, t_key)

    values = gtsam.Values()
    for k in range(K):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(R[k]), p_imu[k]))
        values.insert(V(k), v_ant[k].copy())
        values.insert(B(k), biases[min(k, K - 2)])

    prior = []
    rs = np.radians(opts.prior_rot_sigma_deg)
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
    if mode == "tc" and carrier is not None:
        dd = keyframe_dd_factors(t_key, carrier.at(t_key), lever, frame, carrier.phase_corr, carrier.code_corr, X)
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
                epoch_factors[k].append(("dd", f))
                n_sat[k] = len(set(data.cur.sat.tolist()) | set(data.cur.ref.tolist()))
                gnss_update[k] = True
            if ep is None or ep.n == 0:
                continue
            r_approx = frame.to_ecef(p_ant[k])
            if k not in dd:
                n_sat[k] = ep.n
                gnss_update[k] = True
                for f in pseudorange_factors(k, ep, r_approx, lever, ecef_T_nav, opts.huber_k,
                                             bias_key=arcs.key if arcs is not None else None):
                    epoch_factors[k].append(("pr", f))
            if opts.use_doppler:
                for f in doppler_factors(k, ep, r_approx, lever, omega_b[k], ecef_T_nav,
                                         opts.huber_k):
                    epoch_factors[k].append(("dop", f))
    else:
        lc = lc_fixes if lc_fixes is not None else fixes
        idx = np.clip(np.searchsorted(t_key, lc.t - 1e-3), 0, K - 1)
        for j, k in enumerate(idx):
            if abs(t_key[k] - lc.t[j]) > 1e-3 or not np.all(np.isfinite(lc.p_ecef[j])):
                continue
            noise = lc.sigma_ned[j] if lc.cov_ned is None else lc.cov_ned[j]
            epoch_factors[k].append(("pos", position_factor(k, frame.from_ecef(lc.p_ecef[j]), noise,
                                                            lever, opts.huber_k)))
            gnss_update[k] = True
            n_sat[k] = 1
            if opts.lc_velocity and lc.v_ecef is not None and np.all(np.isfinite(lc.v_ecef[j])):
                v_nav = lc.v_ecef[j] @ frame.R_nav_to_ecef
                v_lever = R[k] @ np.cross(omega_b[k], lever)
                epoch_factors[k].append(("vel", velocity_factor(k, v_nav - v_lever, lc.sigma_v_ned[j])))

    if static is not None and static.any():
        for k, kind, f in zero_motion_factors(static, t_key):
            epoch_factors[k].append((kind, f))
    problem = Problem(None, values, frame, t_key, systems, pims, epoch_factors, imu_factors, clock_groups, prior,
                      n_sat, gnss_update, omega_b, params, dd={k: v[1] for k, v in dd.items()}, lever_arm_b=lever,
                      carrier=carrier, code_bias=arcs if arcs is not None and len(arcs) else None,
                      bias_factor_groups=bias_groups)
    problem.graph = assemble_graph(problem)
    return problem


def rebuild_imu(problem: Problem, imu, imu_noise: ImuErrorModel, opts: SmootherOptions, first: NavSolution) -> Problem:
    """The same problem with the IMU factors re-preintegrated about `first`'s biases and with the gravity
    correction of `first`'s trajectory (all other factors are reused)."""
    t_key = problem.t_key
    accel = imu.accel_m_s2 + gravity_correction_b(imu.t, first.t, first.R_body_to_nav, first.p_nav, problem.frame)
    seg = split_at_keyframes(imu.t, imu.gyro_rad_s, accel, t_key, imu.dt[0])
    biases = [gtsam.imuBias.ConstantBias(b[:3], b[3:]) for b in first.bias[:-1]]
    pims = preintegrate(problem.params, seg, biases,
                        with_bridges(interval_params(imu_noise, problem.frame, seg, opts.earth_rotation), imu,
                                     imu_noise, problem.frame, t_key, opts.earth_rotation))
    imu_factors = [gtsam.CombinedImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), B(k + 1), pims[k])
                   for k in range(len(t_key) - 1)]
    new = dataclasses.replace(problem, pims=pims, imu_factors=imu_factors, accel=accel)
    new.graph = assemble_graph(new)
    return new


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
                              c.code_corr, X)
    for k in range(len(problem.t_key)):
        fl = [(kind, f) for kind, f in problem.epoch_factors[k] if kind != "dd"]
        if k in new:
            fl.insert(0, ("dd", new[k][0]))
        problem.epoch_factors[k] = fl
    problem.dd = {k: v[1] for k, v in new.items()}
    problem.graph = assemble_graph(problem)
    return dropped


def optimize(problem: Problem, max_iterations: int = 30):
    """Levenberg-Marquardt over the whole graph; returns the optimised gtsam.Values."""
    p = gtsam.LevenbergMarquardtParams()
    p.setMaxIterations(max_iterations)
    # stop when the cost changes by less than 1e-5 relative: with costs of 1e3-1e5 that is a chi-square change far
    # below one, i.e. nothing the covariances could resolve (1e-7 bought two more iterations)
    p.setRelativeErrorTol(1e-5)
    p.setAbsoluteErrorTol(1e-7)
    # a navigation-grade IMU makes the normal equations so stiff that only heavily damped steps succeed:
    # let lambda grow past gtsam's default bound (1e5) instead of stopping without a single step
    p.setlambdaUpperBound(1e12)
    # eliminate keyframe by keyframe: the graph is a chain of keyframe blocks, and COLAMD, blind to that, takes
    # more iterations once the satellites' code biases add thousands of scalar variables
    p.setOrdering(problem.ordering())
    opt = gtsam.LevenbergMarquardtOptimizer(problem.graph, problem.values, p)
    values = opt.optimize()
    problem.iterations = opt.iterations()
    return values


def read_states(problem: Problem, values) -> NavSolution:
    """Keyframe states from gtsam Values (no covariances)."""
    K = len(problem.t_key)
    p = np.empty((K, 3))
    v = np.empty((K, 3))
    R = np.empty((K, 3, 3))
    b = np.empty((K, 6))
    for k in range(K):
        pose = values.atPose3(X(k))
        p[k] = pose.translation()
        R[k] = pose.rotation().matrix()
        v[k] = values.atPoint3(V(k))
        b[k] = values.atConstantBias(B(k)).vector()
    clock = {s: np.array([values.atDouble(CLK(s, k)) for k in range(K)]) for s in problem.systems}
    drift = (np.array([values.atDouble(DRIFT(k)) for k in range(K)]) if problem.systems
             else np.zeros(K))
    sol = NavSolution(problem.frame, problem.t_key.copy(), p, v, R, b, clock, drift,
                      n_sat=problem.n_sat.copy(), gnss_update=problem.gnss_update.copy())
    if problem.code_bias is not None:
        sol.code_bias = bias_estimates(problem.code_bias, values)
    return sol


def gnss_residuals(problem: Problem, values) -> dict:
    """Post-fit residuals of the GNSS factors: kind -> (keyframe index (M,), residual (M,) m or m/s, sigma (M,))."""
    out: dict = {}
    for k, fl in enumerate(problem.epoch_factors):
        for kind, f in fl:
            if kind == "dd":
                data = problem.dd[k]
                e, sig = dd_residuals(data, values, X, problem.lever_arm_b, problem.frame)
                names = np.where(data.cur.kind == 1, "ddc", np.where(data.cur.mode == 1, "ddp_float", "ddp"))
                for j in range(len(e)):
                    out.setdefault(str(names[j]), []).append((k, e[j], sig[j]))
                continue
            e = np.atleast_1d(f.unwhitenedError(values))
            w = np.atleast_1d(f.whitenedError(values))
            for j in range(len(e)):
                out.setdefault(kind, []).append((k, e[j], e[j] / w[j] if w[j] != 0 else np.nan))
    return {kind: tuple(np.array(c) for c in zip(*rows)) for kind, rows in out.items()}


def add_marginals(sol: NavSolution, problem: Problem, values) -> None:
    """Fill cov_pose / cov_vel (and the full keyframe block `cov_block`) from the linearised graph."""
    P = smoothed_covariances(problem.graph, values, problem.blocks())
    sol.cov_pose = P[:, :6, :6].copy()
    sol.cov_vel = P[:, 6:9, 6:9].copy()
    sol.cov_block = P


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
    if problem.values.exists(ZERO()):
        vals.insert(ZERO(), 0.0)
    return vals


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
    timing = {}
    t0 = time.perf_counter()
    static = static_ends(imu, t_key, lc_fixes or fixes if mode == "lc" else fixes) if opts.zupt else None
    measured = static_white_noise(imu, t_key, static) if opts.static_noise else None
    if measured is not None and (measured[0] > noise.gyro_arw or measured[1] > noise.accel_vrw):
        # the IMU is noisier at rest than its model (vibration): never smooth with less noise than it shows
        noise = dataclasses.replace(noise, gyro_arw=max(noise.gyro_arw, measured[0]),
                                    accel_vrw=max(noise.accel_vrw, measured[1]))
    problem = build_problem(imu, frame, t_key, fixes, noise, opts, mode, epochs, lc_fixes, carrier, static)
    timing["build_s"] = time.perf_counter() - t0
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
    values = optimize(problem, opts.max_iterations)
    timing["optimize_s"] = time.perf_counter() - t0
    iterations.append(problem.iterations)
    sol = read_states(problem, values)
    dropped = screen_dd(problem, values, opts.dd_outlier_sigma) if opts.dd_outlier_sigma else 0
    post = reject_outliers(problem, values, opts.gnss_outlier_sigma) if opts.gnss_outlier_sigma else []
    rejected += post
    if (dropped or post) and not second_pass:
        problem.values = values
        values = optimize(problem, opts.max_iterations)
        sol = read_states(problem, values)
    if second_pass:
        # re-preintegrate with the gravity correction and about the estimated biases, start from pass one
        t0 = time.perf_counter()
        problem = rebuild_imu(problem, imu, noise, opts, sol)
        problem.values = values
        values = optimize(problem, opts.max_iterations)
        sol = read_states(problem, values)
        timing["second_pass_s"] = time.perf_counter() - t0
        iterations.append(problem.iterations)
    sol.residuals = gnss_residuals(problem, values)
    sol.info = {"mode": mode, "keyframes": len(t_key), "factors": problem.graph.size(),
                "error_final": problem.graph.error(values), "systems": problem.systems,
                "lm_iterations": iterations, "dd_rows_dropped": dropped,
                "static_keyframes": int(static.sum()) if static is not None else 0,
                "static_white_noise": None if measured is None else
                {"gyro_arw_deg_rt_h": round(float(np.degrees(measured[0]) * 60.0), 4),
                 "accel_vrw_m_s_rt_h": round(float(measured[1] * 60.0), 4)},
                "imu_noise_used": {"gyro_arw_deg_rt_h": round(float(np.degrees(noise.gyro_arw) * 60.0), 4),
                                   "accel_vrw_m_s_rt_h": round(float(noise.accel_vrw * 60.0), 4)},
                "static_start_end_s": _static_spans(t_key, static), "gnss_rejected": rejected}
    if opts.covariances:
        t0 = time.perf_counter()
        add_marginals(sol, problem, values)
        if problem.dd and problem.carrier is not None:
            add_atmosphere_budget(sol, problem)
        timing["covariance_s"] = time.perf_counter() - t0
    sol.info["timing"] = {k: round(v, 2) for k, v in timing.items()}
    sol.problem, sol.values = problem, values
    return sol
