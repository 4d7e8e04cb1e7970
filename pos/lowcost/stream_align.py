"""Align a logger's time axis with GPS time: coarse by the stream ends, fine by the PPS signal (seed 000, 3.1).

The logger clock is a crystal: GPS time = offset + (1 + drift) * logger time. The coarse step
assumes both recorders stopped together (the seed: less than a second apart). The fine step
builds a synthetic PPS from the GNSS time tags (high in the first half of every GPS second),
cross-correlates it with the PPS the logger recorded to find the sub-second phase, then fits
offset and drift to every recorded rising edge.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

from dgcal.fields.errors import InputError


@dataclass
class ClockFit:
    """GPS time = offset_s + (1 + drift) * t_logger; with the fit's sigmas and the edge residual RMS (s).

    The precision depends on how far the sampling phase sweeps through the PPS during the record:
    sub-millisecond needs drift * duration of at least about two samples (a crystal of +-50-100 ppm
    over ten minutes at 50 Hz); `max_error_s` says what the record supports.
    """

    offset_s: float
    drift: float
    sigma_offset_s: float
    sigma_drift: float
    residual_rms_s: float
    n_edges: int
    max_error_s: float = float("nan")  # bound on the clock error anywhere in the record (edge-consistent set)

    def to_gps(self, t_logger) -> np.ndarray:
        """GPS seconds of logger times (s)."""
        return self.offset_s + (1.0 + self.drift) * np.asarray(t_logger, float)


def coarse_offset_by_end(t_gps_last: float, t_logger_last: float) -> float:
    """Offset (s) that makes the two streams end together: GPS time = logger time + offset."""
    return float(t_gps_last - t_logger_last)


def synthetic_pps(t_gps: np.ndarray) -> np.ndarray:
    """The PPS level (1 high, 0 low) at GPS times: high during the first half of each second."""
    return (np.mod(np.asarray(t_gps, float), 1.0) < 0.5).astype(float)


def pps_phase_by_correlation(t_logger: np.ndarray, pps: np.ndarray, offset_s: float, step_s: float = 1e-3) -> float:
    """Sub-second shift (s, in [-0.5, 0.5)) to add to `offset_s` that best aligns the recorded PPS with the synthetic one."""
    level = (pps > 0.5 * (np.nanmax(pps) + np.nanmin(pps))).astype(float) * 2 - 1
    shifts = np.arange(-0.5, 0.5, step_s)
    t = np.asarray(t_logger, float) + offset_s
    # correlation with a square wave of period 1 s, evaluated for every candidate shift at once
    phase = np.mod(t[None, :] + shifts[:, None], 1.0)
    score = (np.where(phase < 0.5, 1.0, -1.0) * level[None, :]).sum(axis=1)
    return float(shifts[int(np.argmax(score))])


def rising_edges(t: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Times of rising edges of a two-level signal: the midpoint between the last low and first high sample."""
    x = np.asarray(level, float)
    hi = x > 0.5 * (np.nanmax(x) + np.nanmin(x))
    k = np.nonzero(~hi[:-1] & hi[1:])[0]
    return 0.5 * (t[k] + t[k + 1])


def fit_clock_to_pps(t_logger: np.ndarray, pps: np.ndarray, t_gps_last: float, t_logger_last: float,
                     valid: np.ndarray | None = None) -> ClockFit:
    """Fit GPS time = offset + (1 + drift) t_logger from the recorded PPS (coarse by the ends, then phase, then edges).

    `valid` masks samples that were really recorded (lost packets filled by copies carry no PPS information).
    """
    t_logger = np.asarray(t_logger, float)
    pps = np.asarray(pps, float)
    if valid is not None:
        t_logger, pps = t_logger[valid], pps[valid]
    offset = coarse_offset_by_end(t_gps_last, t_logger_last)
    offset += pps_phase_by_correlation(t_logger, pps, offset)
    # keep only edges whose neighbouring samples are consecutive recorded samples
    edges = rising_edges(t_logger, pps)
    if len(edges) < 3:
        raise InputError(f"only {len(edges)} PPS rising edges recorded; need 3 or more", field="pps")
    dt_nom = np.median(np.diff(t_logger))
    k = np.searchsorted(t_logger, edges)
    ok = (t_logger[k] - t_logger[k - 1]) < 1.5 * dt_nom
    k = k[ok]
    lo, hi = t_logger[k - 1], t_logger[k]  # each edge lies between its last low and first high sample
    target = np.round(0.5 * (lo + hi) + offset)  # the GPS second each edge marks
    fit = _chebyshev_clock(lo, hi, target, offset)
    if fit is None:  # inconsistent edges (jitter, glitches): least squares on the midpoints instead
        return _least_squares_clock(0.5 * (lo + hi), target, float(dt_nom))
    return fit


def _chebyshev_clock(lo: np.ndarray, hi: np.ndarray, target: np.ndarray, base: float) -> ClockFit | None:
    """Offset and drift at the centre of the set consistent with every edge (a linear programme).

    The sampling phase walks through the PPS as the crystal drifts, so the edge intervals act like
    a vernier: together they pin the clock far below one sample. Quantisation errors are not
    random here (they sweep linearly with time), which is why plain least squares on edge
    midpoints would bias the drift.
    """

    tm = 0.5 * (lo[0] + hi[-1])
    T = max(1.0, float(hi[-1] - lo[0]))
    a, b = (lo - tm) / T, (hi - tm) / T
    # unknowns: o, D = drift * T, r (radius); GPS(t) = t + base + o + D (t - tm) / T, with `base` the
    # approximate offset taken out so the programme sees small numbers (GPS seconds are ~1e9)
    # o + D a + r |(1,a)| <= target - base - lo ;  -o - D b + r |(1,b)| <= hi + base - target
    na, nb = np.hypot(1, a), np.hypot(1, b)
    A = np.vstack([np.column_stack([np.ones_like(a), a, na]), np.column_stack([-np.ones_like(b), -b, nb])])
    rhs = np.r_[(target - base) - lo, hi - (target - base)]
    res = linprog([0, 0, -1], A_ub=A, b_ub=rhs, bounds=[(None, None), (None, None), (0, None)], method="highs")
    if res.status != 0 or res.x[2] <= 0:
        return None
    o, D, r = res.x
    # honest bound: how far the clock at either end of the record can move within the feasible set
    half = 0.0
    for ends in (a[0], b[-1]):
        ext = [linprog(sgn * np.array([1.0, ends]), A_ub=A[:, :2], b_ub=rhs, bounds=[(None, None)] * 2,
                       method="highs") for sgn in (1, -1)]
        if all(e.status == 0 for e in ext):
            half = max(half, 0.5 * (-ext[1].fun - ext[0].fun))
    drift = D / T
    offset = base + o - drift * tm
    mid = 0.5 * (lo + hi)
    resid = target - (offset + (1 + drift) * mid)
    # the feasible set's inscribed radius bounds the error; quote it as a one-sigma figure of a uniform spread
    return ClockFit(float(offset), float(drift), float(half / np.sqrt(3)), float(2 * half / np.sqrt(3) / T),
                    float(np.sqrt(np.mean(resid**2))), int(len(lo)), float(half))


def _least_squares_clock(edges: np.ndarray, target: np.ndarray, dt_nom: float) -> ClockFit:
    A = np.column_stack([np.ones_like(edges), edges])
    coef, *_ = np.linalg.lstsq(A, target - edges, rcond=None)
    res = target - edges - A @ coef
    s2 = max(res.var(ddof=2) if len(res) > 2 else dt_nom**2 / 12, 1e-12)
    cov = s2 * np.linalg.inv(A.T @ A)
    return ClockFit(float(coef[0]), float(coef[1]), float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1])),
                    float(np.sqrt(np.mean(res**2))), int(len(edges)), float(3 * np.sqrt(cov[0, 0])))
