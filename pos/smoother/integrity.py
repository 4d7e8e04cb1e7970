"""GNSS epoch screening and the IMU bridges' noise in the smoother.

Two tests keep a bad GNSS epoch out of the smoothed trajectory:

1. `screen_fixes`, before the graph is built (the fixes also give the initial track, which a 1000 km epoch
   would wreck): each fix is predicted from its neighbours (linear interpolation between the previous and the
   next fix, extrapolation from the two before and from the two after). Between two fixes the antenna cannot
   accelerate by more than the largest specific force the IMU measured plus gravity, |a| <= max|f| + g, so a
   linear prediction is off by at most |a| |(t - t1)(t - t2)| / 2; a fix that no prediction reaches within that
   bound plus `k_sigma` times the combined sigma is impossible and rejected (the test repeats until nothing
   changes, so runs of bad epochs are peeled off). A fix's velocity is tested likewise against the secant of
   the neighbouring positions and set to NaN when it fails.
2. `reject_outliers`, after the first (Huber-weighted) solution: the post-fit residual of every position,
   velocity, pseudorange and Doppler factor, whitened by its own noise model, against the chi-square point of
   its dimension at the two-sided probability of `k_sigma` sigmas, scaled by the robust (median) spread of
   that kind's residuals when it exceeds one (sigmas that are too small for the data reject nothing they
   would not also reject at the right scale). Rejected factors leave the graph before the second pass.

`with_bridges` adds the white noise of the IMU's bridged spans (`dgcal.pos.ins.integrity`) to the
preintegration parameters of the keyframe intervals they overlap, so the smoother's covariances grow there.
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from scipy.special import chdtri, ndtr   # not scipy.stats: its import alone takes 0.5-0.8 s

from dgcal.fields.errors import ResultError
from dgcal.pos.ins.integrity import bridge_densities
from dgcal.pos.smoother.initial import GnssFixes
from dgcal.pos.smoother.preintegration import preintegration_params

G_MAX = 9.84                 # largest normal gravity on the Earth (poles), m/s^2, plus a margin
A_NO_IMU = 50.0              # acceleration bound (m/s^2) between fixes the IMU does not cover


def fix_sigma_3d(fixes: GnssFixes) -> np.ndarray:
    """3D position sigma (m) of each fix (root of the covariance trace)."""
    if fixes.cov_ned is not None:
        return np.sqrt(np.clip(np.einsum("nii->n", fixes.cov_ned), 0.0, None))
    return np.linalg.norm(fixes.sigma_ned, axis=1)


def accel_bound(imu, t: np.ndarray) -> np.ndarray:
    """|a| bound (m/s^2) over each interval (t[j], t[j+1]] of sorted times t: the largest |f| of the IMU samples
    in it (and of the sample straddling its end) plus G_MAX; A_NO_IMU where the IMU does not cover it."""
    A = np.full(max(len(t) - 1, 0), A_NO_IMU)
    if imu is None or len(imu) < 2 or len(t) < 2:
        return A
    f = np.linalg.norm(imu.accel_m_s2, axis=1)
    n = len(f)
    i0 = np.searchsorted(imu.t, t[:-1], side="left")
    i1 = np.searchsorted(imu.t, t[1:], side="right")
    inside = (i0 < n) & (t[:-1] >= imu.t[0] - imu.dt[0]) & (t[1:] <= imu.t[-1] + 1e-6)
    if inside.any():
        starts = np.minimum(i0, n - 1)
        starts = np.maximum.accumulate(starts)
        cm = np.maximum.reduceat(f, starts)          # max of f[starts[j]:starts[j+1]] (the last: to the end)
        cm = np.maximum(cm, f[np.minimum(i1, n - 1)])
        A[inside] = cm[inside] + G_MAX
    return A


def _span_max(A: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """max(A[lo:hi]) for each pair (hi > lo), via a sparse table (vectorised)."""
    n = len(A)
    table = [A]
    w = 1
    while 2 * w <= n:
        prev = table[-1]
        table.append(np.maximum(prev[:-w], prev[w:]))
        w *= 2
    length = np.maximum(hi - lo, 1)
    j = np.floor(np.log2(length)).astype(int)
    out = np.empty(len(lo))
    for lev in np.unique(j):
        m = j == lev
        tab = table[lev]
        out[m] = np.maximum(tab[lo[m]], tab[hi[m] - (1 << lev)])
    return out


def _position_test(t, P, S, A, k_sigma):
    """Which of the fixes (t, P (M,3), sigma S) fail every neighbour prediction; A[m] bounds |a| on
    (t[m], t[m+1]]. Returns the mask of failures and, per fix, the smallest miss beyond the bound (m)."""
    M = len(t)
    fail = np.zeros(M, bool)
    excess = np.full(M, np.inf)
    if M < 3:
        return fail, np.zeros(M)
    m = np.arange(M)
    tested = np.zeros(M, bool)
    for d1, d2 in ((-1, 1), (-2, -1), (1, 2)):
        ok = (m + d1 >= 0) & (m + d2 < M) & (m + d1 < M) & (m + d2 >= 0)
        j = m[ok]
        a, b = j + d1, j + d2
        t1, t2, tj = t[a], t[b], t[j]
        w2 = (tj - t1) / (t2 - t1)
        w1 = 1.0 - w2
        pred = w1[:, None] * P[a] + w2[:, None] * P[b]
        lo = np.minimum(np.minimum(a, b), j)
        hi = np.maximum(np.maximum(a, b), j)
        amax = _span_max(A, lo, hi) if len(A) else np.full(len(j), A_NO_IMU)
        kin = 0.5 * amax * np.abs((tj - t1) * (tj - t2))
        noise = np.sqrt(S[j] ** 2 + (w1 * S[a]) ** 2 + (w2 * S[b]) ** 2)
        miss = np.linalg.norm(P[j] - pred, axis=1) - (kin + k_sigma * noise)
        excess[j] = np.minimum(excess[j], miss)
        tested[j] = True
    fail = tested & (excess > 0)
    return fail, np.where(tested, excess, 0.0)


def screen_fixes(fixes: GnssFixes, imu, k_sigma: float = 5.0, max_rounds: int = 50):
    """The fixes without those the IMU's acceleration bound makes impossible (see the module docstring), and
    the rejections: dicts with kind ('position' or 'velocity'), t_gps and a one-line detail. More than half of
    the fixes impossible is a ResultError (the IMU and the GNSS disagree about time or units, not the epochs)."""
    t = np.asarray(fixes.t, float)
    finite = np.all(np.isfinite(fixes.p_ecef), axis=1)
    idx = np.flatnonzero(finite)
    S = fix_sigma_3d(fixes)
    S = np.where(np.isfinite(S), S, 10.0)
    rejected = np.zeros(len(t), bool)
    why = {}
    for _ in range(max_rounds):
        if len(idx) < 3:
            break
        A = accel_bound(imu, t[idx])
        fail, excess = _position_test(t[idx], fixes.p_ecef[idx], S[idx], A, k_sigma)
        if not fail.any():
            break
        for j in idx[fail]:
            why[int(j)] = float(excess[np.searchsorted(idx, j)])
        rejected[idx[fail]] = True
        idx = idx[~fail]
    if finite.sum() >= 10 and rejected.sum() > 0.5 * finite.sum():
        raise ResultError(f"GNSS: {int(rejected.sum())} of {int(finite.sum())} fixes are farther from their "
                          "neighbours than the IMU's accelerations allow: wrong IMU or GNSS time, units or file?")
    out = []
    for j in np.flatnonzero(rejected):
        out.append({"kind": "position", "t_gps": float(t[j]),
                    "detail": f"fix {why[int(j)]:.1f} m beyond what the IMU allows from its neighbours: rejected"})
    keep = ~rejected
    v = None if fixes.v_ecef is None else fixes.v_ecef.copy()
    sv = None if fixes.sigma_v_ned is None else fixes.sigma_v_ned.copy()
    if v is not None and sv is not None and len(idx) >= 3:
        bad_v = _velocity_test(t, fixes.p_ecef, S, v, sv, idx, imu, k_sigma)
        for j in np.flatnonzero(bad_v & keep):
            out.append({"kind": "velocity", "t_gps": float(t[j]),
                        "detail": "velocity inconsistent with the neighbouring positions: not used"})
        v[bad_v] = np.nan
        sv[bad_v] = np.nan
    sub = GnssFixes(t[keep], fixes.p_ecef[keep], fixes.sigma_ned[keep], None if v is None else v[keep],
                    None if sv is None else sv[keep], None if fixes.cov_ned is None else fixes.cov_ned[keep],
                    fixes.velocity_on_time)
    out.sort(key=lambda r: r["t_gps"])
    return sub, out


def _velocity_test(t, p, S, v, sv, idx, imu, k_sigma) -> np.ndarray:
    """Fixes (indices into t) whose velocity misses the secant of the neighbouring good positions by more
    than the acceleration bound times the larger neighbour interval plus `k_sigma` combined sigmas."""
    bad = np.zeros(len(t), bool)
    ok_v = np.all(np.isfinite(v[idx]), axis=1) & np.all(np.isfinite(sv[idx]), axis=1)
    M = len(idx)
    m = np.arange(M)
    a = np.clip(m - 1, 0, M - 1)
    b = np.clip(m + 1, 0, M - 1)
    a[0], b[-1] = 0, M - 1
    T = t[idx[b]] - t[idx[a]]
    good = ok_v & (T > 0)
    if not good.any():
        return bad
    sec = (p[idx[b]] - p[idx[a]]) / np.where(T > 0, T, 1.0)[:, None]
    A = accel_bound(imu, t[idx])
    amax = _span_max(A, a, np.maximum(b, a + 1)) if len(A) else np.full(M, A_NO_IMU)
    reach = amax * np.maximum(t[idx[b]] - t[idx[m]], t[idx[m]] - t[idx[a]])
    noise = np.sqrt(np.sum(sv[idx] ** 2, axis=1) + (S[idx[a]] ** 2 + S[idx[b]] ** 2) / np.where(T > 0, T, 1.0) ** 2)
    miss = np.linalg.norm(v[idx] - sec, axis=1) > reach + k_sigma * noise
    bad[idx[good & miss]] = True
    return bad


def assemble_graph(problem) -> gtsam.NonlinearFactorGraph:
    """The factor graph of a problem from its parts (priors, IMU, clock, per-keyframe GNSS factors)."""
    graph = gtsam.NonlinearFactorGraph()
    for f in problem.prior_factors + problem.imu_factors:
        graph.add(f)
    for g in problem.clock_factor_groups + problem.bias_factor_groups:
        for f in g:
            graph.add(f)
    for fl in problem.epoch_factors:
        for _, f, _ in fl:
            graph.add(f)
    return graph


def factor_kinds(problem) -> list:
    """The kind of every factor of `assemble_graph(problem)`, in its order: None for priors and processes, else
    (kind, keyframe) of a keyframe's measurement (GNSS factors, zero-motion information)."""
    n_process = (len(problem.prior_factors) + len(problem.imu_factors)
                 + sum(len(g) for g in problem.clock_factor_groups + problem.bias_factor_groups))
    out: list = [None] * n_process
    for k, fl in enumerate(problem.epoch_factors):
        out.extend((kind, k) for kind, _, _ in fl)
    return out


@dataclass
class FactorTable:
    """Every factor of `assemble_graph(problem)` in order: its kind (None: prior or process) and keyframe, its first
    row in the linearised graph (`start`, one more entry: the row count), the sigma of its measurement where the
    problem recorded it (pseudorange, Doppler; NaN elsewhere) and its Huber threshold (NaN: not robust)."""

    kinds: list
    start: np.ndarray
    sigma: np.ndarray
    huber: np.ndarray


_ROBUST_KINDS = ("pr", "dop", "pos")   # the factors built with the problem's Huber threshold


def factor_table(problem) -> FactorTable:
    """The `FactorTable` of a problem's graph (cached until the graph is rebuilt)."""
    hit = getattr(problem, "_table", None)
    if hit is not None and hit[0] is problem.graph:
        return hit[1]
    tab = _factor_table(problem)
    problem._table = (problem.graph, tab)
    return tab


def _factor_table(problem) -> FactorTable:
    process = (problem.prior_factors + problem.imu_factors
               + [f for g in problem.clock_factor_groups + problem.bias_factor_groups for f in g])
    dims = [f.dim() for f in process]
    sigma = [np.nan] * len(process)
    huber = [np.nan] * len(process)
    k_rob = np.nan if problem.huber_k is None else float(problem.huber_k)
    for fl in problem.epoch_factors:
        for kind, f, sig in fl:
            dims.append(1 if sig is not None else f.dim())
            sigma.append(np.nan if sig is None else sig)
            # the linearised factors (LC fixes with error states, double differences) are not robust
            huber.append(k_rob if kind in _ROBUST_KINDS and not isinstance(f, gtsam.LinearContainerFactor) else np.nan)
    return FactorTable(factor_kinds(problem), np.r_[0, np.cumsum(dims)].astype(np.int64), np.array(sigma, float),
                       np.array(huber, float))


def whitened_errors(rows, tab: FactorTable) -> np.ndarray:
    """Every row's error whitened by its factor's Gaussian noise (without the robust re-weighting), from the graph
    linearised at the point of interest (`dgcal.pos.smoother.linearised.KeyframeRows`): gtsam's right-hand side is
    minus the whitened error, scaled by sqrt(w) for a robust factor, w = k/|e| (Huber) beyond k, so
    |b| = sqrt(k |e|) there and |e| = |b|^2 / k."""
    n = int(tab.start[-1])
    b = np.zeros(n)
    m = min(n, len(rows.b_all))
    b[:m] = rows.b_all[:m]
    nb = np.sqrt(np.add.reduceat(b * b, tab.start[:-1])) if n else np.zeros(0)
    dims = np.diff(tab.start)
    k = np.repeat(tab.huber, dims)
    nbr = np.repeat(nb, dims)
    scale = np.where(np.isfinite(k) & (nbr > np.nan_to_num(k, nan=np.inf)), nbr / np.where(np.isfinite(k), k, 1.0), 1.0)
    return -b * scale


_KIND = {"pos": "position", "vel": "velocity", "pr": "pseudorange", "dop": "Doppler"}


def reject_outliers(problem, rows, k_sigma: float = 5.0) -> list[dict]:
    """Remove the GNSS factors whose post-fit residual fails the chi-square test (module docstring) from `problem`
    (epoch factors, graph, GNSS-update flags and satellite counts); `rows`: the graph linearised at the solution
    (`dgcal.pos.smoother.linearised.keyframe_rows`). Returns one dict per rejected factor: kind, t_gps, keyframe,
    normalised residual (sigmas) and detail."""
    alpha = 2.0 * ndtr(-k_sigma)
    tab = factor_table(problem)
    z = whitened_errors(rows, tab)
    z2_all = np.add.reduceat(z * z, tab.start[:-1]) if len(z) else np.zeros(0)
    dims = np.diff(tab.start)
    finite = np.isfinite(z2_all)
    first = len(tab.kinds) - sum(len(fl) for fl in problem.epoch_factors)
    kind_of = np.array([e[0] for fl in problem.epoch_factors for e in fl], dtype=object)
    k_of = np.repeat(np.arange(len(problem.epoch_factors)), [len(fl) for fl in problem.epoch_factors])
    j_of = np.concatenate([np.arange(len(fl)) for fl in problem.epoch_factors]) if len(k_of) else np.zeros(0, int)
    z2_e, dim_e, fin_e = z2_all[first:], dims[first:], finite[first:]
    drop: dict = {}
    out = []
    for kind in _KIND:
        sel = np.flatnonzero((kind_of == kind) & fin_e)
        if not len(sel):
            continue
        k, j, z2 = k_of[sel], j_of[sel], z2_e[sel]
        dim = int(dim_e[sel[0]])
        scale = max(1.0, float(np.median(z2)) / float(chdtri(dim, 0.5)))
        thr = scale * float(chdtri(dim, alpha))
        for i in np.flatnonzero(z2 > thr):
            drop.setdefault(int(k[i]), set()).add(int(j[i]))
            out.append({"kind": _KIND[kind], "t_gps": float(problem.t_key[k[i]]), "keyframe": int(k[i]),
                        "normalised": round(float(np.sqrt(z2[i])), 2),
                        "detail": f"post-fit {_KIND[kind]} residual {np.sqrt(z2[i]):.1f} sigma (limit "
                                  f"{np.sqrt(thr):.1f}): rejected"})
    if not drop:
        return []
    for k, js in drop.items():
        fl = problem.epoch_factors[k]
        n_pr = sum(1 for j in js if fl[j][0] == "pr")
        problem.epoch_factors[k] = [x for j, x in enumerate(fl) if j not in js]
        kinds = {e[0] for e in problem.epoch_factors[k]}
        if problem.gnss_update is not None:
            problem.gnss_update[k] = bool(kinds & {"pos", "pr", "dd"})
        if problem.n_sat is not None:
            if n_pr:
                problem.n_sat[k] = max(0, int(problem.n_sat[k]) - n_pr)
            elif "pr" not in kinds and "dd" not in kinds:
                problem.n_sat[k] = int("pos" in kinds)
    problem.graph = assemble_graph(problem)
    out.sort(key=lambda r: (r["t_gps"], r["kind"]))
    return out


def with_bridges(per_interval: list, imu, noise, frame, t_key: np.ndarray, earth_rotation: bool = True) -> list:
    """Per-interval preintegration parameters with the bridged spans' white noise added (`imu.bridges`); the
    intervals without a bridge keep their entry (None: the shared parameters)."""
    dens = bridge_densities(getattr(imu, "bridges", []), np.asarray(t_key, float))
    if dens is None:
        return per_interval
    qg, qa = dens
    out = list(per_interval)
    for k in range(len(out)):
        if not (np.any(qg[k]) or np.any(qa[k])):
            continue
        p = out[k] if out[k] is not None else preintegration_params(noise, frame, earth_rotation)
        p.setGyroscopeCovariance(p.getGyroscopeCovariance() + qg[k])
        p.setAccelerometerCovariance(p.getAccelerometerCovariance() + qa[k])
        out[k] = p
    return out


def gnss_warnings(rejected: list[dict], max_times: int = 8) -> list[str]:
    """One console line per kind of GNSS rejection (and input), naming the epoch times (continuous GPS s)."""
    groups: dict = {}
    for r in rejected:
        stage = "post-fit" if "normalised" in r else "IMU-bound"
        groups.setdefault((r.get("input", "gnss"), r["kind"], stage), []).append(r)
    out = []
    for (src, kind, stage), rows in groups.items():
        times = sorted({round(r["t_gps"], 3) for r in rows})
        more = f" (+{len(times) - max_times} more, see pos_summary.json)" if len(times) > max_times else ""
        what = ("beyond what the IMU-measured acceleration allows from the neighbouring epochs"
                if stage == "IMU-bound" else "beyond the chi-square limit after the first pass")
        where = " (initial track only)" if src == "initial track" else ""
        noun = "epoch" if kind in ("position", "velocity") else "observation"
        out.append(f"GNSS: {len(rows)} {kind} {noun}{'s' if len(rows) != 1 else ''}{where} rejected, {what}; "
                   f"at t = {', '.join(f'{t:.3f}' for t in times[:max_times])}{more}")
    return out
