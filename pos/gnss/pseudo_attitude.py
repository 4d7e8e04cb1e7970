"""Coarse attitude from GNSS velocity alone: seed 001's pseudo-roll, pseudo-pitch, pseudo-yaw and rates.

With coordinated flight (velocity along the body x axis, no sideslip), the GNSS velocity V and its
time derivative A (NED) give (seed 001, eq. 1-7):
  A_n = A - (A.V/|V|^2) V,   g_n = g - (g.V/|V|^2) V          (eq. 1, 2: parts normal to V)
  L = A_n - g_n                                              (eq. 3: pseudo lift, -specific force)
  p = g x V                                                  (eq. 4: local horizontal reference)
  roll  = arcsin(L.p / (|L| |p|))                            (eq. 5)
  pitch = arctan(-V_D / sqrt(V_N^2 + V_E^2))                 (eq. 6: flight-path angle)
  yaw   = atan2(V_E, V_N)                                    (eq. 7: course over ground)
Euler rates are time derivatives of these; body rates [p q r] follow from the standard Z-Y-X
kinematic relation (eq. 8, whose printed matrix is garbled in the seed text):
  p = droll - dyaw sin(pitch),  q = dpitch cos(roll) + dyaw sin(roll) cos(pitch),
  r = -dpitch sin(roll) + dyaw cos(roll) cos(pitch).
Pitch and yaw differ from the true attitude by the angle of attack and sideslip/crab (wind); roll
is close to the true roll in coordinated turns. Used to initialise the smoother in motion.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgcal.fields.constants import G0
from dgcal.fields.frames import R_body_to_ned_from_rph


@dataclass
class PseudoAttitude:
    """Pseudo roll/pitch/yaw (deg, yaw in [0, 360)), Euler rates (deg/s), body rates (rad/s), validity mask, and
    (when the velocity noise is known) the 1-sigma of roll/pitch/yaw (deg) from that noise alone."""

    t: np.ndarray
    rph: np.ndarray
    rph_rate: np.ndarray
    omega_b: np.ndarray
    valid: np.ndarray
    sigma_rph: np.ndarray | None = None
    sigma_v_mps: float | None = None

    @property
    def R_body_to_ned(self) -> np.ndarray:
        """Body-to-NED rotations (N,3,3) of the pseudo attitude (NaN where invalid)."""
        return R_body_to_ned_from_rph(self.rph[:, 0], self.rph[:, 1], self.rph[:, 2])


def time_derivative(t: np.ndarray, y: np.ndarray, window_s: float = 0.0) -> np.ndarray:
    """d y / d t along axis 0: Savitzky-Golay (quadratic, `window_s` wide) if uniform, else central differences."""
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    dt = np.diff(t)
    if len(t) < 3:
        return np.gradient(y, t, axis=0) if len(t) > 1 else np.zeros_like(y)
    step = float(np.median(dt))
    uniform = np.allclose(dt, step, rtol=1e-3, atol=1e-6)
    n = int(round(window_s / step)) if window_s > 0 else 0
    if uniform and n >= 3:
        n = n + 1 if n % 2 == 0 else n
        n = min(n, len(t) - (1 - len(t) % 2))
        if n >= 3:
            from scipy.signal import savgol_filter   # here: scipy.signal costs 0.6-0.8 s to import, most runs need none
            return savgol_filter(y, n, 2, deriv=1, delta=step, axis=0, mode="interp")
    return np.gradient(y, t, axis=0)


def velocity_noise(t: np.ndarray, v_ned: np.ndarray) -> float:
    """White noise (m/s, per axis) of a velocity series from its second differences (robust: 1.4826 MAD / sqrt 6)."""
    d2 = np.diff(np.asarray(v_ned, float), 2, axis=0)
    if len(d2) < 3:
        return float("nan")
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0))) / np.sqrt(6.0))


def derivative_gain(t: np.ndarray, window_s: float) -> float:
    """Noise gain (1/s) of `time_derivative`: the sigma of the derivative of white noise of unit sigma."""
    t = np.asarray(t, float)
    step = float(np.median(np.diff(t)))
    n = int(round(window_s / step)) if window_s > 0 else 0
    if n >= 3:
        n = n + 1 if n % 2 == 0 else n
        n = min(n, len(t) - (1 - len(t) % 2))
    if n >= 3:
        from scipy.signal import savgol_coeffs       # here: scipy.signal costs 0.6-0.8 s to import
        return float(np.linalg.norm(savgol_coeffs(n, 2, deriv=1, delta=step)))
    return float(np.sqrt(0.5) / step)  # central differences


def pseudo_attitude(t: np.ndarray, v_ned: np.ndarray, a_ned: np.ndarray | None = None, g: float = G0,
                    window_s: float = 0.8, min_speed: float = 3.0, sigma_v_mps: float | str | None = None
                    ) -> PseudoAttitude:
    """Pseudo attitude (seed 001 eq. 1-8) from GNSS NED velocity (m/s) at GPS times t (s).

    `a_ned` (m/s^2) is the velocity's derivative; if None it is computed (Savitzky-Golay over `window_s`
    when > 0; 0.8 s suits 10 Hz Doppler velocities with 2 cm/s noise: roll RMS 0.3 deg in 25 deg turns;
    sparser data fall back to central differences). Samples slower than `min_speed` m/s are invalid (NaN).
    `sigma_v_mps` (m/s per axis, or 'auto': estimated by `velocity_noise`) adds `sigma_rph`: roll through the
    derivative's noise gain and eq. 5, plus the derivative's smoothing error where the acceleration changes
    quickly (a quadratic fit over a window of half-width w misses 0.1 w^2 |d3V/dt3| of the derivative, taken
    from the data), pitch and yaw through the velocity direction (eq. 6, 7). The coordinated-flight
    assumption itself (no sideslip acceleration) is not covered.
    """
    t = np.asarray(t, float)
    V = np.asarray(v_ned, float)
    A = time_derivative(t, V, window_s) if a_ned is None else np.asarray(a_ned, float)
    speed2 = np.sum(V * V, axis=1)
    valid = speed2 > min_speed ** 2
    s2 = np.where(valid, speed2, 1.0)[:, None]
    gv = np.array([0.0, 0.0, g])
    A_n = A - (np.sum(A * V, axis=1)[:, None] / s2) * V
    g_n = gv - (V @ gv)[:, None] / s2 * V
    L = A_n - g_n
    p = np.cross(gv, V)
    denom = np.linalg.norm(L, axis=1) * np.linalg.norm(p, axis=1)
    valid &= denom > 0
    roll = np.arcsin(np.clip(np.sum(L * p, axis=1) / np.where(valid, denom, 1.0), -1.0, 1.0))
    pitch = np.arctan2(-V[:, 2], np.hypot(V[:, 0], V[:, 1]))
    yaw = np.arctan2(V[:, 1], V[:, 0])
    ang = np.column_stack([roll, pitch, np.unwrap(yaw)])
    rates = time_derivative(t, ang, window_s)
    dr, dp, dy = rates[:, 0], rates[:, 1], rates[:, 2]
    sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    omega = np.column_stack([dr - dy * sp, dp * cr + dy * sr * cp, -dp * sr + dy * cr * cp])
    rph = np.degrees(np.column_stack([roll, pitch, np.mod(yaw, 2 * np.pi)]))
    rph_rate = np.degrees(rates)
    rph[~valid] = np.nan
    rph_rate[~valid] = np.nan
    omega[~valid] = np.nan
    sig = None
    if sigma_v_mps is not None:
        sv = velocity_noise(t, V) if isinstance(sigma_v_mps, str) else float(sigma_v_mps)
        sa = np.full((len(t), 3), sv * (derivative_gain(t, window_s) if a_ned is None else 0.0))
        if a_ned is None and window_s > 0:
            d3v = time_derivative(t, time_derivative(t, A, 2 * window_s), 2 * window_s)  # m/s^4
            sa = np.hypot(sa, 0.1 * (0.5 * window_s) ** 2 * np.abs(d3v))
        # roll: d(roll)/dA along the three axes (finite differences of eq. 1-5), times the derivative's error
        dr2 = np.zeros(len(t))
        for i in range(3):
            dA = np.zeros(3)
            dA[i] = 1e-3
            A2 = A + dA
            An2 = A2 - (np.sum(A2 * V, axis=1)[:, None] / s2) * V
            L2 = An2 - g_n
            den2 = np.linalg.norm(L2, axis=1) * np.linalg.norm(p, axis=1)
            r2 = np.arcsin(np.clip(np.sum(L2 * p, axis=1) / np.where(valid, den2, 1.0), -1.0, 1.0))
            dr2 += ((r2 - roll) / 1e-3 * sa[:, i]) ** 2
        vh = np.hypot(V[:, 0], V[:, 1])
        sig = np.degrees(np.column_stack([np.sqrt(dr2), sv / np.sqrt(speed2), sv / np.where(vh > 0, vh, np.nan)]))
        sig[~valid] = np.nan
        sigma_v_mps = sv
    return PseudoAttitude(t=t, rph=rph, rph_rate=rph_rate, omega_b=omega, valid=valid, sigma_rph=sig,
                          sigma_v_mps=None if sigma_v_mps is None else float(sigma_v_mps))
