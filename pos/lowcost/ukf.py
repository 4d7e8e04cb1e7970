"""15-state GPS/INS Unscented Kalman Filter of seed 000 (eq. 1-19): a forward filter alternative to the smoother.

State (NED tangent frame `dgcal.pos.ins.nav_frame.NavFrame`, body FRD):
  x = [p_nav (3) m, v_nav (3) m/s, roll, pitch, yaw (3) rad, b_a (3) m/s^2, b_g (3) rad/s]
Process (seed eq. 1-4): p' = v; v' = R_body_to_nav(euler) (f - b_a) + g_nav; Euler rates from the
gyro rates (p, q, r) - b_g through the Z-Y-X kinematic matrix; biases are random walks. Optional earth
rate (default on) removes R^T omega_ie from the gyros and adds Coriolis, which the seed neglects.

Prediction (eq. 6-10): the state is augmented with the process noise (accelerometer and gyro white
noise held constant over the prediction interval, bias random-walk increments), scaled unscented
transform sigma points (alpha, beta, kappa of van der Merwe) are pushed through the strapdown equations
sample by sample — vectorised over the sigma points — and recombined. Update (eq. 11-19): sigma points of
the predicted state go through h (antenna position and velocity with the lever arm; H = [I6 0] when it is
zero, seed eq. 5); the measurement noise is additive, for which augmenting with n (eq. 11) is identical to
adding R to P_yy. Euler-angle differences are wrapped to (-pi, pi] around the central sigma point.

Beyond the seed (issue 27): states at the output rate where no fix is near (GNSS outages: predicted by the IMU
alone, the covariance growing as it propagates), and a start at any speed — roll and pitch from the accelerometers
(`level_attitude`), the heading from the GNSS course once moving (`UkfOptions.align_speed_mps`), unknown until then
(`HEADING_UNKNOWN_SIGMA_DEG`, yaw kept out of the sigma points).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from dgcal.fields.crs import ecef_to_geodetic
from dgcal.fields.frames import R_body_to_ned_from_rph, rph_from_R_body_to_ned
from dgcal.fields.io.formats import Trajectory
from dgcal.pos.ins.error_model import ImuErrorModel, imu_grade
from dgcal.pos.ins.integrity import bridge_densities
from dgcal.pos.ins.nav_frame import NavFrame

N_STATE = 15  # the seed's states; with GNSS error states 18
N_NOISE = 12  # accel white, gyro white, accel-bias rw, gyro-bias rw (+ GNSS error driving noise)
_YAW_FREE_VAR = 1e-10  # rad^2: yaw's variance inside the filter while the heading is unknown
HEADING_UNKNOWN_SIGMA_DEG = 180.0 / np.sqrt(3.0)  # the sigma of a heading uniform on the circle (no course yet)
_UNKNOWN_ACCEL_TAU_S = 1.0  # s: how long a horizontal acceleration of unknown direction is taken to last
_VEL_INDEPENDENT_S = 0.1  # s: GNSS velocity errors taken as independent at most this often (levelling)
_ANG = slice(6, 9)
_GNSS_ERR = slice(15, 18)


@dataclass
class UkfOptions:
    """Tuning: unscented scaling, initial sigmas, measurement use, lever arm (IMU -> antenna, body FRD, m)."""

    alpha: float = 0.5
    beta: float = 2.0
    kappa: float = 0.0
    lever_arm_b: np.ndarray = field(default_factory=lambda: np.zeros(3))
    # roll, pitch: sigmas of a level start (without `level_from_accel`, or too little data after the first fix);
    # heading: sigma of heading - GNSS course (crab, sideslip) when the heading is taken from the course
    init_att_sigma_deg: tuple = (5.0, 5.0, 15.0)
    # a start at any speed: roll and pitch from the accelerometers over `align_window_s` after the first fix, matched
    # to the GNSS velocity change (so a turning or accelerating start levels too; `level_attitude`); heading = GNSS
    # course once the ground speed reaches `align_speed_mps` (unknown until then: HEADING_UNKNOWN_SIGMA_DEG)
    level_from_accel: bool = True
    align_window_s: float = 2.0
    align_speed_mps: float = 0.5
    init_vel_sigma_mps: float = 0.5
    init_pos_sigma_m: float = 3.0
    use_velocity: bool = True
    earth_rotation: bool = True
    # unmodelled scale factor and misalignment errors, entered as process noise whose variance over `scale_corr_s`
    # equals that of the systematic error they stand for, per axis: (scale * w_i)^2 + misalign^2 * sum_j!=i w_j^2
    # for the gyro rates w (rad/s), and the same for the specific force's change from its running mean (its
    # steady part acts as a bias, which the bias states take); None: the IMU error model's sigmas
    gyro_scale_noise: float | None = None
    accel_scale_noise: float | None = None
    gyro_misalign_noise: float | None = None
    accel_misalign_noise: float | None = None
    scale_corr_s: float = 20.0
    f_mean_tau_s: float = 30.0
    # GNSS position errors are correlated over about a minute (multipath, orbits, atmosphere): three
    # first-order Gauss-Markov states (nav frame, m) carry them, with the fix sigma minus `gnss_white_m` as their
    # sigma and `gnss_corr_s` as correlation time; the white part is the measurement noise. Off: the seed's
    # 15 states with the fixes taken as white (position sigmas then far too small at 50 Hz).
    gnss_error_states: bool = True
    gnss_corr_s: float = 60.0
    gnss_white_m: float = 0.2


@dataclass
class UkfSolution:
    """Filtered states at the epochs `t` (GPS s: every GNSS fix, and the output grid where no fix is near, e.g. in
    GNSS outages, where `updated` is False): IMU positions/velocities in `frame` (NED), Euler angles (deg), biases
    (accel m/s^2, gyro rad/s), the GNSS position errors (K,3, m, nav; zeros without error states) and the
    covariances (K,n,n; n = 15, or 18 with the GNSS error states) in the state's units (rad for angles); before the
    heading is known its variance is that of a uniform heading, uncorrelated."""

    frame: NavFrame
    t: np.ndarray
    p_nav: np.ndarray
    v_nav: np.ndarray
    rph_deg: np.ndarray
    bias: np.ndarray
    P: np.ndarray
    innovations: np.ndarray
    nis: np.ndarray
    info: dict = field(default_factory=dict)
    gnss_error: np.ndarray | None = None
    updated: np.ndarray | None = None        # (K,) bool: a GNSS fix updated the state at this epoch
    heading_known: np.ndarray | None = None  # (K,) bool: False before the heading came from the GNSS course

    @property
    def sigma_p_nav(self) -> np.ndarray:
        """1-sigma of the IMU position along the nav axes (K,3) m."""
        return np.sqrt(np.einsum("kii->ki", self.P[:, 0:3, 0:3]))

    @property
    def sigma_rph_deg(self) -> np.ndarray:
        """1-sigma roll, pitch, yaw (deg) from the filter covariance (K,3)."""
        return np.degrees(np.sqrt(np.einsum("kii->ki", self.P[:, _ANG, _ANG])))

    @property
    def R_body_to_nav(self) -> np.ndarray:
        """Rotation body FRD -> nav NED at each epoch (K,3,3)."""
        return R_body_to_ned_from_rph(self.rph_deg[:, 0], self.rph_deg[:, 1], self.rph_deg[:, 2])

    def to_trajectory(self):
        """The filtered states as a `dgcal.fields.io.formats.Trajectory` (geodetic, local-NED velocity and attitude,
        sigmas from the filter covariance) for the trajectory CSV and the DG / mounting tools."""
        R_nav_to_ned = self.frame.R_nav_to_local_ned(self.p_nav)  # to the local NED axes (earth curvature)
        geo = ecef_to_geodetic(self.frame.to_ecef(self.p_nav))
        v = np.einsum("kij,kj->ki", R_nav_to_ned, self.v_nav)
        rph = rph_from_R_body_to_ned(R_nav_to_ned @ self.R_body_to_nav)
        P_p = R_nav_to_ned @ self.P[:, 0:3, 0:3] @ np.swapaxes(R_nav_to_ned, 1, 2)
        sig = np.column_stack([np.sqrt(np.einsum("kii->ki", P_p)), self.sigma_rph_deg])
        return Trajectory(t=self.t.copy(), lat=geo[:, 0], lon=geo[:, 1], h=geo[:, 2], v_ned=v, rph=rph, sigma=sig)


def wrap_pi(a: np.ndarray) -> np.ndarray:
    """Angles (rad) wrapped to (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(a, float), 2 * np.pi)


def _R_body_to_nav_from_euler(e: np.ndarray) -> np.ndarray:
    """R_body_to_nav for Euler angles (S,3) rad: Rz(yaw) Ry(pitch) Rx(roll), seed eq. 2's DCM; (S,3,3)."""
    cr, sr = np.cos(e[:, 0]), np.sin(e[:, 0])
    cp, sp = np.cos(e[:, 1]), np.sin(e[:, 1])
    cy, sy = np.cos(e[:, 2]), np.sin(e[:, 2])
    R_body_to_nav = np.empty((len(e), 3, 3))
    R_body_to_nav[:, 0, 0] = cy * cp
    R_body_to_nav[:, 0, 1] = -sy * cr + cy * sp * sr
    R_body_to_nav[:, 0, 2] = sy * sr + cy * sp * cr
    R_body_to_nav[:, 1, 0] = sy * cp
    R_body_to_nav[:, 1, 1] = cy * cr + sy * sp * sr
    R_body_to_nav[:, 1, 2] = -cy * sr + sy * sp * cr
    R_body_to_nav[:, 2, 0] = -sp
    R_body_to_nav[:, 2, 1] = cp * sr
    R_body_to_nav[:, 2, 2] = cp * cr
    return R_body_to_nav


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b for a fixed vector a (3,) and rows b (S,3)."""
    out = np.empty_like(b)
    out[:, 0] = a[1] * b[:, 2] - a[2] * b[:, 1]
    out[:, 1] = a[2] * b[:, 0] - a[0] * b[:, 2]
    out[:, 2] = a[0] * b[:, 1] - a[1] * b[:, 0]
    return out


def _R_tilt(rp: np.ndarray) -> np.ndarray:
    """Ry(pitch) Rx(roll) (3,3): body FRD -> the heading-aligned level frame, for roll, pitch (2,) rad."""
    return _R_body_to_nav_from_euler(np.array([[rp[0], rp[1], 0.0]]))[0]


def _exp_so3(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector phi (3,) rad (Rodrigues)."""
    a = float(np.linalg.norm(phi))
    K = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if a < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + np.sin(a) / a * K + (1.0 - np.cos(a)) / a ** 2 * K @ K


def euler_rates(e: np.ndarray, w_b: np.ndarray) -> np.ndarray:
    """Seed eq. 3: Euler-angle rates (S,3) rad/s from body rates w_b = (p, q, r) (S,3) rad/s."""
    sr, cr = np.sin(e[:, 0]), np.cos(e[:, 0])
    tp, sec = np.tan(e[:, 1]), 1.0 / np.cos(e[:, 1])
    q, r = w_b[:, 1], w_b[:, 2]
    a = q * sr + r * cr
    out = np.empty_like(w_b)
    out[:, 0] = w_b[:, 0] + a * tp
    out[:, 1] = q * cr - r * sr
    out[:, 2] = a * sec
    return out


class SigmaPoints:
    """Scaled unscented transform (van der Merwe): sigma points and weights for dimension n."""

    def __init__(self, n: int, alpha: float, beta: float, kappa: float):
        self.n = n
        lam = alpha ** 2 * (n + kappa) - n
        self.gamma = np.sqrt(n + lam)
        self.wm = np.full(2 * n + 1, 0.5 / (n + lam))
        self.wc = self.wm.copy()
        self.wm[0] = lam / (n + lam)
        self.wc[0] = lam / (n + lam) + 1 - alpha ** 2 + beta

    def points(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """(2n+1, n) sigma points of N(x, P) (seed eq. 7 / 12 with lambda -> gamma = sqrt(n + lambda))."""
        S = _chol(P) * self.gamma
        return np.vstack([x, x + S.T, x - S.T])


def _chol(P: np.ndarray) -> np.ndarray:
    P = 0.5 * (P + P.T)
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(P)
        return V * np.sqrt(np.clip(w, 1e-18, None))


def _mean_cov(chi: np.ndarray, sp: SigmaPoints, ang: slice | None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean and covariance of sigma points (eq. 9-10), angles averaged as wrapped offsets."""
    d = chi - chi[0]
    if ang is not None:
        d[:, ang] = wrap_pi(d[:, ang])
    m = chi[0] + sp.wm @ d
    if ang is not None:
        m[ang] = wrap_pi(m[ang])
    r = d - (sp.wm @ d)
    return m, (r * sp.wc[:, None]).T @ r


class StrapdownUkf:
    """The filter: `predict(dtheta, dvel, dt)` over a block of IMU samples, `update(z, R)` with a GNSS fix.

    With `opts.gnss_error_states` the state carries three Gauss-Markov GNSS position errors after the seed's 15
    (`sigma_gnss` sets their steady-state sigma, nav axes, m; updated per fix)."""

    def __init__(self, frame: NavFrame, x0: np.ndarray, P0: np.ndarray, noise: ImuErrorModel, opts: UkfOptions):
        self.frame, self.opts, self.noise = frame, opts, noise
        self.x = np.asarray(x0, float).copy()
        self.P = np.asarray(P0, float).copy()
        self.n_x = len(self.x)
        self.gm = self.n_x > N_STATE
        self.n_q = N_NOISE + (3 if self.gm else 0)
        self.sigma_gnss = np.ones(3)
        self.heading_known = True   # False: yaw unknown (no course yet), kept out of the sigma points
        self.f_mean: np.ndarray | None = None   # running mean of the specific force (m/s^2, body)
        self.g_nav = np.array([0.0, 0.0, frame.gravity])
        self.w_ie = np.array(frame.omega_ie_nav) if opts.earth_rotation else np.zeros(3)
        self.sp_aug = SigmaPoints(self.n_x + self.n_q, opts.alpha, opts.beta, opts.kappa)
        self.sp = SigmaPoints(self.n_x, opts.alpha, opts.beta, opts.kappa)

    @staticmethod
    def _axis_var(x2: np.ndarray, scale: float, mis: float) -> np.ndarray:
        """Per-axis variance (3,) of scale (fraction) and misalignment (rad) errors for mean squares x2 (3,)."""
        return scale ** 2 * x2 + mis ** 2 * (x2.sum() - x2)

    def _noise_cov(self, T: float, w2: np.ndarray, df2: np.ndarray, bridge=None) -> np.ndarray:
        """Covariance of the augmented process noise over a block of length T (s); w2, df2 the per-axis mean
        squares of the rates (rad/s)^2 and of the specific force's change from its running mean (m/s^2)^2;
        `bridge`: per-axis white-noise densities (gyro rad^2/s, accel (m/s)^2/s) of bridged IMU samples in the block
        (dgcal.pos.ins.integrity), added as the block's constant rate errors (density / T)."""
        n, o = self.noise, self.opts
        c = o.scale_corr_s / T
        pick = lambda v, d: d if v is None else v  # noqa: E731
        q_g = n.gyro_arw ** 2 / T + self._axis_var(w2, pick(o.gyro_scale_noise, n.gyro_scale_sigma),
                                                    pick(o.gyro_misalign_noise, n.gyro_misalign_sigma)) * c
        v_a = self._axis_var(df2, pick(o.accel_scale_noise, n.accel_scale_sigma),
                             pick(o.accel_misalign_noise, n.accel_misalign_sigma))
        q_a = n.accel_vrw ** 2 / T + v_a * c
        if bridge is not None:
            q_g = q_g + bridge[0] / T
            q_a = q_a + bridge[1] / T
        # a specific force that stays away from its old mean (a climb's pitch) shifts the scale and misalignment
        # error for good: the bias takes it, a Gauss-Markov walk of that variance over `f_mean_tau_s`
        q_ba = n.accel_bias_rw ** 2 * T + v_a * (2.0 * T / o.f_mean_tau_s)
        q = list(q_a) + list(q_g) + list(q_ba) + [n.gyro_bias_rw ** 2 * T] * 3
        if self.gm:
            phi = np.exp(-T / self.opts.gnss_corr_s)
            q += list(self.sigma_gnss ** 2 * (1 - phi ** 2))
        return np.diag(q)

    def predict(self, dtheta: np.ndarray, dvel: np.ndarray, dt: np.ndarray, bridge=None) -> None:
        """Propagate through IMU increments (M,3) rad and m/s over intervals dt (M,) s (seed eq. 6-10); `bridge`:
        the per-axis noise densities (gyro, accel) of bridged samples in the block, or None."""
        T = float(dt.sum())
        w2 = np.mean((dtheta / dt[:, None]) ** 2, axis=0)
        f = dvel / dt[:, None]
        if self.f_mean is None:
            self.f_mean = f.mean(axis=0)
        df2 = np.mean((f - self.f_mean) ** 2, axis=0)
        a = min(1.0, T / self.opts.f_mean_tau_s)
        self.f_mean = (1 - a) * self.f_mean + a * f.mean(axis=0)
        nx = self.n_x
        n = nx + self.n_q
        self._decouple_yaw()
        xa = np.zeros(n)
        xa[:nx] = self.x
        Pa = np.zeros((n, n))
        Pa[:nx, :nx] = self.P
        Pa[nx:, nx:] = self._noise_cov(T, w2, df2, bridge)
        chi = self.sp_aug.points(xa, Pa)
        p, v, e = chi[:, 0:3].copy(), chi[:, 3:6].copy(), chi[:, 6:9].copy()
        ba, bg = chi[:, 9:12], chi[:, 12:15]
        na, ng = chi[:, nx:nx + 3], chi[:, nx + 3:nx + 6]
        # earth rate in body axes, frozen over the (short) block
        w_ie_b = _R_body_to_nav_from_euler(e).transpose(0, 2, 1) @ self.w_ie
        w_cor = 2.0 * self.w_ie
        h2 = 0.0
        for k in range(len(dt)):
            h = dt[k]
            w_b = dtheta[k] / h - bg - ng - w_ie_b
            e_mid = e + (0.5 * h) * euler_rates(e, w_b)  # midpoint step: second order in h
            e_new = e + h * euler_rates(e_mid, w_b)
            f_b = dvel[k] / h - ba - na
            sf = np.einsum("sij,sj->si", _R_body_to_nav_from_euler(e_mid), f_b)
            if not self.heading_known:
                h2 += self._unknown_heading_accel(sf, e_mid[:, 2], T) * h
            a_nav = sf - _cross(w_cor, v)
            a_nav[:, 2] += self.g_nav[2]
            v_new = v + h * a_nav
            p = p + (0.5 * h) * (v + v_new)
            v, e = v_new, e_new
        chi_x = np.empty((len(chi), nx))
        chi_x[:, 0:3], chi_x[:, 3:6], chi_x[:, 6:9] = p, v, wrap_pi(e)
        chi_x[:, 9:12], chi_x[:, 12:15] = ba + chi[:, nx + 6:nx + 9], bg + chi[:, nx + 9:nx + 12]
        if self.gm:
            chi_x[:, _GNSS_ERR] = np.exp(-T / self.opts.gnss_corr_s) * chi[:, _GNSS_ERR] + chi[:, nx + 12:nx + 15]
        self.x, self.P = _mean_cov(chi_x, self.sp_aug, _ANG)
        if not self.heading_known:
            S = h2 / T   # the horizontal acceleration of unknown direction as white noise (`_unknown_heading_accel`)
            self.P[3:5, 3:5] += np.eye(2) * S * T
            self.P[0:2, 0:2] += np.eye(2) * S * T ** 3 / 3.0
            self.P[0:2, 3:5] += np.eye(2) * S * T ** 2 / 2.0
            self.P[3:5, 0:2] += np.eye(2) * S * T ** 2 / 2.0
            self._decouple_yaw()

    def _unknown_heading_accel(self, sf: np.ndarray, yaw: np.ndarray, T: float) -> float:
        """While the heading is unknown: the levelled horizontal specific force of the mean beyond what its tilt and
        bias uncertainty can explain (3 sigma, from the sigma points) is an acceleration of unknown direction: taken
        out of the sigma points' `sf` (S,3, nav, in place) and returned as the density (m/s^2)^2 s of the white
        acceleration that stands for it (held `_UNKNOWN_ACCEL_TAU_S`); what stays (at rest: the levelling signal)
        adds |h|^2 T."""
        cy, sy = np.cos(yaw), np.sin(yaw)
        hx, hy = cy * sf[:, 0] + sy * sf[:, 1], -sy * sf[:, 0] + cy * sf[:, 1]   # heading-aligned level axes
        d2 = (hx[1:] - hx[0]) ** 2 + (hy[1:] - hy[0]) ** 2
        c = 3.0 * np.sqrt(float(self.sp_aug.wc[1:] @ d2))
        m = float(np.hypot(hx[0], hy[0]))
        if m <= c:
            return m * m * T
        r = 1.0 - c / m
        sf[:, 0] -= r * (cy * hx[0] - sy * hy[0])
        sf[:, 1] -= r * (sy * hx[0] + cy * hy[0])
        return m * m * _UNKNOWN_ACCEL_TAU_S

    def _decouple_yaw(self) -> None:
        """While the heading is unknown, yaw is carried without correlation and spread (its mean still integrates
        the gyros): the sigma points must not wrap it around the circle."""
        if not self.heading_known:
            self.P[8, :] = 0.0
            self.P[:, 8] = 0.0
            self.P[8, 8] = _YAW_FREE_VAR

    def reported_P(self) -> np.ndarray:
        """The covariance to report: the filter's, with a uniform heading's variance while the heading is unknown."""
        P = self.P.copy()
        if not self.heading_known:
            P[8, :] = 0.0
            P[:, 8] = 0.0
            P[8, 8] = np.radians(HEADING_UNKNOWN_SIGMA_DEG) ** 2
        return P

    def align_heading(self) -> bool:
        """Heading = course of the filtered velocity when the ground speed reaches `align_speed_mps` (variance: the
        course's from the velocity covariance plus `init_att_sigma_deg[2]`^2 for heading - course); True if done."""
        vn, ve = self.x[3], self.x[4]
        speed = float(np.hypot(vn, ve))
        if speed < self.opts.align_speed_mps or speed <= 0.0:
            return False
        g = np.array([-ve, vn]) / speed ** 2          # d(course)/d(vn, ve)
        var = float(g @ self.P[3:5, 3:5] @ g) + np.radians(self.opts.init_att_sigma_deg[2]) ** 2
        self.x[8] = np.arctan2(ve, vn)
        self.P[8, :] = 0.0
        self.P[:, 8] = 0.0
        self.P[8, 8] = var
        self.heading_known = True
        return True

    def h(self, chi: np.ndarray, w_b: np.ndarray, with_velocity: bool) -> np.ndarray:
        """Antenna position (and velocity) in nav for state sigma points (S,n); seed eq. 5 plus the lever arm and
        the GNSS error states."""
        lever = np.asarray(self.opts.lever_arm_b, float)
        if lever.any():
            R_body_to_nav = _R_body_to_nav_from_euler(chi[:, _ANG])
            y = chi[:, 0:3] + R_body_to_nav @ lever
            v = chi[:, 3:6] + R_body_to_nav @ np.cross(w_b, lever)
        else:  # seed eq. 5: H = [I6 0]
            y, v = chi[:, 0:3].copy(), chi[:, 3:6]
        if self.gm:
            y = y + chi[:, _GNSS_ERR]
        return np.column_stack([y, v]) if with_velocity else y

    def update(self, z: np.ndarray, Rz: np.ndarray, w_b: np.ndarray) -> tuple[np.ndarray, float]:
        """GNSS update (seed eq. 11-19) with z = antenna p_nav (3) [+ v_nav (3)], covariance Rz; returns
        (innovation, normalised innovation squared)."""
        self._decouple_yaw()
        lever = np.asarray(self.opts.lever_arm_b, float)
        if not self.heading_known and lever.any():  # the lever arm points nowhere known horizontally
            Rz = Rz.copy()
            R_tilt = _R_tilt(self.x[6:8])
            Rz[0:2, 0:2] += np.eye(2) * float(np.sum((R_tilt @ lever)[:2] ** 2))
            if len(z) == 6:
                Rz[3:5, 3:5] += np.eye(2) * float(np.sum((R_tilt @ np.cross(w_b, lever))[:2] ** 2))
        chi = self.sp.points(self.x, self.P)
        Y = self.h(chi, w_b, len(z) == 6)
        y, Pyy = _mean_cov(Y, self.sp, None)
        Pyy = Pyy + Rz
        dx = chi - chi[0]
        dx[:, _ANG] = wrap_pi(dx[:, _ANG])
        dx -= self.sp.wm @ dx
        Pxy = (dx * self.sp.wc[:, None]).T @ (Y - y)
        K = np.linalg.solve(Pyy, Pxy.T).T
        nu = z - y
        self.x = self.x + K @ nu
        self.x[_ANG] = wrap_pi(self.x[_ANG])
        self.P = self.P - K @ Pyy @ K.T
        self.P = 0.5 * (self.P + self.P.T)
        self._decouple_yaw()
        return nu, float(nu @ np.linalg.solve(Pyy, nu))


def fix_velocities(t: np.ndarray, p: np.ndarray, white: np.ndarray, sig_e: np.ndarray | None,
                   corr_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocities (N,3) m/s of fixes without them, by central differences over about +-0.5 s, and their sigmas (N,3)
    from the white (N,3) and Gauss-Markov (N,3 or None; correlation time `corr_s`) parts of the fix sigmas."""
    n = len(t)
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    m = max(1, int(round(0.5 / dt)))
    idx = np.arange(n)
    a, b = np.clip(idx - m, 0, n - 1), np.clip(idx + m, 0, n - 1)
    D = t[b] - t[a]
    v = (p[b] - p[a]) / D[:, None]
    var = white[a] ** 2 + white[b] ** 2
    if sig_e is not None:
        var = var + sig_e[a] ** 2 + sig_e[b] ** 2 - 2 * sig_e[a] * sig_e[b] * np.exp(-D / corr_s)[:, None]
    return v, np.sqrt(np.clip(var, 1e-12, None)) / D[:, None]


def tilt_from_vectors(f_b: np.ndarray, u_nav: np.ndarray, yaw: float) -> np.ndarray:
    """Roll and pitch (2,) rad of the attitude R = Rz(yaw) Ry(pitch) Rx(roll) that takes the body vector f_b (3,)
    to the nav vector u_nav (3,) (a specific force, or its integral); pitch within +-90 deg."""
    c, s = np.cos(yaw), np.sin(yaw)
    ux, uy, uz = c * u_nav[0] + s * u_nav[1], -s * u_nav[0] + c * u_nav[1], u_nav[2]
    fx, fy, fz = f_b
    rho, delta = np.hypot(ux, uz), np.arctan2(uz, ux)
    a = np.arccos(np.clip(fx / rho, -1.0, 1.0))
    cand = wrap_pi(np.array([a - delta, -a - delta]))
    th = float(cand[np.argmax(np.cos(cand))])
    wz = np.sin(th) * ux + np.cos(th) * uz
    return np.array([np.arctan2(fy * wz - fz * uy, fy * uy + fz * wz), th])


def _body_velocity_changes(imu, t0: float, ts: np.ndarray) -> np.ndarray:
    """The IMU's velocity change (N,3) m/s from t0 to each of the sorted times ts (N,) (>= t0), in the body axes at
    t0 (gyros integrated, no bias)."""
    t, dt = imu.t, imu.dt
    C, dv = np.eye(3), np.zeros(3)
    out = np.zeros((len(ts), 3))
    t_prev = t0
    for n, t1 in enumerate(ts):
        if t1 > t_prev:
            i = int(np.searchsorted(t, t_prev, side="right"))
            i1 = min(int(np.searchsorted(t, t1, side="left")), len(t) - 1)
            t_end = np.minimum(t[i:i1 + 1], t1)
            t_start = np.r_[t_prev, t_end[:-1]]
            frac = np.clip((t_end - t_start) / dt[i:i1 + 1], 0.0, None)
            for dth, dvel in zip(imu.dtheta[i:i1 + 1] * frac[:, None], imu.dvel[i:i1 + 1] * frac[:, None]):
                dv += C @ _exp_so3(0.5 * dth) @ dvel
                C = C @ _exp_so3(dth)
            t_prev = t1
        out[n] = dv
    return out


def level_attitude(imu, frame: NavFrame, t_fix: np.ndarray, v_fix: np.ndarray, sv_fix: np.ndarray, j0: int,
                   yaw: float, var_yaw: float, noise: ImuErrorModel, opts: UkfOptions):
    """Roll and pitch at fix j0 from the accelerometers (velocity matching): over the `align_window_s` after it,
    the IMU's mean velocity in the window's second half minus that in its first (body axes at j0) against the same
    of the GNSS velocities minus gravity (and Coriolis) — at rest plain levelling, moving it holds in turns and
    accelerations too (given the heading `yaw`).

    Returns (roll, pitch (2,) rad, their covariance (2,2), their covariance with the accelerometer-bias states (2,3)
    and with yaw (2,)), or None without `level_from_accel` or IMU and fixes over at least 0.1 s. The covariance
    holds the turn-on accelerometer bias (which the tilt takes up exactly at rest: hence the correlation),
    velocity random walk, misalignment, gyro bias and noise over the window, the fixes' velocity noise (taken as
    independent at most every `_VEL_INDEPENDENT_S`) and the heading's variance `var_yaw`."""
    t0 = t_fix[j0]
    sel = np.flatnonzero((t_fix >= t0) & (t_fix <= min(t0 + opts.align_window_s, imu.t[-1]) + 1e-9))
    if not opts.level_from_accel or len(sel) < 2 or t_fix[sel[-1]] - t0 < 0.1:
        return None
    ts = t_fix[sel]
    T = float(ts[-1] - t0)
    dvb = _body_velocity_changes(imu, t0, ts)
    first = ts < t0 + 0.5 * T
    second = ~first
    T_eff = float(ts[second].mean() - ts[first].mean())
    A = dvb[second].mean(axis=0) - dvb[first].mean(axis=0)
    w_ie = np.array(frame.omega_ie_nav) if opts.earth_rotation else np.zeros(3)
    v_bar = v_fix[sel].mean(axis=0)
    u = v_fix[sel][second].mean(axis=0) - v_fix[sel][first].mean(axis=0) \
        - np.array([0.0, 0.0, frame.gravity]) * T_eff + 2.0 * np.cross(w_ie, v_bar) * T_eff
    rp = tilt_from_vectors(A, u, yaw)
    J = np.empty((2, 7))
    for k in range(7):   # numerical Jacobian over A (3), u (3), yaw
        d = np.zeros(7)
        d[k] = 1e-6 if k == 6 else 1e-4
        J[:, k] = wrap_pi(tilt_from_vectors(A + d[:3], u + d[3:6], yaw + d[6]) - rp) / d[k]
    g = float(np.linalg.norm(A))
    var_f = ((noise.accel_bias_sigma * T_eff) ** 2 + noise.accel_vrw ** 2 * T + (noise.accel_misalign_sigma * g) ** 2
             + (noise.gyro_bias_sigma * g * T / 2.0) ** 2 + noise.gyro_arw ** 2 * g ** 2 * T / 3.0)
    var_u = np.zeros(3)
    for m in (first, second):
        n_ind = min(int(m.sum()), max(1, int(np.ceil((ts[m][-1] - ts[m][0]) / _VEL_INDEPENDENT_S))))
        var_u += np.mean(sv_fix[sel][m] ** 2, axis=0) / n_ind
    P = J[:, :3] @ J[:, :3].T * var_f + (J[:, 3:6] * var_u) @ J[:, 3:6].T + np.outer(J[:, 6], J[:, 6]) * var_yaw
    return rp, P, -T_eff * noise.accel_bias_sigma ** 2 * J[:, :3], J[:, 6] * var_yaw


def initial_state(imu, frame: NavFrame, t_fix, p_fix, v_fix, sv_fix, sp_meas, sig_e, j0: int, noise: ImuErrorModel,
                  opts: UkfOptions) -> tuple[np.ndarray, np.ndarray, dict]:
    """The filter's state and covariance at fix j0 (see `run_ukf`) and a description of the start."""
    gm = sig_e is not None
    v0, sv0 = v_fix[j0], sv_fix[j0]
    speed = float(np.hypot(v0[0], v0[1]))
    known = speed >= opts.align_speed_mps and speed > 0.0
    yaw, var_yaw = 0.0, 0.0
    if known:
        yaw = float(np.arctan2(v0[1], v0[0]))
        var_yaw = ((v0[1] * sv0[0]) ** 2 + (v0[0] * sv0[1]) ** 2) / speed ** 4 \
            + np.radians(opts.init_att_sigma_deg[2]) ** 2
    lev = level_attitude(imu, frame, t_fix, v_fix, sv_fix, j0, yaw, var_yaw, noise, opts)
    n = N_STATE + (3 if gm else 0)
    x0 = np.zeros(n)
    P0 = np.zeros((n, n))
    if lev is None:
        rp, P_rp, C_ba, C_yaw = np.zeros(2), np.diag(np.radians(opts.init_att_sigma_deg[:2]) ** 2), \
            np.zeros((2, 3)), np.zeros(2)
    else:
        rp, P_rp, C_ba, C_yaw = lev
    x0[6:9] = rp[0], rp[1], yaw
    lever = np.asarray(opts.lever_arm_b, float)
    R0 = _R_body_to_nav_from_euler(x0[None, 6:9])[0]
    x0[0:3], x0[3:6] = p_fix[j0] - R0 @ lever, v0
    P0[np.diag_indices(15)] = np.r_[[opts.init_pos_sigma_m ** 2] * 3, [opts.init_vel_sigma_mps ** 2] * 3,
                                    [0.0, 0.0, var_yaw if known else _YAW_FREE_VAR],
                                    [noise.accel_bias_sigma ** 2] * 3, [noise.gyro_bias_sigma ** 2] * 3]
    P0[6:8, 6:8] = P_rp
    P0[6:8, 9:12], P0[9:12, 6:8] = C_ba, C_ba.T
    if known:
        P0[6:8, 8] = P0[8, 6:8] = C_yaw
    if gm:  # the first fix is p + e + white: p starts there, perfectly anti-correlated with the error state
        P0[0:3, 0:3] = np.diag(sig_e[j0] ** 2 + sp_meas[j0] ** 2)
        P0[_GNSS_ERR, _GNSS_ERR] = np.diag(sig_e[j0] ** 2)
        P0[0:3, _GNSS_ERR] = P0[_GNSS_ERR, 0:3] = -np.diag(sig_e[j0] ** 2)
    if not known and lever.any():   # the lever arm points nowhere known horizontally
        P0[0:2, 0:2] += np.eye(2) * float(np.sum((_R_tilt(rp) @ lever)[:2] ** 2))
    start = {"t_gps": float(t_fix[j0]), "ground_speed_mps": round(speed, 3), "heading_known": bool(known),
             "levelled": "accelerometers" if lev is not None else "level",
             "roll_pitch_deg": np.degrees(rp).round(3).tolist(),
             "roll_pitch_sigma_deg": np.degrees(np.sqrt(np.diag(P_rp))).round(3).tolist()}
    return x0, P0, start


def run_ukf(imu, fixes, grade: str | ImuErrorModel, opts: UkfOptions | None = None, frame: NavFrame | None = None,
            progress: bool = False, rate_hz: float | None = None) -> UkfSolution:
    """Run the 15-state UKF (+ 3 GNSS error states, `UkfOptions.gnss_error_states`) over an IMU record with GNSS
    fixes; states at every GNSS epoch and, where no fix is near (GNSS outages, the IMU record after the last fix,
    fixes slower than `rate_hz`), at `rate_hz` (default: the fixes' median rate) predicted by the IMU alone.

    imu: `dgcal.pos.ins.imu_data.ImuData` (body FRD increments, GPS s). fixes: `dgcal.pos.smoother.initial.GnssFixes`
    (antenna ECEF positions, optional velocities, sigmas in NED). grade: `ImuErrorModel` or preset name (carried
    as its `smoother_noise()`). Each fix sigma is split into a white part (`gnss_white_m`, the measurement noise)
    and a correlated part (the Gauss-Markov states' sigma).
    The filter starts at the first fix inside the IMU span, at any speed: roll and pitch from the accelerometers
    (`UkfOptions.level_from_accel`, see `level_attitude`), heading = GNSS course when the ground speed is at least
    `align_speed_mps`; slower, the heading is unknown (sigma `HEADING_UNKNOWN_SIGMA_DEG`) until it is.
    """
    opts = opts or UkfOptions()
    noise = imu_grade(grade).smoother_noise()
    ok = np.all(np.isfinite(fixes.p_ecef), axis=1)
    if ok.sum() < 2:
        raise ValueError("the UKF needs at least two GNSS fixes")
    frame = frame or NavFrame.at_ecef(fixes.p_ecef[ok].mean(axis=0))
    t_fix = np.asarray(fixes.t, float)[ok]
    p_fix = frame.from_ecef(fixes.p_ecef[ok])
    has_v = fixes.v_ecef is not None and opts.use_velocity
    sp_fix = np.asarray(fixes.sigma_ned, float)[ok]
    gm = bool(opts.gnss_error_states)
    if gm:  # fix sigma = white (measurement noise) + correlated (Gauss-Markov states)
        white = np.minimum(opts.gnss_white_m, 0.7 * sp_fix)
        sig_e = np.sqrt(np.clip(sp_fix ** 2 - white ** 2, 1e-6, None))
        sp_meas = white
    else:
        sig_e, sp_meas = None, sp_fix
    if fixes.v_ecef is not None:
        v_fix = fixes.v_ecef[ok] @ frame.R_nav_to_ecef
        sv_fix = (np.asarray(fixes.sigma_v_ned, float)[ok] if fixes.sigma_v_ned is not None
                  else np.full_like(v_fix, 0.1))
    else:
        v_fix, sv_fix = fix_velocities(t_fix, p_fix, sp_meas, sig_e, opts.gnss_corr_s)
    t_imu = imu.t
    inside = np.flatnonzero((t_fix >= t_imu[0]) & (t_fix <= t_imu[-1]))
    if len(inside) == 0:
        raise ValueError("no GNSS fix inside the IMU span to start the UKF")
    j0 = int(inside[0])
    x0, P0, start = initial_state(imu, frame, t_fix, p_fix, v_fix, sv_fix, sp_meas, sig_e, j0, noise, opts)
    f = StrapdownUkf(frame, x0, P0, noise, opts)
    f.heading_known = start["heading_known"]
    if gm:
        f.sigma_gnss = sig_e[j0]
    # the epochs: every fix from the start, and the output grid where no fix is near
    tf = t_fix[j0:inside[-1] + 1]
    step = 1.0 / rate_hz if rate_hz else (float(np.median(np.diff(tf))) if len(tf) > 1 else 1.0 / imu.rate_hz)
    grid = tf[0] + step * np.arange(int(np.floor((t_imu[-1] - tf[0]) / step + 1e-9)) + 1)
    if len(tf) > 1:
        k = np.clip(np.searchsorted(tf, grid), 1, len(tf) - 1)
        near = np.minimum(np.abs(grid - tf[k - 1]), np.abs(grid - tf[k]))
    else:
        near = np.abs(grid - tf[0])
    fix_dt = float(np.median(np.diff(tf))) if len(tf) > 1 else step
    epochs = np.union1d(tf, grid[near > 0.5 * min(step, fix_dt)])
    fix_of = np.full(len(epochs), -1)
    fix_of[np.searchsorted(epochs, tf)] = np.arange(j0, j0 + len(tf))
    dt_all = imu.dt
    i = int(np.searchsorted(t_imu, epochs[0], side="right"))
    t_prev = epochs[0]
    out_t, out_x, out_P = [t_prev], [f.x.copy()], [f.reported_P()]
    innov, nis, upd, known = [np.full(6, np.nan)], [np.nan], [True], [f.heading_known]
    if has_v:
        zz = np.hstack([p_fix, v_fix])
        rr = np.hstack([sp_meas, np.asarray(fixes.sigma_v_ned, float)[ok]]) ** 2
    # bridged IMU gaps and spikes (dgcal.pos.ins.integrity.check_imu): their interpolation error as extra noise
    dens = bridge_densities(getattr(imu, "bridges", []), epochs)
    it = range(1, len(epochs))
    if progress:
        it = tqdm(it, desc="ukf", unit="epoch", leave=False)
    t_aligned = float(epochs[0]) if f.heading_known else None
    for e in it:
        tj = epochs[e]
        i1 = int(np.searchsorted(t_imu, tj, side="left"))  # samples i..i1 cover (t_prev, tj]
        t_end = np.minimum(t_imu[i:i1 + 1], tj)
        t_start = np.empty_like(t_end)
        t_start[0] = t_prev
        t_start[1:] = t_end[:-1]
        h = t_end - t_start
        frac = h / dt_all[i:i1 + 1]
        keep = h > 1e-9
        if keep.any():
            br = None
            if dens is not None and (dens[0][e - 1].any() or dens[1][e - 1].any()):
                br = (np.diag(dens[0][e - 1]), np.diag(dens[1][e - 1]))
            f.predict(imu.dtheta[i:i1 + 1][keep] * frac[keep, None], imu.dvel[i:i1 + 1][keep] * frac[keep, None],
                      h[keep], br)
        i = i1 if t_imu[i1] > tj + 1e-9 else i1 + 1
        t_prev = tj
        j = fix_of[e]
        row = np.full(6, np.nan)
        q = np.nan
        if j >= 0:
            w_b = imu.dtheta[min(i1, len(t_imu) - 1)] / dt_all[min(i1, len(t_imu) - 1)] - f.x[12:15]
            if has_v:
                z = zz[j]
                Rz = np.diag(rr[j])
            else:
                z, Rz = p_fix[j], np.diag(sp_meas[j] ** 2)
            nu, q = f.update(z, Rz, w_b)
            q /= len(nu)
            row[:len(nu)] = nu
            if gm:
                f.sigma_gnss = sig_e[j]
            if not f.heading_known and f.align_heading():
                t_aligned = float(tj)
        out_t.append(tj)
        out_x.append(f.x.copy())
        out_P.append(f.reported_P())
        innov.append(row)
        nis.append(q)
        upd.append(j >= 0)
        known.append(f.heading_known)
    X = np.array(out_x)
    start.update(t_heading_aligned=t_aligned, output_step_s=step)
    return UkfSolution(frame=frame, t=np.array(out_t), p_nav=X[:, 0:3], v_nav=X[:, 3:6],
                       rph_deg=_deg_rph(X[:, 6:9]),
                       bias=X[:, 9:15], P=np.array(out_P), innovations=np.array(innov), nis=np.array(nis),
                       info={"n_updates": int(np.sum(upd)) - 1, "alpha": opts.alpha, "beta": opts.beta,
                             "kappa": opts.kappa, "velocity_updates": bool(has_v), "n_states": int(X.shape[1]),
                             "gnss_error_states": gm, "gnss_corr_s": opts.gnss_corr_s if gm else None,
                             "start": start},
                       gnss_error=X[:, _GNSS_ERR] if gm else np.zeros((len(X), 3)),
                       updated=np.array(upd), heading_known=np.array(known))


def _deg_rph(e: np.ndarray) -> np.ndarray:
    """Euler angles (rad) -> roll, pitch in (-180, 180], heading in [0, 360) degrees."""
    d = np.degrees(wrap_pi(e))
    d[:, 2] = np.mod(d[:, 2], 360.0)
    return d
