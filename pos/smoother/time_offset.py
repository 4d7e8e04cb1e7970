"""The IMU-GNSS time offset estimated with its sigma, from the smoother's own chi-square profile.

An IMU logged on a clock that is off from GNSS time by delta puts every specific force and rate delta seconds
early or late: in motion the GNSS measurements then disagree with the IMU by about v*delta and a*delta, and the
smoother's minimum cost (chi-square, twice gtsam's error) grows with |delta - delta_true|. Around its minimum the
profile is a parabola, chi2(d) = chi2_min + (d - d_hat)^2 / sigma^2 for Gaussian errors (the profile likelihood):
three smoothings at d0 - h, d0, d0 + h give d_hat and sigma, and the step h is refined once around d_hat (h near
sigma keeps the parabola's own error small). The offset is a constant of the whole record; the smoother is run
as usual at each trial offset, so everything it models (carrier phase, code biases, static ends) counts.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from dgcal.pos.ins.imu_data import ImuData
from dgcal.pos.smoother.batch import smooth


@dataclass
class TimeOffsetEstimate:
    """The IMU time offset (s, added to the IMU's time tags) minimising the smoother's chi-square, its sigma (s)
    from the profile's curvature, and the trials (offset s, chi-square)."""

    offset_s: float
    sigma_s: float
    trials: list = field(default_factory=list)
    note: str = ""

    def as_dict(self) -> dict:
        """JSON-ready: offset and sigma in ms, the trials, the note."""
        return {"offset_ms": round(1e3 * self.offset_s, 3), "sigma_ms": round(1e3 * self.sigma_s, 3),
                "trials": [[round(1e3 * d, 3), round(c, 3)] for d, c in self.trials], "note": self.note}


def parabola_vertex(d: np.ndarray, c: np.ndarray) -> tuple[float, float]:
    """Vertex (d_hat) and 1-sigma half-width (where the chi-square grows by one) of the parabola through three
    points (d, chi-square); (nan, nan) if it does not open upwards."""
    A = np.vstack([d ** 2, d, np.ones(3)]).T
    a, b, _ = np.linalg.solve(A, c)
    if not np.isfinite(a) or a <= 0:
        return float("nan"), float("nan")
    return float(-b / (2 * a)), float(1.0 / np.sqrt(a))


def estimate_time_offset(chi2_at: Callable[[float], float], start_s: float = 0.0, step_s: float = 0.02,
                         max_widen: int = 4) -> TimeOffsetEstimate:
    """The IMU time offset (s) minimising `chi2_at(offset)` (the smoother's chi-square with the IMU's times shifted
    by `offset`): a parabola through start - h, start, start + h, h widened (x4) while the profile is flat or not
    convex within it and re-centred on a vertex outside it, then one more parabola centred on the estimate with
    h = max(sigma, h/4)."""
    trials: list = []

    def run(d: float) -> float:
        c = float(chi2_at(d))
        trials.append((d, c))
        return c

    h = step_s
    centre = start_s
    c0 = run(centre)
    d_hat = sig = float("nan")
    for _ in range(max_widen):
        cm, cp = run(centre - h), run(centre + h)
        d_hat, sig = parabola_vertex(np.array([centre - h, centre, centre + h]), np.array([cm, c0, cp]))
        if np.isfinite(d_hat) and abs(d_hat - centre) <= 2 * h and sig < 4 * h:
            break
        if np.isfinite(d_hat) and abs(d_hat - centre) > 2 * h:
            centre = float(np.clip(d_hat, centre - 10 * h, centre + 10 * h))   # jump towards the vertex
            h = max(h, min(sig, 4 * h)) if np.isfinite(sig) else h
            c0 = run(centre)
        else:
            h *= 4.0
    if not np.isfinite(d_hat):
        return TimeOffsetEstimate(start_s, float("inf"), trials, "the chi-square does not change with the offset: "
                                  "too little motion to observe it")
    h2 = max(min(sig, h), h / 4.0)
    c_mid = run(d_hat)
    d2, s2 = parabola_vertex(np.array([d_hat - h2, d_hat, d_hat + h2]),
                             np.array([run(d_hat - h2), c_mid, run(d_hat + h2)]))
    if np.isfinite(d2) and abs(d2 - d_hat) <= 2 * h2:
        d_hat, sig = d2, s2
    return TimeOffsetEstimate(float(d_hat), float(sig), trials)


def shifted_imu(imu, offset_s: float):
    """The IMU data with `offset_s` (s) added to every time tag (and to its bridged spans)."""
    return ImuData(imu.t + offset_s, imu.dtheta, imu.dvel, imu.rate_hz, imu.path, imu.lines,
                   [replace(b, t0=b.t0 + offset_s, t1=b.t1 + offset_s) for b in imu.bridges])


def smoother_chi2(imu, fixes, grade, opts, mode: str = "tc", gnss=None, lc_fixes=None, carrier=None
                  ) -> Callable[[float], float]:
    """chi2(offset): the smoother's final chi-square (twice gtsam's error, both passes, no covariances) with the
    IMU's time tags shifted by `offset` s; the GNSS inputs as `dgcal.pos.smoother.batch.smooth` takes them.

    LC: the noise is what the data show (the IMU's white noise in motion and the fixes' white share, estimated by
    one smoothing with covariances at the offset as given, `dgcal.pos.smoother.batch`) and held for every trial: a
    profile drawn with weights the data contradict has its minimum elsewhere (on the real drive the IMU noise the
    static start shows, half what the drive shows, moved it by 15 ms)."""
    quiet = replace(opts, covariances=False)
    if mode == "lc" and opts.covariances:
        cal = smooth(imu, fixes, grade, opts, mode=mode, gnss=gnss, lc_fixes=lc_fixes, carrier=carrier)
        grade = cal.imu_noise if cal.imu_noise is not None else grade
        share = cal.problem.lc.white_share if cal.problem.lc is not None else opts.lc_fix_white_share
        quiet = replace(quiet, motion_noise=False, lc_fix_white_share=share)

    def chi2(offset_s: float) -> float:
        sol = smooth(shifted_imu(imu, offset_s), fixes, grade, quiet, mode=mode, gnss=gnss, lc_fixes=lc_fixes,
                     carrier=carrier)
        return 2.0 * float(sol.info["error_final"])
    return chi2
