"""A static start and end of the data, detected and used as zero-velocity information.

A vehicle standing still before it moves off (a car at the kerb, a UAV on the ground before take-off) and after
it stops gives the smoother what the GNSS alone cannot: zero velocity, no rotation (the gyro biases, and the
heading held) and no displacement. Only the leading and trailing runs of keyframes are used, never a pause in
the middle of the data (a hovering multirotor has near-zero GNSS velocity but is not at rest).

A keyframe is at rest when the GNSS speed is below ``speed_mps`` plus twice its sigma and the IMU is quiet: the
standard deviation of the specific-force magnitude within +-0.5 s is below ``accel_std_mps2`` (engine or rotor
vibration at rest stays far below a moving vehicle's accelerations) and the magnitude of the mean angular rate
there below ``gyro_mean_dps`` (the mean of the vector: vibration averages out, a turn does not). The run must
last ``min_duration_s``; half a second is cut at its moving end.
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from dgcal.pos.smoother.factors import V, X


@dataclass
class StaticOptions:
    """Detection thresholds (m/s, m/s^2, deg/s, s) and the zero-motion sigmas (m/s, m, deg) of a static start/end."""

    speed_mps: float = 0.05
    accel_std_mps2: float = 0.3
    gyro_mean_dps: float = 1.0
    min_duration_s: float = 3.0
    sigma_v_mps: float = 0.01
    sigma_pos_m: float = 0.003
    sigma_rot_deg: float = 0.02


def _speed_at(t_key: np.ndarray, fixes) -> tuple[np.ndarray, np.ndarray]:
    """GNSS speed (m/s) and its sigma at the keyframes (inf where unknown)."""
    if fixes is None or fixes.v_ecef is None:
        return np.full(len(t_key), np.inf), np.zeros(len(t_key))
    v = fixes.v_ecef
    ok = np.all(np.isfinite(v), axis=1)
    if ok.sum() < 2:
        return np.full(len(t_key), np.inf), np.zeros(len(t_key))
    sp = np.linalg.norm(v[ok], axis=1)
    s = np.linalg.norm(fixes.sigma_v_ned[ok], axis=1) if fixes.sigma_v_ned is not None else np.zeros(ok.sum())
    t = fixes.t[ok]
    far = np.abs(t[np.clip(np.searchsorted(t, t_key), 0, len(t) - 1)] - t_key) > 1.5
    out = np.interp(t_key, t, sp)
    out[far | (t_key < t[0] - 1.0) | (t_key > t[-1] + 1.0)] = np.inf
    return out, np.interp(t_key, t, np.nan_to_num(s))


def _imu_quiet(imu, t_key: np.ndarray, o: StaticOptions) -> np.ndarray:
    """IMU at rest around each keyframe (specific-force magnitude scatter and mean rate within +-0.5 s)."""
    f = np.linalg.norm(imu.accel_m_s2, axis=1)
    a = np.searchsorted(imu.t, t_key - 0.5)
    b = np.searchsorted(imu.t, t_key + 0.5)
    c1, c2 = (np.concatenate([[0.0], np.cumsum(x)]) for x in (f, f * f))
    cw = np.vstack([np.zeros(3), np.cumsum(imu.gyro_rad_s, axis=0)])
    n = np.maximum(b - a, 1)
    mean = (c1[b] - c1[a]) / n
    var = np.maximum((c2[b] - c2[a]) / n - mean ** 2, 0.0)
    wmean = np.degrees(np.linalg.norm(cw[b] - cw[a], axis=1) / n)   # mean rate vector: vibration averages out
    return (b - a >= 3) & (np.sqrt(var) < o.accel_std_mps2) & (wmean < o.gyro_mean_dps)


def static_ends(imu, t_key: np.ndarray, fixes, opts: StaticOptions | None = None) -> np.ndarray:
    """Boolean (K,): the keyframes of a static start and a static end of the data (see the module docstring)."""
    o = opts or StaticOptions()
    sp, ssp = _speed_at(t_key, fixes)
    rest = (sp < o.speed_mps + 2.0 * ssp) & _imu_quiet(imu, t_key, o)
    out = np.zeros(len(t_key), bool)
    for idx in (np.arange(len(t_key)), np.arange(len(t_key))[::-1]):
        run = []
        for k in idx:
            if not rest[k]:
                break
            run.append(k)
        if len(run) >= 2:
            run = np.array(run)
            span = abs(t_key[run[-1]] - t_key[run[0]])
            if span >= o.min_duration_s:
                edge = t_key[run[-1]]
                keep = np.abs(t_key[run] - edge) >= 0.5
                out[run[keep]] = True
    return out


def zero_motion_factors(static: np.ndarray, t_key: np.ndarray, opts: StaticOptions | None = None) -> list:
    """(keyframe, kind, factor) for the static keyframes: zero velocity at each, and no rotation and no
    displacement between consecutive static keyframes (BetweenFactorPose3 to the identity)."""
    o = opts or StaticOptions()
    out = []
    nv = gtsam.noiseModel.Isotropic.Sigma(3, o.sigma_v_mps)
    npose = gtsam.noiseModel.Diagonal.Sigmas(np.r_[[np.radians(o.sigma_rot_deg)] * 3, [o.sigma_pos_m] * 3])
    for k in np.nonzero(static)[0]:
        out.append((int(k), "zupt", gtsam.PriorFactorPoint3(V(int(k)), np.zeros(3), nv)))
        if k > 0 and static[k - 1]:
            out.append((int(k), "zaru", gtsam.BetweenFactorPose3(X(int(k) - 1), X(int(k)), gtsam.Pose3(), npose)))
    return out


def static_white_noise(imu, t_key: np.ndarray, static: np.ndarray, tau_s: float = 0.1) -> tuple[float, float] | None:
    """White-noise densities measured at rest: (gyro rad/sqrt(s), accel m/s/sqrt(s)) from the Allan deviation at
    `tau_s` of the IMU in each static run (RMS over the three axes, the larger run), or None without a run of at
    least 20 tau. At rest an engine's or rotors' vibration shows here; datasheet densities are for a quiet sensor."""
    if static is None or not static.any():
        return None
    k = np.nonzero(static)[0]
    runs = np.split(k, np.nonzero(np.diff(k) > 1)[0] + 1)
    m = max(int(round(tau_s * imu.rate_hz)), 1)
    best = None
    for r in runs:
        i0, i1 = np.searchsorted(imu.t, [t_key[r[0]], t_key[r[-1]]])
        n = (i1 - i0) // m
        if n < 20:
            continue
        out = []
        for x in (imu.gyro_rad_s[i0:i0 + n * m], imu.accel_m_s2[i0:i0 + n * m]):
            xm = x.reshape(n, m, 3).mean(axis=1)
            adev = np.sqrt(0.5 * np.mean(np.diff(xm, axis=0) ** 2, axis=0))
            out.append(float(np.sqrt(np.mean(adev ** 2)) * np.sqrt(m / imu.rate_hz)))
        best = out if best is None else [max(a, b) for a, b in zip(best, out)]
    return None if best is None else (best[0], best[1])
