"""Align a logger's time axis with GPS time (seed 000, 3.1): PPS for the sub-second clock, a coarse alignment for
the whole second, each checked against the other.

The logger clock is a crystal: GPS time = offset + (1 + drift) * logger time. The recorded PPS (high in the
first half of every GPS second) fixes drift and the sub-second phase, but not which GPS second each edge
marks: that whole-second part comes from a coarse alignment —
- `coarse_by_correlation`: the logger's laser range or barometric height against the GNSS height (band-passed,
  normalised cross-correlation over the whole offset range, refined to a fraction of a sample, with an
  ambiguity figure: the best peak away from the best one);
- `coarse_by_time_tags`: GNSS time the logger itself received (an NMEA/binary time field in its packets);
- `coarse_by_ends`: the streams' last packets, only when the user can bound how far apart the recorders
  stopped (the seed's assumption; they may stop many seconds apart).
`resolve_whole_seconds` combines the two and says whether the coarse figure is good enough to pick the
second, and whether the PPS fit contradicts it.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import linprog

from dgcal.fields.errors import InputError


@dataclass
class ClockFit:
    """GPS time = offset_s + (1 + drift) * t_logger; with the fit's sigmas and the edge residual RMS (s).

    The precision depends on how far the sampling phase sweeps through the PPS during the record:
    sub-millisecond needs drift * duration of at least about two samples (a crystal of +-50-100 ppm
    over ten minutes at 50 Hz); `max_error_s` bounds the clock error anywhere in the record (the
    edge-consistent set). `n_expected` counts the edges a perfect record would show (whole GPS seconds
    whose two bracketing samples were recorded), `n_spurious` the edges that fit no second,
    `residual_max_s` the largest edge-midpoint residual and `dt_s` the sampling interval; `whole_second`
    says whether the whole-second part of `offset_s` is resolved (False: known modulo 1 s).
    """

    offset_s: float
    drift: float
    sigma_offset_s: float
    sigma_drift: float
    residual_rms_s: float
    n_edges: int
    max_error_s: float = float("nan")
    n_expected: int = -1
    n_spurious: int = 0
    residual_max_s: float = float("nan")
    dt_s: float = float("nan")
    consistent: bool = True          # every edge inside its sample interval (the linear programme was feasible)
    whole_second: bool = True
    drift_range: tuple[float, float] = (float("nan"), float("nan"))   # drifts consistent with every edge

    def to_gps(self, t_logger) -> np.ndarray:
        """GPS seconds of logger times (s)."""
        return self.offset_s + (1.0 + self.drift) * np.asarray(t_logger, float)


@dataclass
class CoarseAlignment:
    """A coarse GPS time `gps_at_ref` (s) of logger time `t_ref` (s) by `method`, with a sigma (s) and a bound
    (s: the error it is trusted within; four sigmas for correlations, the declared gap for stream ends) and
    the figures that back it (correlation peak, ambiguity ratio, search range...)."""

    method: str
    t_ref: float
    gps_at_ref: float
    sigma_s: float
    bound_s: float
    figures: dict = field(default_factory=dict)

    @property
    def offset_s(self) -> float:
        """GPS time minus logger time at `t_ref` (s)."""
        return float(self.gps_at_ref - self.t_ref)


def coarse_offset_by_end(t_gps_last: float, t_logger_last: float) -> float:
    """Offset (s) that makes the two streams end together: GPS time = logger time + offset."""
    return float(t_gps_last - t_logger_last)


def coarse_by_ends(t_gps_last: float, t_logger_last: float, end_gap_s: float) -> CoarseAlignment:
    """Coarse alignment by the stream ends, trusted within the declared gap `end_gap_s` (s) between the recorders'
    last packets."""
    return CoarseAlignment("stream ends", float(t_logger_last), float(t_gps_last), end_gap_s / np.sqrt(3.0),
                           float(end_gap_s), {"end_gap_s": float(end_gap_s)})


def coarse_by_time_tags(t_logger: np.ndarray, gps_time: np.ndarray, latency_s: float = 0.05) -> CoarseAlignment:
    """Coarse alignment from GNSS times (continuous GPS s) the logger recorded in its own packets: where the value
    changes a new message arrived, `latency_s` (s) after its epoch on average."""
    t_logger, g = np.asarray(t_logger, float), np.asarray(gps_time, float)
    ok = np.isfinite(g)
    new = np.r_[False, np.diff(g[ok]) != 0] if ok.sum() > 1 else np.zeros(ok.sum(), bool)
    tl, gg = t_logger[ok][new], g[ok][new]
    if len(tl) < 3:
        raise InputError(f"only {len(tl)} GNSS time updates in the logger's time column", field="gps_time")
    off = gg + latency_s - tl
    med = float(np.median(off))
    mad = 1.4826 * float(np.median(np.abs(off - med)))
    t_ref = float(np.median(tl))
    sig = max(latency_s, mad)
    return CoarseAlignment("logger GNSS time", t_ref, t_ref + med, sig, 4 * sig, {"n_updates": int(len(tl))})


def _band_pass(y: np.ndarray, h: float, short_s: float = 0.3, long_s: float = 20.0) -> np.ndarray:
    """Moving average over `short_s` minus moving average over `long_s` (s) of a signal sampled every h s."""
    def mavg(x, n):
        n = max(1, int(round(n)))
        c = np.cumsum(np.r_[0.0, x])
        k = np.arange(len(x))
        lo, hi = np.clip(k - n // 2, 0, len(x)), np.clip(k + n // 2 + 1, 0, len(x))
        return (c[hi] - c[lo]) / (hi - lo)
    return mavg(y, short_s / h) - mavg(y, long_s / h)


def _xcorr_normalised(a: np.ndarray, b: np.ndarray, min_overlap: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised cross-correlation r(l) = sum a[i] b[i+l] / sqrt(sum a^2 sum b^2) over each overlap, for every
    lag l with at least `min_overlap` samples; (lags, r)."""
    na, nb = len(a), len(b)
    n = 1 << int(np.ceil(np.log2(na + nb)))
    c = np.fft.irfft(np.conj(np.fft.rfft(a, n)) * np.fft.rfft(b, n), n)
    lags = np.arange(-(na - 1), nb)
    c = np.r_[c[n - (na - 1):], c[:nb]] if na > 1 else c[:nb]
    ca, cb = np.cumsum(np.r_[0.0, a * a]), np.cumsum(np.r_[0.0, b * b])
    i0 = np.maximum(0, -lags)
    i1 = np.minimum(na, nb - lags)
    ov = i1 - i0
    ea = ca[np.clip(i1, 0, na)] - ca[np.clip(i0, 0, na)]
    eb = cb[np.clip(i1 + lags, 0, nb)] - cb[np.clip(i0 + lags, 0, nb)]
    with np.errstate(invalid="ignore", divide="ignore"):
        r = c / np.sqrt(ea * eb)
    r[(ov < min_overlap) | ~np.isfinite(r)] = -np.inf
    return lags, r


def coarse_by_correlation(t_gnss: np.ndarray, h_gnss: np.ndarray, t_logger: np.ndarray, y_logger: np.ndarray,
                          clock: ClockFit | None = None, name: str = "laser", step_s: float = 0.1,
                          search_s: float | None = None, centre_offset_s: float | None = None) -> CoarseAlignment:
    """Coarse alignment by cross-correlating a logger height signal (`name`: laser range or barometric height, m)
    with the GNSS height (m, GPS s): both band-passed (1-20 s) so the ground's height and a barometer's drift
    drop out; the logger times go through `clock` (the PPS drift and sub-second phase) when given.

    `search_s` limits the search to offsets within that many seconds of `centre_offset_s` (GPS minus logger
    time); default: every offset with at least 20 s (or 30 % of the shorter record) of overlap. The figures
    give the correlation at the peak, the best correlation at least 2 s away (ambiguity) and the refined
    offset's sigma (residual scatter inflated by its correlation length).
    """
    tg, hg = np.asarray(t_gnss, float), np.asarray(h_gnss, float)
    tl, yl = np.asarray(t_logger, float), np.asarray(y_logger, float)
    okg, okl = np.isfinite(hg), np.isfinite(yl)
    tg, hg, tl, yl = tg[okg], hg[okg], tl[okl], yl[okl]
    # a sensor updated slower than the logger samples is held: its readings belong to the first sample of each run
    new = np.r_[True, np.diff(yl) != 0]
    if new.mean() < 0.7:
        tl, yl = tl[new], yl[new]
    if len(tg) < 10 or len(tl) < 10:
        raise InputError(f"too few samples to correlate {name} with the GNSS height", field=name)
    tau = clock.to_gps(tl) if clock is not None else tl.copy()
    base = float(tau[0])
    tau = tau - base  # logger signal on its own (GPS-rate) axis, GPS = base + tau + lag
    g0 = float(tg[0])
    gg = np.arange(0.0, tg[-1] - g0, step_s)
    lg = np.arange(0.0, tau[-1], step_s)
    A = _band_pass(np.interp(gg, tg - g0, hg), step_s)
    B = _band_pass(np.interp(lg, tau, yl), step_s)
    shorter = min(len(A), len(B))
    min_ov = int(min(max(20.0 / step_s, 0.3 * shorter), shorter))
    lags, r = _xcorr_normalised(B, A, min_ov)  # r[l]: B[i] against A[i + l]
    # lag l (samples): logger sample i at tau = i*step matches GNSS at g0 + (i + l) step => GPS = base + tau + lag_s
    lag_s = g0 - base + lags * step_s
    if search_s is not None and centre_offset_s is not None:
        # offset GPS - t_logger at the record's start: base + lag_s - tl[0] ~ centre
        far = np.abs(base + lag_s - tl[0] - (centre_offset_s)) > search_s
        r = np.where(far, -np.inf, r)
    if not np.isfinite(r).any():
        raise InputError(f"the {name} and GNSS records do not overlap by 20 s at any offset", field=name)
    k = int(np.argmax(r))
    peak = float(r[k])
    # ambiguity: the best other local maximum (the main peak's own flanks do not count)
    loc = np.r_[False, (r[1:-1] > r[:-2]) & (r[1:-1] >= r[2:]), False] & np.isfinite(r)
    loc[k] = False
    second = float(np.max(r[loc])) if loc.any() else -np.inf
    # refine: least squares on the continuous lag with a scale and a level, around the peak
    delta, sig, scale = _refine_lag(lg, B, gg, A, float(lags[k] * step_s), step_s)
    lag_ref = g0 - base + delta
    t_ref = float(tl[len(tl) // 2])
    tau_ref = (clock.to_gps(t_ref) if clock is not None else t_ref) - base
    gps_ref = base + float(tau_ref) + lag_ref
    figs = {"signal": name, "peak_correlation": round(peak, 4),
            "second_peak_correlation": round(second, 4) if np.isfinite(second) else None,
            "ambiguity_ratio": round(second / peak, 4) if np.isfinite(second) and peak > 0 else None,
            "scale": round(scale, 4), "lag_sigma_s": sig, "grid_s": step_s,
            "overlap_min_s": min_ov * step_s}
    return CoarseAlignment(f"{name} vs GNSS height", t_ref, gps_ref, sig, 4 * sig, figs)


def _refine_lag(tb: np.ndarray, B: np.ndarray, ta: np.ndarray, A: np.ndarray, lag0: float, h: float,
                n_iter: int = 6) -> tuple[float, float, float]:
    """Continuous lag (s) between signal B(t) and A(t + lag) near `lag0`, with its sigma (s) and the scale of A."""
    lag = lag0
    s = 1.0
    for _ in range(n_iter):
        x = tb + lag
        m = (x >= ta[0]) & (x <= ta[-1])
        a = np.interp(x[m], ta, A)
        da = np.interp(x[m], ta, np.gradient(A, h))
        M = np.column_stack([a, np.ones(m.sum())])
        coef = np.linalg.lstsq(M, B[m], rcond=None)[0]
        s = float(coef[0])
        res = B[m] - M @ coef
        J = s * da
        den = float(J @ J)
        if den <= 0:
            break
        step = float(J @ res) / den
        lag += np.clip(step, -h, h)
        if abs(step) < 1e-5:
            break
    # sigma: a Newey-West (Bartlett-weighted) sandwich, since the residuals (terrain under a laser, baro noise)
    # and the signal's derivative are both correlated over seconds
    u = J * (res - res.mean())
    L = int(min(len(u) // 4, max(10, round(30.0 / h))))
    c = np.correlate(u, u, "full")[len(u) - 1:len(u) + L] if len(u) <= 20000 else np.array(
        [u[:len(u) - k] @ u[k:] for k in range(L + 1)])
    w = 1.0 - np.arange(L + 1) / (L + 1)
    var = (c[0] + 2 * np.sum(w[1:] * c[1:])) / den ** 2 if den > 0 else np.inf
    # ... which needs many correlation lengths of record: never below the residual variance inflated by the
    # residuals' own correlation length (the conservative figure that dominates for short records)
    rr = res - res.mean()
    m = min(len(rr), 4000)
    ac = np.correlate(rr[:m], rr[:m], "full")[m - 1:]
    ac = ac / ac[0] if ac[0] > 0 else ac
    below = np.nonzero(ac < np.exp(-1))[0]
    n_corr = max(1.0, float(below[0]) if len(below) else float(len(ac)))
    var_w = float(rr @ rr) / max(len(rr) - 3, 1) / den * 2 * n_corr if den > 0 else np.inf
    sig = float(np.sqrt(max(var, var_w)))
    return float(lag), sig, s


def synthetic_pps(t_gps: np.ndarray) -> np.ndarray:
    """The PPS level (1 high, 0 low) at GPS times: high during the first half of each second."""
    return (np.mod(np.asarray(t_gps, float), 1.0) < 0.5).astype(float)


def pps_phase_by_correlation(t_logger: np.ndarray, pps: np.ndarray, offset_s: float, step_s: float = 1e-3) -> float:
    """Sub-second shift (s, in [-0.5, 0.5)) to add to `offset_s` that best aligns the recorded PPS with the synthetic
    one (the seed's fine alignment; `fit_pps_clock` supersedes it)."""
    level = (pps > 0.5 * (np.nanmax(pps) + np.nanmin(pps))).astype(float) * 2 - 1
    shifts = np.arange(-0.5, 0.5, step_s)
    t = np.asarray(t_logger, float) + offset_s
    phase = np.mod(t[None, :] + shifts[:, None], 1.0)
    score = (np.where(phase < 0.5, 1.0, -1.0) * level[None, :]).sum(axis=1)
    return float(shifts[int(np.argmax(score))])


def rising_edges(t: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Times of rising edges of a two-level signal: the midpoint between the last low and first high sample."""
    x = np.asarray(level, float)
    hi = x > 0.5 * (np.nanmax(x) + np.nanmin(x))
    k = np.nonzero(~hi[:-1] & hi[1:])[0]
    return 0.5 * (t[k] + t[k + 1])


def fit_pps_clock(t_logger: np.ndarray, pps: np.ndarray, valid: np.ndarray | None = None,
                  inverted: bool = False, dt_s: float | None = None, max_drift: float | None = 200e-6) -> ClockFit:
    """Drift and sub-second phase of the logger clock from its recorded PPS alone (the whole second unresolved:
    `whole_second` False, GPS = offset_s + (1 + drift) t modulo 1 s).

    Edges are labelled with the whole seconds between them (an edge that fits no second is spurious), then
    the clock best supported by the set consistent with every edge interval is taken (linear programmes, drift
    within +-`max_drift`; see `_chebyshev_clock`); when no clock is consistent, least squares on the midpoints
    with outlying edges dropped (`consistent` False; a drift beyond `max_drift` then shows as such). Counts the
    edges expected from the fitted clock and the recorded samples.
    """
    t_all = np.asarray(t_logger, float)
    x_all = np.asarray(pps, float)
    rec = np.ones(len(t_all), bool) if valid is None else np.asarray(valid, bool)
    t, x = t_all[rec], x_all[rec]
    if inverted:
        x = -x
    dt_nom = float(dt_s) if dt_s else float(np.median(np.diff(t)))
    if len(x) < 3 or not np.isfinite(x).all() or np.nanmax(x) - np.nanmin(x) <= 0:
        raise InputError("the PPS channel is flat or empty", field="pps")
    hi_mask = x > 0.5 * (np.nanmax(x) + np.nanmin(x))
    k = np.nonzero(~hi_mask[:-1] & hi_mask[1:])[0]
    k = k[(t[k + 1] - t[k]) < 1.5 * dt_nom]  # the two samples around the edge must be consecutive
    lo, hi = t[k], t[k + 1]
    if len(lo) < 3:
        raise InputError(f"only {len(lo)} PPS rising edges recorded; need 3 or more", field="pps")
    mid = 0.5 * (lo + hi)
    label = np.zeros(len(mid), np.int64)
    keep = np.ones(len(mid), bool)
    prev = 0
    for i in range(1, len(mid)):  # whole seconds between edges; an edge off the 1 s rhythm is spurious
        d = mid[i] - mid[prev]
        n = int(round(d))
        if n < 1 or abs(d - n) > max(5 * dt_nom, 0.1):
            keep[i] = False
            continue
        label[i] = label[prev] + n
        prev = i
    n_spurious = int((~keep).sum())
    lo, hi, mid, label = lo[keep], hi[keep], mid[keep], label[keep].astype(float)
    base = float(np.median(label - mid))
    fit = _chebyshev_clock(lo, hi, label, base, max_drift)
    consistent = fit is not None
    if fit is None:  # inconsistent edges (jitter, glitches): least squares, outliers (> one sample) dropped
        use = np.ones(len(mid), bool)
        for _ in range(5):
            fit = _least_squares_clock(mid[use], label[use], dt_nom)
            res = label - fit.to_gps(mid)
            bad = use & (np.abs(res) > max(1.0 * dt_nom, 4 * fit.residual_rms_s))
            if not bad.any():
                break
            use &= ~bad
        n_spurious += int((~use).sum())
        again = _chebyshev_clock(lo[use], hi[use], label[use], base, max_drift)
        if again is not None:
            fit, consistent = again, True
            lo, hi, mid, label = lo[use], hi[use], mid[use], label[use]
    res = label - fit.to_gps(mid)
    # expected edges: every whole second of the fitted clock inside the record whose bracketing samples exist
    g0, g1 = fit.to_gps(t_all[rec][0]), fit.to_gps(t_all[rec][-1])
    secs = np.arange(np.ceil(g0), np.floor(g1) + 1)
    if inverted:
        secs = secs + 0.5
        secs = secs[secs <= g1]
    t_edge = (secs - fit.offset_s) / (1.0 + fit.drift)
    i = np.searchsorted(t_all, t_edge)
    inside = (i > 0) & (i < len(t_all))
    i = i[inside]
    both = rec[i - 1] & rec[i] & ((t_all[i] - t_all[i - 1]) < 1.5 * dt_nom)
    return replace(fit, n_expected=int(both.sum()), n_spurious=n_spurious,
                   residual_max_s=float(np.max(np.abs(res))), residual_rms_s=float(np.sqrt(np.mean(res ** 2))),
                   dt_s=dt_nom, consistent=consistent, whole_second=False, n_edges=int(len(mid)))


LATENCY_ALLOWANCE_S = 0.05  # sensor update and hold delays the coarse signals may carry (a 10 Hz laser held: 0.04 s)


def resolve_whole_seconds(clock: ClockFit, coarse: CoarseAlignment) -> tuple[ClockFit, dict]:
    """The PPS clock (known modulo 1 s) with its whole second taken from a coarse alignment; returns the clock and
    the figures of the two checks: 'resolvable' (the coarse bound below 0.45 s: one whole second within reach)
    and 'contradicted' (coarse minus PPS time after the whole second, `residual_s`, beyond the coarse bound plus
    a latency allowance: the PPS fit contradicts the coarse alignment).

    For a correlation the bound is 4 sigma and the contradiction threshold 3 sigma + 0.05 s, so a wrong whole
    second would need a coarse error of about six sigmas to pass both checks."""
    pps_at_ref = float(clock.to_gps(coarse.t_ref))
    n = float(np.round(coarse.gps_at_ref - pps_at_ref))
    resid = float(coarse.gps_at_ref - pps_at_ref - n)
    if coarse.method == "stream ends":
        bound, tol = coarse.bound_s, coarse.bound_s + 0.02
    else:
        bound, tol = 4 * coarse.sigma_s, 3 * coarse.sigma_s + LATENCY_ALLOWANCE_S
    figs = {"method": coarse.method, "bound_s": float(bound), "sigma_s": float(coarse.sigma_s),
            "residual_s": resid, "residual_limit_s": float(tol), "resolvable": bool(bound < 0.45),
            "contradicted": bool(abs(resid) > tol), "whole_seconds_added": n, **coarse.figures}
    return replace(clock, offset_s=clock.offset_s + n, whole_second=True), figs


def fit_clock_to_pps(t_logger: np.ndarray, pps: np.ndarray, t_gps_last: float, t_logger_last: float,
                     valid: np.ndarray | None = None) -> ClockFit:
    """Fit GPS time = offset + (1 + drift) t_logger from the recorded PPS, the whole second by the stream ends
    (the seed's procedure: valid only when the recorders stopped within half a second of each other).

    `valid` masks samples that were really recorded (lost packets filled by copies carry no PPS information).
    """
    clock = fit_pps_clock(t_logger, pps, valid)
    out, _ = resolve_whole_seconds(clock, coarse_by_ends(t_gps_last, t_logger_last, 0.5))
    return out


def _chebyshev_clock(lo: np.ndarray, hi: np.ndarray, target: np.ndarray, base: float,
                     max_drift: float | None = None) -> ClockFit | None:
    """The clock best supported by the set of clocks consistent with every edge (linear programmes); None when
    no clock (within +-`max_drift`, the crystal's plausible range, when given) is consistent.

    The sampling phase walks through the PPS as the crystal drifts, so the edge intervals act like a vernier:
    together they pin the clock far below one sample once the phase has swept about two samples (with one
    sweep the consistent set is a thin sliver pivoting about the wrap). Quantisation errors are not random
    here (they sweep linearly with time), which is why plain least squares on edge midpoints would bias the
    drift. The error of a linear clock is largest at the record's ends, so the estimate is the line through
    the middles of the consistent clock values at the two ends, and the bound is the larger half-range: no
    consistent clock is farther from the estimate anywhere in the record.
    """
    tm = 0.5 * (lo[0] + hi[-1])
    T = max(1.0, float(hi[-1] - lo[0]))
    a, b = (lo - tm) / T, (hi - tm) / T
    # unknowns: o, D = drift * T; GPS(t) = t + base + o + D (t - tm) / T, with `base` the approximate offset
    # taken out so the programmes see small numbers (GPS seconds are ~1e9)
    A = np.vstack([np.column_stack([np.ones_like(a), a]), np.column_stack([-np.ones_like(b), -b])])
    rhs = np.r_[(target - base) - lo, hi - (target - base)]
    dlim = (None, None) if max_drift is None else (-max_drift * T, max_drift * T)
    bounds = [(None, None), dlim]

    def extreme(c, sgn):
        e = linprog(sgn * np.asarray(c, float), A_ub=A, b_ub=rhs, bounds=bounds, method="highs")
        return None if e.status != 0 else sgn * e.fun

    a0, a1 = float(a[0]), float(b[-1])
    vals = [extreme(c, sgn) for c in ([1.0, a0], [1.0, a1], [0.0, 1.0]) for sgn in (1, -1)]
    if any(v is None for v in vals):
        return None
    s_lo, s_hi, e_lo, e_hi, d_lo, d_hi = vals
    cs, ce = 0.5 * (s_lo + s_hi), 0.5 * (e_lo + e_hi)
    D = (ce - cs) / (a1 - a0)
    o = cs - D * a0
    bound = max(0.5 * (s_hi - s_lo), 0.5 * (e_hi - e_lo), 0.0)
    drift = D / T
    offset = base + o - drift * tm
    mid = 0.5 * (lo + hi)
    resid = target - (offset + (1 + drift) * mid)
    # the bound as a one-sigma figure of a uniform spread for the sigmas
    return ClockFit(float(offset), float(drift), float(bound / np.sqrt(3)), float(0.5 * (d_hi - d_lo) / np.sqrt(3) / T),
                    float(np.sqrt(np.mean(resid**2))), int(len(lo)), float(bound),
                    drift_range=(float(d_lo / T), float(d_hi / T)))


def _least_squares_clock(edges: np.ndarray, target: np.ndarray, dt_nom: float) -> ClockFit:
    A = np.column_stack([np.ones_like(edges), edges - edges.mean()])
    coef, *_ = np.linalg.lstsq(A, target - edges, rcond=None)
    res = target - edges - A @ coef
    s2 = max(res.var(ddof=2) if len(res) > 2 else dt_nom**2 / 12, dt_nom ** 2 / 12)
    cov = s2 * np.linalg.inv(A.T @ A)
    off = coef[0] - coef[1] * edges.mean()
    return ClockFit(float(off), float(coef[1]), float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1])),
                    float(np.sqrt(np.mean(res**2))), int(len(edges)), float(3 * np.sqrt(cov[0, 0]) + dt_nom / 2),
                    consistent=False)
