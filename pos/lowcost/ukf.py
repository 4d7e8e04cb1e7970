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
_ANG = slice(6, 9)
_GNSS_ERR = slice(15, 18)


@dataclass
class UkfOptions:
    """Tuning: unscented scaling, initial sigmas, measurement use, lever arm (IMU -> antenna, body FRD, m)."""

    alpha: float = 0.5
    beta: float = 2.0
    kappa: float = 0.0
    lever_arm_b: np.ndarray = field(default_factory=lambda: np.zeros(3))
    init_att_sigma_deg: tuple = (5.0, 5.0, 15.0)
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
    """Filtered states at the GNSS epochs `t` (GPS s): IMU positions/velocities in `frame` (NED), Euler angles
    (deg), biases (accel m/s^2, gyro rad/s), the GNSS position errors (K,3, m, nav; zeros without error states)
    and the covariances (K,n,n; n = 15, or 18 with the GNSS error states) in the state's units (rad for angles)."""

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
        q_a = n.accel_vrw ** 2 / T + self._axis_var(df2, pick(o.accel_scale_noise, n.accel_scale_sigma),
                                                     pick(o.accel_misalign_noise, n.accel_misalign_sigma)) * c
        if bridge is not None:
            q_g = q_g + bridge[0] / T
            q_a = q_a + bridge[1] / T
        q = list(q_a) + list(q_g) + [n.accel_bias_rw ** 2 * T] * 3 + [n.gyro_bias_rw ** 2 * T] * 3
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
        for k in range(len(dt)):
            h = dt[k]
            w_b = dtheta[k] / h - bg - ng - w_ie_b
            e_mid = e + (0.5 * h) * euler_rates(e, w_b)  # midpoint step: second order in h
            e_new = e + h * euler_rates(e_mid, w_b)
            f_b = dvel[k] / h - ba - na
            a_nav = np.einsum("sij,sj->si", _R_body_to_nav_from_euler(e_mid), f_b) - _cross(w_cor, v)
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
        return nu, float(nu @ np.linalg.solve(Pyy, nu))


def run_ukf(imu, fixes, grade: str | ImuErrorModel, opts: UkfOptions | None = None, frame: NavFrame | None = None,
            progress: bool = False) -> UkfSolution:
    """Run the 15-state UKF (+ 3 GNSS error states, `UkfOptions.gnss_error_states`) over an IMU record with GNSS
    fixes; states at every GNSS epoch.

    imu: `dgcal.pos.ins.imu_data.ImuData` (body FRD increments, GPS s). fixes: `dgcal.pos.smoother.initial.GnssFixes`
    (antenna ECEF positions, optional velocities, sigmas in NED). grade: `ImuErrorModel` or preset name (carried
    as its `smoother_noise()`). Each fix sigma is split into a white part (`gnss_white_m`, the measurement noise)
    and a correlated part (the Gauss-Markov states' sigma).
    The filter starts at the first fix with level attitude and heading = GNSS course.
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
    v_fix = fixes.v_ecef[ok] @ frame.R_nav_to_ecef if fixes.v_ecef is not None else np.gradient(p_fix, t_fix, axis=0)
    sp_fix = np.asarray(fixes.sigma_ned, float)[ok]
    sv_fix = np.asarray(fixes.sigma_v_ned, float)[ok] if has_v else None
    # first fix inside the IMU span with a usable course
    start = np.flatnonzero((t_fix >= imu.t[0]) & (np.hypot(v_fix[:, 0], v_fix[:, 1]) > 3.0))
    if len(start) == 0:
        raise ValueError("no GNSS fix with ground speed > 3 m/s inside the IMU span to start the UKF")
    j0 = int(start[0])
    gm = bool(opts.gnss_error_states)
    if gm:  # fix sigma = white (measurement noise) + correlated (Gauss-Markov states)
        white = np.minimum(opts.gnss_white_m, 0.7 * sp_fix)
        sig_e = np.sqrt(np.clip(sp_fix ** 2 - white ** 2, 1e-6, None))
        sp_meas = white
    else:
        sig_e, sp_meas = None, sp_fix
    x0 = np.zeros(N_STATE + (3 if gm else 0))
    x0[0:3], x0[3:6] = p_fix[j0], v_fix[j0]
    x0[8] = np.arctan2(v_fix[j0, 1], v_fix[j0, 0])
    p0 = np.r_[[opts.init_pos_sigma_m ** 2] * 3, [opts.init_vel_sigma_mps ** 2] * 3,
               np.radians(opts.init_att_sigma_deg) ** 2, [noise.accel_bias_sigma ** 2] * 3,
               [noise.gyro_bias_sigma ** 2] * 3]
    if gm:
        p0 = np.r_[p0, sig_e[j0] ** 2]
    P0 = np.diag(p0)
    if gm:  # the first fix is p + e + white: p starts there, perfectly anti-correlated with the error state
        P0[0:3, 0:3] = np.diag(sig_e[j0] ** 2 + sp_meas[j0] ** 2)
        P0[0:3, _GNSS_ERR] = P0[_GNSS_ERR, 0:3] = -np.diag(sig_e[j0] ** 2)
    f = StrapdownUkf(frame, x0, P0, noise, opts)
    if gm:
        f.sigma_gnss = sig_e[j0]
    dt_all = imu.dt
    t_imu = imu.t
    i = int(np.searchsorted(t_imu, t_fix[j0], side="right"))
    t_prev = t_fix[j0]
    out_t, out_x, out_P, innov, nis = [t_prev], [f.x.copy()], [f.P.copy()], [np.full(6, np.nan)], [np.nan]
    if has_v:
        zz = np.hstack([p_fix, v_fix])
        rr = np.hstack([sp_meas, sv_fix]) ** 2
    # bridged IMU gaps and spikes (dgcal.pos.ins.integrity.check_imu): their interpolation error as extra noise
    dens = bridge_densities(getattr(imu, "bridges", []), t_fix[j0:])
    it = range(j0 + 1, len(t_fix))
    if progress:
        it = tqdm(it, desc="ukf", unit="fix", leave=False)
    for j in it:
        tj = t_fix[j]
        if tj > t_imu[-1]:
            break
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
            if dens is not None and (dens[0][j - j0 - 1].any() or dens[1][j - j0 - 1].any()):
                br = (np.diag(dens[0][j - j0 - 1]), np.diag(dens[1][j - j0 - 1]))
            f.predict(imu.dtheta[i:i1 + 1][keep] * frac[keep, None], imu.dvel[i:i1 + 1][keep] * frac[keep, None],
                      h[keep], br)
        i = i1 if t_imu[i1] > tj + 1e-9 else i1 + 1
        t_prev = tj
        w_b = imu.dtheta[min(i1, len(t_imu) - 1)] / dt_all[min(i1, len(t_imu) - 1)] - f.x[12:15]
        if has_v:
            z = zz[j]
            Rz = np.diag(rr[j])
        else:
            z, Rz = p_fix[j], np.diag(sp_meas[j] ** 2)
        nu, q = f.update(z, Rz, w_b)
        if gm:
            f.sigma_gnss = sig_e[j]
        out_t.append(tj)
        out_x.append(f.x.copy())
        out_P.append(f.P.copy())
        row = np.full(6, np.nan)
        row[:len(nu)] = nu
        innov.append(row)
        nis.append(q / len(nu))
    X = np.array(out_x)
    return UkfSolution(frame=frame, t=np.array(out_t), p_nav=X[:, 0:3], v_nav=X[:, 3:6],
                       rph_deg=_deg_rph(X[:, 6:9]),
                       bias=X[:, 9:15], P=np.array(out_P), innovations=np.array(innov), nis=np.array(nis),
                       info={"n_updates": len(out_t) - 1, "alpha": opts.alpha, "beta": opts.beta,
                             "kappa": opts.kappa, "velocity_updates": bool(has_v), "n_states": int(X.shape[1]),
                             "gnss_error_states": gm, "gnss_corr_s": opts.gnss_corr_s if gm else None},
                       gnss_error=X[:, _GNSS_ERR] if gm else np.zeros((len(X), 3)))


def _deg_rph(e: np.ndarray) -> np.ndarray:
    """Euler angles (rad) -> roll, pitch in (-180, 180], heading in [0, 360) degrees."""
    d = np.degrees(wrap_pi(e))
    d[:, 2] = np.mod(d[:, 2], 360.0)
    return d
