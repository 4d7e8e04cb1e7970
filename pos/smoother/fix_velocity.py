"""The LC fixes' velocities and their timing (`SmootherOptions.lc_velocity`, "auto" by default).

A GNSS solution file's velocity is often not the velocity at its epoch. RTKLIB's comes from its Kalman filter and
lags: on the real car drive (`../shared/data/gnss-imu-drive`) it trails the positions by about 0.125 s, and the
smoother that used it as stated closed 15 s gaps to 0.28 m with error/sigma 2.1/3.0 (N/E) instead of 0.22 m
without it. A receiver's Doppler velocity (`--mode spp`, a simulator) is on time. Which one a file holds cannot be
told from its columns, so by default ("auto") the smoother first solves without the velocities and measures them
against its own antenna velocity, which the positions and the IMU give to centimetres per second:

    v_fix(t) = v(t - delta) + eps x v(t) + n  ~  v(t) - delta a(t) + eps x v(t) + n,

the latency delta by weighted least squares over every fix (a the antenna acceleration of the solution) together
with a rotation eps of the solution's velocity (its attitude error: in a level turn at constant speed a heading
error looks just like a latency, 0.2 deg in a 0.14 rad/s turn like 25 ms; speed changes and climbs tell them
apart); its sigma from the scatter or, when larger, from the spread of the latencies of eight stretches of the
record (the solution's own velocity error is smooth and can follow the acceleration for a while).

A velocity late by delta is off by delta a, along the acceleration only. So the velocities are always used, but
what the latency leaves uncertain is noise along the acceleration: where the data determine it (sigma within
`LATENCY_SIGMA_MAX_S`) a significant (3 sigma) latency is removed (each keyframe gets the fix velocity interpolated
at t + delta) and its sigma is that noise; where they do not (a fixed-wing flying level turns at constant speed),
the velocities count only across the acceleration (a latency of up to `LATENCY_MAX_S`). On the drive: 125 +- 2 ms,
removed (gaps 0.18 m, error/sigma 0.9); on a simulated low-cost fixed-wing (on-time velocities, no speed changes):
not determined, the velocities inform the tilt and the heading across the turns. "true" uses them as stated,
"false" never.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LATENCY_SIGMA_MAX_S = 0.02      # the velocities are used when their latency is known to this (s)
LATENCY_MAX_S = 1.0             # ... and within this
LATENCY_PRIOR_S = 0.2           # what a solution's velocity may lag by, unknown (a receiver's or RTKLIB's filter)
BLOCKS = 8                      # stretches of the record whose latencies' spread bounds its sigma from below


def velocity_mode(value) -> str:
    """`SmootherOptions.lc_velocity` as one of "auto", "true", "false" (booleans and their words accepted)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    v = str(value).strip().lower()
    if v in ("true", "yes", "on", "1"):
        return "true"
    if v in ("false", "no", "off", "0", "none"):
        return "false"
    if v == "auto":
        return v
    raise ValueError(f"lc_velocity must be auto, true or false, not {value!r}")


@dataclass
class VelocityLatency:
    """The fixes' velocity latency (s, positive: the velocity lags) and its sigma, the factor by which their stated
    variance is too small after it is removed (against the solution's velocity, whose own error counts in it:
    reported, not applied), the fixes compared and whether the velocities are used."""

    @property
    def shift_s(self) -> float:
        """The latency removed from the velocities: the estimate where it is known (`used`) and significant (3
        sigma), else none."""
        return self.latency_s if self.used and abs(self.latency_s) > 3.0 * self.sigma_s else 0.0

    @property
    def sigma_left_s(self) -> float:
        """What is not known of the latency once `shift_s` is removed (s): its sigma and the estimate left in,
        or `LATENCY_PRIOR_S` where the data do not determine it."""
        if not self.used:
            return LATENCY_PRIOR_S
        left = self.latency_s - self.shift_s
        return float(np.hypot(self.sigma_s, left))

    latency_s: float
    sigma_s: float
    variance_factor: float
    n: int
    used: bool

    def as_dict(self) -> dict:
        """JSON-ready (ms)."""
        return {"latency_ms": round(1e3 * self.latency_s, 1), "sigma_ms": round(1e3 * self.sigma_s, 1),
                "removed_ms": round(1e3 * self.shift_s, 1), "sigma_left_ms": round(1e3 * self.sigma_left_s, 1),
                "variance_factor": round(self.variance_factor, 2),
                "n": self.n, "used": self.used}


def _skew_rows(v: np.ndarray) -> np.ndarray:
    """(M,3,3) the matrices of e -> e x v, i.e. -[v]x, for each row of v."""
    out = np.zeros(v.shape + (3,))
    out[:, 0, 1], out[:, 0, 2] = v[:, 2], -v[:, 1]
    out[:, 1, 0], out[:, 1, 2] = -v[:, 2], v[:, 0]
    out[:, 2, 0], out[:, 2, 1] = v[:, 1], -v[:, 0]
    return out


def _fit(H: np.ndarray, d: np.ndarray, w: np.ndarray):
    """Weighted least squares of d (M,3) on the parameters with design H (M,3,p): (x, normal matrix)."""
    N = np.einsum("mip,mi,miq->pq", H, w, H)
    g = np.einsum("mip,mi,mi->p", H, w, d)
    return np.linalg.lstsq(N, g, rcond=None)[0], N


def velocity_latency(t_key: np.ndarray, v_ant: np.ndarray, k: np.ndarray, v_fix: np.ndarray,
                     sigma_v: np.ndarray) -> VelocityLatency:
    """The latency of the fix velocities `v_fix` (M,3) nav m/s with sigmas (M,3) at keyframes `k` against the
    solution's antenna velocity `v_ant` (K,3) at the keyframes `t_key` (module docstring)."""
    ok = np.all(np.isfinite(v_fix), axis=1) & np.all(np.isfinite(sigma_v) & (sigma_v > 0), axis=1)
    k, v_fix, sigma_v = k[ok], v_fix[ok], sigma_v[ok]
    if len(k) < 10 or len(t_key) < 3:
        return VelocityLatency(0.0, np.inf, 1.0, int(len(k)), False)
    a = np.gradient(v_ant, t_key, axis=0)[k]
    w = 1.0 / sigma_v ** 2
    d = v_ant[k] - v_fix                                    # = delta a + eps x v + noise
    # with the latency, a rotation eps of the solution's velocity (its attitude error, while the IMU carries it): in a
    # level turn at constant speed a heading error's e x v is parallel to the acceleration and looks just like a
    # latency (0.2 deg in a 0.14 rad/s turn: 25 ms); speed changes and climbs tell them apart
    # the attitude error drifts (a MEMS gyro's heading by tenths of a degree in a minute): one rotation per stretch
    blocks = np.array_split(np.arange(len(k)), BLOCKS)
    R = _skew_rows(v_ant[k])
    H = np.zeros((len(k), 3, 1 + 3 * len(blocks)))
    H[:, :, 0] = a
    for b, kb in enumerate(blocks):
        H[kb, :, 1 + 3 * b:4 + 3 * b] = R[kb]
    x, N = _fit(H, d, w)
    delta = float(x[0])
    r = d - np.einsum("mip,p->mi", H, x)
    f = float(np.sum(w * r * r) / max(r.size - H.shape[2], 1))     # variance factor of the stated sigmas
    try:
        sigma = float(np.sqrt(max(f, 1.0) * np.linalg.inv(N)[0, 0]))
    except np.linalg.LinAlgError:
        sigma = np.inf
    # the reference is not exact: the solution's velocity error is smooth and can follow the acceleration for a
    # while (a scale factor in a turn), which the scatter above does not show. The latency of separate stretches of
    # the record scatters with it: their spread (as the sigma of their mean) is the honest sigma when larger
    parts, info = [], []
    for b, kb in enumerate(blocks):
        if len(kb) < 10:
            continue
        xb, Nb = _fit(H[kb][:, :, [0, 1 + 3 * b, 2 + 3 * b, 3 + 3 * b]], d[kb], w[kb])
        try:
            var_b = float(np.linalg.inv(Nb)[0, 0])
        except np.linalg.LinAlgError:
            continue
        if np.isfinite(var_b) and var_b > 0:
            parts.append(float(xb[0]))
            info.append(1.0 / var_b)
    if len(parts) >= 3 and np.isfinite(sigma):
        # the information-weighted spread of the stretches' latencies about their weighted mean, as its sigma
        p, wb = np.array(parts), np.array(info)
        mean = float(np.sum(wb * p) / np.sum(wb))
        spread = float(np.sum(wb * (p - mean) ** 2) / ((len(p) - 1) * np.sum(wb)))
        sigma = max(sigma, float(np.sqrt(spread)))
    else:
        sigma = np.inf
    used = sigma <= LATENCY_SIGMA_MAX_S and abs(delta) <= LATENCY_MAX_S
    return VelocityLatency(delta, sigma, f, int(len(k)), bool(used))


def shifted_velocities(t: np.ndarray, v: np.ndarray, delta: float) -> np.ndarray:
    """The fix velocities (M,3) at their epochs `t` corrected for a latency `delta` (s): each epoch takes the velocity
    reported `delta` later, interpolated between neighbouring fixes (held at the ends; NaN stays NaN)."""
    out = np.empty_like(v)
    for j in range(3):
        ok = np.isfinite(v[:, j])
        out[:, j] = np.interp(t + delta, t[ok], v[ok, j]) if ok.sum() >= 2 else v[:, j]
        out[~ok, j] = np.nan
    return out
