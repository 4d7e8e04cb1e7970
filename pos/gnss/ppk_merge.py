"""Forward + backward PPK passes merged per epoch by fix status and covariance (`dgcal.pos.gnss.ppk`).

The two passes of `ppk` use the same measurements in opposite time order: their fixes at an epoch share that
epoch's errors (with the same integers they differ by millimetres), their floats are nearly independent estimates.
`float_variance_factors` measures on the epochs both passes fix how far each pass's float covariance understates
its error; `combine` merges the passes with those calibrated covariances. Positions ECEF m, covariances m^2.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from dgcal.pos.gnss.chi2_points import chi2_limit

if TYPE_CHECKING:
    from dgcal.pos.gnss.ppk import PassResult


def _chi2_3(d: np.ndarray, S: np.ndarray) -> float:
    try:
        return float(d @ np.linalg.solve(S, d))
    except np.linalg.LinAlgError:
        return np.inf


def float_variance_factors(fw: PassResult, bw: PassResult, alpha: float = 1e-3) -> tuple[float, float]:
    """How much each pass's float covariance understates its float error (>= 1): the mean of
    ``e' P_float^-1 e / 3`` over the epochs where both passes hold agreeing fixes (e: the float against the fixed
    position, which is ten times better); without such epochs the two floats' disagreement against their summed
    covariance, for both. A float filter that takes slow code and phase errors as white is overconfident, and the
    fixed epochs of the same data show by how much."""
    both = (fw.status == 3) & (bw.status == 3)
    lim = float(chi2_limit(3, alpha))
    agree = np.array([both[k] and _chi2_3(fw.p[k] - bw.p[k], 0.25 * (fw.P[k] + bw.P[k])) <= lim
                      for k in range(len(both))], dtype=bool)
    out = []
    for r in (fw, bw):
        k = np.flatnonzero(agree & np.all(np.isfinite(r.p_float), axis=1))
        if len(k) >= 5:
            ref = 0.5 * (fw.p[k] + bw.p[k])
            z = [_chi2_3(r.p_float[q] - ref[j], r.P_float[q]) / 3.0 for j, q in enumerate(k)]
            out.append(float(np.clip(np.mean(z), 1.0, 1e6)))
        else:
            out.append(np.nan)
    if np.isnan(out).any():
        k = np.flatnonzero((fw.status >= 2) & (bw.status >= 2))
        z = [_chi2_3(fw.p_float[q] - bw.p_float[q], fw.P_float[q] + bw.P_float[q]) / 3.0 for q in k]
        common = float(np.clip(np.mean(z), 1.0, 1e6)) if len(z) else 1.0
        out = [common if np.isnan(v) else v for v in out]
    return out[0], out[1]


def combine(fw: PassResult, bw: PassResult, alpha: float = 1e-3):
    """Forward + backward per epoch, by fix status and covariance. Float covariances are first scaled by
    `float_variance_factors`. Two agreeing fixes (chi-square, 3 dof, against a quarter of their summed covariance:
    with the same integers they differ by millimetres) are averaged without shrinking the covariance (they share the
    epoch's measurements); a fix beside the other pass's float is kept if the float agrees with it;
    two disagreeing fixes, or a fix the other float contradicts, give float. Floats are combined by their
    covariances, the covariance doubled (but not above the better pass's) for the same reason. Returns (status, p,
    P, ratio, n_sat, n_fixed_amb, (forward factor, backward factor))."""
    N = len(fw.status)
    lim = float(chi2_limit(3, alpha))
    factors = float_variance_factors(fw, bw, alpha)
    Pfw, Pbw = fw.P_float * factors[0], bw.P_float * factors[1]
    status = np.zeros(N, dtype=int)
    p = np.full((N, 3), np.nan)
    P = np.full((N, 3, 3), np.nan)
    ratio = np.full(N, np.nan)
    n_sat = np.maximum(fw.n_sat, bw.n_sat)
    n_fix = np.zeros(N, dtype=int)
    for k in range(N):
        a, b = fw.status[k], bw.status[k]
        if a < 2 and b < 2:
            continue
        if a < 2 or b < 2:
            r, Pr = (fw, Pfw) if a >= 2 else (bw, Pbw)
            status[k], p[k], ratio[k], n_fix[k] = r.status[k], r.p[k], r.ratio[k], r.n_fixed_amb[k]
            P[k] = r.P[k] if r.status[k] == 3 else Pr[k]
            continue
        if a == 3 and b == 3:
            # the two fixes share the epoch's measurements and errors: with the same integers they differ by
            # millimetres, whatever their (common) covariance; half its sigma tells different integers apart
            d = fw.p[k] - bw.p[k]
            if _chi2_3(d, 0.25 * (fw.P[k] + bw.P[k])) <= lim:
                status[k] = 3
                Wf, Wb = np.linalg.inv(fw.P[k]), np.linalg.inv(bw.P[k])
                p[k] = np.linalg.solve(Wf + Wb, Wf @ fw.p[k] + Wb @ bw.p[k])
                P[k] = 0.5 * (fw.P[k] + bw.P[k])
                ratio[k] = max(fw.ratio[k], bw.ratio[k])
                n_fix[k] = max(fw.n_fixed_amb[k], bw.n_fixed_amb[k])
                continue
        elif a == 3 or b == 3:
            fx, fl, Pfl = (fw, bw, Pbw) if a == 3 else (bw, fw, Pfw)
            d = fx.p[k] - fl.p_float[k]
            if _chi2_3(d, fx.P[k] + Pfl[k]) <= lim:
                status[k], p[k], P[k], ratio[k], n_fix[k] = 3, fx.p[k], fx.P[k], fx.ratio[k], fx.n_fixed_amb[k]
                continue
        # float combination
        Wf, Wb = np.linalg.inv(Pfw[k]), np.linalg.inv(Pbw[k])
        Pc = np.linalg.inv(Wf + Wb)
        status[k] = 2
        p[k] = Pc @ (Wf @ fw.p_float[k] + Wb @ bw.p_float[k])
        best = Pfw[k] if np.trace(Pfw[k]) < np.trace(Pbw[k]) else Pbw[k]
        P[k] = 2.0 * Pc if np.trace(2.0 * Pc) < np.trace(best) else best
        # two floats that disagree beyond their covariances: the covariance grows to hold the disagreement
        d = fw.p_float[k] - bw.p_float[k]
        c = _chi2_3(d, Pfw[k] + Pbw[k])
        if c > lim:
            P[k] = P[k] * (c / 3.0)
        ratio[k] = np.nanmax([fw.ratio[k], bw.ratio[k], 0.0])
    return status, p, P, ratio, n_sat, n_fix, factors
