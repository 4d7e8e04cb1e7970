"""Initial values for the smoother in motion: positions/velocities from GNSS fixes, attitude from the GNSS
velocity (pseudo-attitude) at one moving epoch propagated with the gyros, receiver clocks from the
pseudoranges.

No static alignment is needed: the smoother refines the coarse attitude (heading errors of several degrees
converge because the turns of a flight make heading observable).
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from dgcal.fields.constants import C_LIGHT, OMEGA_EARTH
from dgcal.fields.frames import R_body_to_ned_from_rph
from dgcal.pos.gnss.pseudo_attitude import pseudo_attitude
from dgcal.pos.ins.nav_frame import NavFrame


@dataclass
class GnssFixes:
    """Antenna positions (and optionally velocities) from GNSS: SPP for initialisation, or the LC input.

    t (N,) GPS s; p_ecef (N,3) m; sigma_ned (N,3) m; v_ecef (N,3) m/s or None; sigma_v_ned (N,3) m/s or None;
    cov_ned (N,3,3) m^2 or None: the full position covariance (local NED), used instead of sigma_ned when given.
    velocity_on_time: True when the velocities are known to be the epoch's (a receiver's Doppler velocity, SPP's);
    None when that is not known (a solution file: RTKLIB's filter velocity lags), and the LC smoother measures their
    latency (`dgcal.pos.smoother.fix_velocity`).
    """

    t: np.ndarray
    p_ecef: np.ndarray
    sigma_ned: np.ndarray
    v_ecef: np.ndarray | None = None
    sigma_v_ned: np.ndarray | None = None
    cov_ned: np.ndarray | None = None
    velocity_on_time: bool | None = None


def interp_rows(t_new: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column of y (N,d) at t_new (held constant outside)."""
    return np.stack([np.interp(t_new, t, y[:, j]) for j in range(y.shape[1])], axis=1)


def initial_track(t_key: np.ndarray, fixes: GnssFixes, frame: NavFrame):
    """Antenna track at keyframes in nav (p (K,3) m, v (K,3) m/s), interpolated over gaps."""
    ok = np.all(np.isfinite(fixes.p_ecef), axis=1)
    if ok.sum() < 2:
        raise ValueError("fewer than two GNSS fixes to initialise the trajectory")
    p_nav = frame.from_ecef(fixes.p_ecef[ok])
    p = interp_rows(t_key, fixes.t[ok], p_nav)
    if fixes.v_ecef is not None and np.all(np.isfinite(fixes.v_ecef[ok])):
        v = interp_rows(t_key, fixes.t[ok], fixes.v_ecef[ok] @ frame.R_nav_to_ecef)
    else:
        v = np.gradient(p, t_key, axis=0)
    return p, v


def wide_derivative(t: np.ndarray, y: np.ndarray, half_window_s: float = 0.5) -> np.ndarray:
    """d y / d t (along axis 0) as the secant over about +-`half_window_s` (at least the neighbours): at 50 Hz the
    neighbours' difference of 5 cm/s velocity noise is 3.5 m/s^2, which put a pseudo-attitude's roll tens of
    degrees off (and the smoother into a wrong minimum)."""
    t = np.asarray(t, float)
    if len(t) < 2:
        return np.zeros_like(y)
    m = max(1, int(round(half_window_s / float(np.median(np.diff(t))))))
    i = np.arange(len(t))
    lo, hi = np.maximum(i - m, 0), np.minimum(i + m, len(t) - 1)
    return (y[hi] - y[lo]) / (t[hi] - t[lo])[:, None]


def anchor_attitude(t_key: np.ndarray, v_nav: np.ndarray, min_speed: float = 3.0) -> tuple[int, np.ndarray]:
    """Keyframe index and coarse R_body_to_nav at the first moving epoch: the pseudo-attitude of the GNSS
    velocity (dgcal.pos.gnss.pseudo_attitude: roll from the turn's centripetal acceleration, pitch = flight-path
    angle, heading = course); level with heading = course if it cannot be formed."""
    pa = pseudo_attitude(t_key, v_nav, a_ned=wide_derivative(t_key, v_nav), min_speed=min_speed)
    ok = np.flatnonzero(pa.valid & np.all(np.isfinite(pa.rph), axis=1))
    if len(ok):
        a = int(ok[0])
        return a, R_body_to_ned_from_rph(*pa.rph[a])
    vh = np.hypot(v_nav[:, 0], v_nav[:, 1])
    moving = np.flatnonzero(vh > min_speed)
    a = int(moving[0]) if len(moving) else 0
    heading = np.degrees(np.arctan2(v_nav[a, 1], v_nav[a, 0]))
    return a, R_body_to_ned_from_rph(0.0, 0.0, heading)


def propagate_attitude(pims: list, anchor: int, R_body_to_nav_anchor: np.ndarray, p_nav, v_nav) -> np.ndarray:
    """R_body_to_nav at all keyframes by chaining the preintegrated rotations from the anchor (both ways)."""
    K = len(pims) + 1
    R_body_to_nav = np.empty((K, 3, 3))
    R_body_to_nav[anchor] = R_body_to_nav_anchor
    zero = gtsam.imuBias.ConstantBias()
    for k in range(anchor, K - 1):
        ns = gtsam.NavState(gtsam.Rot3(R_body_to_nav[k]), p_nav[k], v_nav[k])
        R_body_to_nav[k + 1] = pims[k].predict(ns, zero).attitude().matrix()
    for k in range(anchor - 1, -1, -1):
        R_body_to_nav[k] = R_body_to_nav[k + 1] @ pims[k].deltaRij().matrix().T
    return R_body_to_nav


def group_medians(group: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The groups present (ascending) and the median of x within each (as np.median: the mean of the middle two
    of an even count)."""
    if not len(x):
        return np.zeros(0, int), np.zeros(0)
    o = np.lexsort((x, group))
    g, v = group[o], x[o]
    first = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    cnt = np.diff(np.r_[first, len(g)])
    lo = first + (cnt - 1) // 2
    hi = first + cnt // 2
    return g[first], 0.5 * (v[lo] + v[hi])


def sagnac_rows(sat_pos_ecef: np.ndarray, p_rx_ecef: np.ndarray) -> np.ndarray:
    """`sagnac_m` with one receiver position per satellite row (N,3) m."""
    return OMEGA_EARTH / C_LIGHT * (sat_pos_ecef[:, 0] * p_rx_ecef[:, 1] - sat_pos_ecef[:, 1] * p_rx_ecef[:, 0])


def initial_clocks(t_key, epochs_at_key, p_ant_nav, frame: NavFrame, systems) -> tuple[dict, np.ndarray]:
    """Receiver clock bias per constellation (s) at keyframes from the pseudoranges at the initial track,
    and the drift (s/s)."""
    K = len(t_key)
    clk = {s: np.full(K, np.nan) for s in systems}
    ks = [k for k, ep in enumerate(epochs_at_key) if ep is not None and ep.n > 0]
    if ks:
        n = np.array([epochs_at_key[k].n for k in ks])
        kk = np.repeat(ks, n)
        sat = np.concatenate([epochs_at_key[k].sat_pos_ecef for k in ks])
        pr = np.concatenate([epochs_at_key[k].pr_corr_m for k in ks])
        system = np.concatenate([np.asarray(epochs_at_key[k].system, str) for k in ks])
        r = frame.to_ecef(p_ant_nav[kk])
        res = pr + sagnac_rows(sat, r) - np.linalg.norm(sat - r, axis=1)
        for s in systems:
            m = (system == s) & np.isfinite(res)
            k_s, med = group_medians(kk[m], res[m])
            clk[s][k_s] = med / C_LIGHT
    ref = None
    for s in systems:
        good = np.isfinite(clk[s])
        if good.sum() == 0:
            clk[s][:] = 0.0 if ref is None else clk[ref]
            continue
        clk[s] = np.interp(t_key, t_key[good], clk[s][good])
        ref = ref or s
    drift = np.gradient(clk[ref], t_key) if ref is not None and K > 1 else np.zeros(K)
    return clk, drift
