"""gtsam factors of the GNSS/INS smoother: keys, TC pseudorange/Doppler, LC position/velocity, receiver clock.

Units: the receiver clock bias variables are in seconds (gtsam's `PseudorangeFactorArm` convention), one
per constellation and keyframe; the common clock drift variable is in s/s. The GNSS front end
(dgcal.pos.gnss.observations) gives satellite positions already rotated for the Earth's rotation (Sagnac) and
range measurements corrected
for satellite clock, ionosphere and troposphere; gtsam's factors add their own Sagnac term, so the same
term (evaluated at the approximate receiver position) is added to the measurement to cancel it.
"""
from __future__ import annotations

import gtsam
import numpy as np

from dgcal.fields.constants import C_LIGHT, OMEGA_EARTH

_SYS_CHAR = {"G": "g", "E": "e", "C": "c", "J": "j", "R": "r", "I": "i", "S": "s"}


def X(k: int) -> int:
    """Key of the body pose (R_body_to_nav, p_nav of the IMU origin) at keyframe k."""
    return gtsam.symbol("x", k)


def V(k: int) -> int:
    """Key of the IMU velocity in nav axes (m/s) at keyframe k."""
    return gtsam.symbol("v", k)


def B(k: int) -> int:
    """Key of the IMU biases (accelerometer m/s^2, gyro rad/s) at keyframe k."""
    return gtsam.symbol("b", k)


def CLK(system: str, k: int) -> int:
    """Key of the receiver clock bias (s) of a constellation at keyframe k."""
    return gtsam.symbol(_SYS_CHAR[system], k)


def DRIFT(k: int) -> int:
    """Key of the receiver clock drift (s/s) at keyframe k."""
    return gtsam.symbol("d", k)


def FE(k: int) -> int:
    """Key of the LC fixes' correction (nav N, E, D, m: minus their time-correlated error) at keyframe k."""
    return gtsam.symbol("f", k)


def ZERO() -> int:
    """Key of a constant 0.0 (pinned by a tight prior): the 'previous clock' of the Doppler factors, see
    `doppler_factors`."""
    return gtsam.symbol("z", 0)


def sagnac_m(sat_pos_ecef: np.ndarray, p_rx_ecef: np.ndarray) -> np.ndarray:
    """Earth-rotation range correction (m) as gtsam's pseudorange factors compute it."""
    s, r = np.atleast_2d(sat_pos_ecef), np.asarray(p_rx_ecef, float)
    return OMEGA_EARTH / C_LIGHT * (s[:, 0] * r[1] - s[:, 1] * r[0])


def sagnac_rate_mps(sat_pos_ecef, sat_vel_ecef, p_rx_ecef) -> np.ndarray:
    """Time derivative (m/s) of `sagnac_m` for a static receiver (as gtsam's Doppler factors compute it)."""
    v, r = np.atleast_2d(sat_vel_ecef), np.asarray(p_rx_ecef, float)
    return OMEGA_EARTH / C_LIGHT * (v[:, 0] * r[1] - v[:, 1] * r[0])


def robust(sigma: float, dim: int = 1, huber_k: float | None = 1.345):
    """Gaussian noise of `sigma`, wrapped in a Huber M-estimator unless `huber_k` is None."""
    base = gtsam.noiseModel.Isotropic.Sigma(dim, float(sigma))
    if huber_k is None:
        return base
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(float(huber_k)), base)


def pseudorange_factors(k: int, epoch, p_approx_ecef, lever_arm_b, ecef_T_nav, huber_k=1.345,
                        sigma_scale: float = 1.0, bias_key=None, with_sigma: bool = False):
    """A pseudorange factor per satellite of a `GnssEpoch` at keyframe k (one clock key per constellation); with
    `with_sigma` the list and the sigma (m) of each factor.

    `bias_key(sat, k)`: the key of the satellite's code-bias state (`dgcal.pos.smoother.code_bias`) or None; with
    one the factor is a `DifferentialPseudorangeFactorArm` on it with the receiver noise only
    (`GnssEpoch.sigma_pr_noise_m`), else a `PseudorangeFactorArm` with the whole sigma."""
    pr = epoch.pr_corr_m + sagnac_m(epoch.sat_pos_ecef, p_approx_ecef)
    noise = epoch.sigma_pr_noise_m
    out, sig = [], []
    for i in range(epoch.n):
        if not np.isfinite(pr[i]):
            continue
        key = bias_key(epoch.sat[i], k) if bias_key is not None else None
        clk = CLK(str(epoch.system[i]), k)
        s = float((epoch.sigma_pr_m[i] if key is None else noise[i]) * sigma_scale)
        if key is None:
            out.append(gtsam.PseudorangeFactorArm(
                X(k), clk, float(pr[i]), epoch.sat_pos_ecef[i], lever_arm_b, ecef_T_nav, 0.0, robust(s, 1, huber_k)))
        else:
            out.append(gtsam.DifferentialPseudorangeFactorArm(
                X(k), clk, key, float(pr[i]), epoch.sat_pos_ecef[i], lever_arm_b, ecef_T_nav,
                0.0, robust(s, 1, huber_k)))
        sig.append(s)
    return (out, sig) if with_sigma else out


def doppler_factors(k: int, epoch, p_approx_ecef, lever_arm_b, omega_b, ecef_T_nav, huber_k=1.345,
                    sigma_scale: float = 1.0, with_sigma: bool = False):
    """DopplerFactorArm per satellite with Doppler at keyframe k, tied to the drift variable DRIFT(k); with
    `with_sigma` the list and the sigma (m/s) of each factor.

    gtsam's factor takes the receiver drift as (clock_curr - clock_prev) / dt; handing it (ZERO, DRIFT(k),
    dt = 1 s) makes that the instantaneous drift state (s/s) rather than the mean over the epoch interval,
    which would differ from it by the clock's random walk (~0.1-0.2 m/s for a TCXO, more than the noise).
    """
    rr = epoch.rr_corr_mps + sagnac_rate_mps(epoch.sat_pos_ecef, epoch.sat_vel_ecef, p_approx_ecef)
    out, sig = [], []
    for i in range(epoch.n):
        if not np.isfinite(rr[i]):
            continue
        s = float(epoch.sigma_rr_mps[i] * sigma_scale)
        # wavelength 1 m: the factor's measured range rate is -lambda*D, so D = -rr
        out.append(gtsam.DopplerFactorArm(
            X(k), V(k), ZERO(), DRIFT(k), float(-rr[i]), 1.0, epoch.sat_pos_ecef[i],
            epoch.sat_vel_ecef[i], p_approx_ecef, lever_arm_b, ecef_T_nav, omega_b, 1.0, 0.0, robust(s, 1, huber_k)))
        sig.append(s)
    return (out, sig) if with_sigma else out


def clock_factors(systems, k: int, dt: float, bias_rw_m: float, drift_rw_mps: float, lin_values) -> list:
    """Receiver clock process from keyframe k to k+1: b_s(k+1) = b_s(k) + d(k) dt + w, d(k+1) = d(k) + w'.

    Densities: `bias_rw_m` m/sqrt(s) on each bias, `drift_rw_mps` m/s/sqrt(s) on the drift. The bias
    equation is linear: a JacobianFactor wrapped as a nonlinear factor about `lin_values` (which must hold
    the three clock keys; its right-hand side is set so that the error is exactly A x).
    """
    out = []
    # the drift's own random walk integrates into the bias too (q_d dt^3 / 3)
    sb = np.sqrt(bias_rw_m ** 2 * dt + drift_rw_mps ** 2 * dt ** 3 / 3.0) / C_LIGHT
    d0 = lin_values.atDouble(DRIFT(k))
    for s in systems:
        x0 = lin_values.atDouble(CLK(s, k + 1)) - lin_values.atDouble(CLK(s, k)) - dt * d0
        jf = gtsam.JacobianFactor(CLK(s, k + 1), np.array([[1.0]]), CLK(s, k), np.array([[-1.0]]),
                                  DRIFT(k), np.array([[-float(dt)]]), np.array([-x0]),
                                  gtsam.noiseModel.Isotropic.Sigma(1, sb))
        out.append(gtsam.LinearContainerFactor(jf, lin_values))
    out.append(gtsam.BetweenFactorDouble(DRIFT(k), DRIFT(k + 1), 0.0,
                                         gtsam.noiseModel.Isotropic.Sigma(1, drift_rw_mps * np.sqrt(dt) / C_LIGHT)))
    return out


def position_factor(k: int, p_ant_nav, sigma_ned, lever_arm_b, huber_k=None):
    """LC: antenna position (nav frame, m) with per-axis sigmas (m) or a full 3x3 covariance (m^2), through the
    lever arm."""
    s = np.asarray(sigma_ned, float)
    base = (gtsam.noiseModel.Gaussian.Covariance(s) if s.shape == (3, 3)
            else gtsam.noiseModel.Diagonal.Sigmas(s))
    if huber_k is not None:
        base = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(float(huber_k)), base)
    return gtsam.GPSFactorArm(X(k), np.asarray(p_ant_nav, float), np.asarray(lever_arm_b, float), base)


def velocity_factor(k: int, v_nav, sigma_ned):
    """LC: IMU velocity (nav frame, m/s; the antenna's lever-arm rate already removed) with sigmas (m/s) or a full
    3x3 covariance (m^2/s^2)."""
    s = np.asarray(sigma_ned, float)
    noise = gtsam.noiseModel.Gaussian.Covariance(s) if s.shape == (3, 3) else gtsam.noiseModel.Diagonal.Sigmas(s)
    return gtsam.PriorFactorPoint3(V(k), np.asarray(v_nav, float), noise)
