"""The IMU-GNSS time offset estimated with its sigma, from the smoother's own chi-square profile.

An IMU logged on a clock that is off from GNSS time by delta puts every specific force and rate delta seconds
early or late: in motion the GNSS measurements then disagree with the IMU by about v*delta and a*delta, and the
smoother's minimum cost (chi-square, twice gtsam's error) grows with |delta - delta_true|. Around its minimum the
profile is a parabola, chi2(d) = chi2_min + (d - d_hat)^2 / sigma^2 for Gaussian errors (the profile likelihood):
three smoothings at d0 - h, d0, d0 + h give d_hat and sigma, and the step h is refined once around d_hat (h near
sigma keeps the parabola's own error small). The offset is a constant of the whole record; the smoother is run
as usual at each trial offset, so everything it models (carrier phase, code biases, static ends) counts.

The profile's curvature is the offset's sigma only if every error the smoother leaves is white. Errors the model
does not carry (a vehicle's vibration, unmodelled lever-arm or mounting effects, fix errors of another shape than
the Gauss-Markov states) are correlated over the record and pull the vertex where they happen to lie, so the
curvature alone was 1-2 ms on the real car drive while two reasonable configurations put the offset 120 ms apart.
Hence a block jackknife over time (`window_jackknife`): the chi-square of every trial is split into `windows`
consecutive time windows (each factor into the window of its keyframe), each window's share is a parabola in the
offset, and the vertex is recomputed with each window left out; the spread of those estimates is the sigma that
holds with correlated errors (it equals the curvature's for white ones). The reported sigma is the larger of the
two; an offset whose windows disagree far beyond that (`JACKKNIFE_MAX_INFLATION`), or whose sigma exceeds the
estimate, is declared not determinable and not applied (`TimeOffsetEstimate.determinable`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from dgcal.pos.ins.imu_data import ImuData
from dgcal.pos.smoother.batch import smooth


# Block jackknife: windows at least this long (the LC fixes' error states' correlation time is 60 s), 4-10 of them
WINDOW_MIN_S = 60.0
WINDOWS_MIN, WINDOWS_MAX = 4, 10
# The windows may disagree this much beyond the curvature's sigma before the offset is "not determinable": a larger
# spread means the offset's chi-square is shaped by errors the smoother does not model, not by the offset
JACKKNIFE_MAX_INFLATION = 5.0
# below this sigma an offset is determined even near zero (the offset given was right)
MIN_USEFUL_SIGMA_S = 0.005


@dataclass
class TimeOffsetEstimate:
    """The IMU time offset (s, added to the IMU's time tags) minimising the smoother's chi-square, its sigma (s: the
    larger of the profile curvature's and the time windows' jackknife), and the trials (offset s, chi-square).

    formal_sigma_s: from the curvature alone (white errors); jackknife_sigma_s: the block jackknife over
    `windows` time windows (nan without them); window_offsets_s: each window's own vertex (nan where it has no
    curvature), window_weights its chi-square share's curvature (1/s^2); determinable: False when the windows
    disagree too much or the sigma exceeds the estimate (the estimate is then not applied)."""

    offset_s: float
    sigma_s: float
    trials: list = field(default_factory=list)
    note: str = ""
    formal_sigma_s: float = float("nan")
    jackknife_sigma_s: float = float("nan")
    windows: int = 0
    window_offsets_s: list = field(default_factory=list)
    window_weights: list = field(default_factory=list)
    determinable: bool = True

    def as_dict(self) -> dict:
        """JSON-ready: offset and sigmas in ms, the trials, the windows' vertices, whether it is determinable."""
        return {"offset_ms": _ms(self.offset_s), "sigma_ms": _ms(self.sigma_s),
                "formal_sigma_ms": _ms(self.formal_sigma_s), "jackknife_sigma_ms": _ms(self.jackknife_sigma_s),
                "windows": self.windows, "window_offsets_ms": [_ms(x) for x in self.window_offsets_s],
                "determinable": self.determinable,
                "trials": [[round(1e3 * d, 3), round(c, 3)] for d, c in self.trials], "note": self.note}


def _ms(x: float) -> float | None:
    """Seconds as milliseconds rounded for JSON (None when not finite)."""
    return round(1e3 * float(x), 3) if np.isfinite(x) else None


def parabola_vertex(d: np.ndarray, c: np.ndarray) -> tuple[float, float]:
    """Vertex (d_hat) and 1-sigma half-width (where the chi-square grows by one) of the parabola through three
    points (d, chi-square); (nan, nan) if it does not open upwards."""
    A = np.vstack([d ** 2, d, np.ones(3)]).T
    a, b, _ = np.linalg.solve(A, c)
    if not np.isfinite(a) or a <= 0:
        return float("nan"), float("nan")
    return float(-b / (2 * a)), float(1.0 / np.sqrt(a))


def estimate_time_offset(chi2_at: Callable[[float], float | tuple], start_s: float = 0.0, step_s: float = 0.02,
                         max_widen: int = 4) -> TimeOffsetEstimate:
    """The IMU time offset (s) minimising `chi2_at(offset)` (the smoother's chi-square with the IMU's times shifted
    by `offset`): a parabola through start - h, start, start + h, h widened (x4) while the profile is flat or not
    convex within it and re-centred on a vertex outside it, then one more parabola centred on the estimate with
    h = max(sigma, h/4). When `chi2_at` returns (chi-square, per-window chi-squares) two more trials at 3 h either
    side feed the block jackknife (`window_jackknife`) and the sigma is the larger of the two."""
    trials: list = []
    parts: dict = {}

    def run(d: float) -> float:
        out = chi2_at(d)
        c = float(out[0]) if isinstance(out, tuple) else float(out)
        if isinstance(out, tuple):
            parts[d] = np.asarray(out[1], float)
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
                                  "too little motion to observe it", determinable=False)
    h2 = max(min(sig, h), h / 4.0)
    c_mid = run(d_hat)
    centre2 = d_hat
    d2, s2 = parabola_vertex(np.array([d_hat - h2, d_hat, d_hat + h2]),
                             np.array([run(d_hat - h2), c_mid, run(d_hat + h2)]))
    if np.isfinite(d2) and abs(d2 - d_hat) <= 2 * h2:
        d_hat, sig = d2, s2
    est = TimeOffsetEstimate(float(d_hat), float(sig), trials, formal_sigma_s=float(sig))
    if parts:
        # the window shares change little over +-sigma against the smoother's convergence noise: wider trials too
        for d in (centre2 - 3 * h2, centre2 + 3 * h2):
            run(d)
        near = sorted(d for d in parts if abs(d - centre2) <= 3.5 * h2)
        jk, x_w, a_w = window_jackknife(np.array(near), np.array([parts[d] for d in near]), est.offset_s)
        est.jackknife_sigma_s, est.windows, est.window_offsets_s = jk, len(x_w), list(x_w)
        est.window_weights = list(np.maximum(a_w, 0.0))
        if np.isfinite(jk):
            est.sigma_s = max(est.formal_sigma_s, jk)
    judge_determinable(est)
    return est


def window_jackknife(d: np.ndarray, C: np.ndarray, d_hat: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Block-jackknife sigma (s) of the profile's vertex from per-window chi-squares C (n trials, W windows) at
    offsets d (s): each window's share fitted as c + g x + a x^2 in x = d - d_hat (least squares), the vertex
    without window w at -(G - g_w) / 2(A - a_w), the jackknife variance (W-1)/W sum (x_(-w) - mean)^2. Also each
    window's own vertex (s; nan where its share has no curvature) and its share's curvature a (1/s^2). nan when
    fewer than 3 trials or windows."""
    W = C.shape[1] if C.ndim == 2 else 0
    if len(d) < 3 or W < 3:
        return float("nan"), np.full(W, np.nan), np.zeros(W)
    x = d - d_hat
    A_fit = np.vstack([np.ones_like(x), x, x * x]).T
    coef = np.linalg.lstsq(A_fit, C, rcond=None)[0]            # (3, W)
    g, a = coef[1], coef[2]
    G, A = float(g.sum()), float(a.sum())
    if not A > 0 or np.any(A - a <= 0):
        return float("nan"), np.full(W, np.nan), a
    loo = -(G - g) / (2.0 * (A - a))
    var = (W - 1) / W * float(np.sum((loo - loo.mean()) ** 2))
    own = np.where(a > 1e-3 * A, d_hat - g / (2.0 * np.where(a > 0, a, 1.0)), np.nan)
    return float(np.sqrt(var)), own, a


def judge_determinable(est: TimeOffsetEstimate) -> None:
    """Mark `est` not determinable (with its reason in `note`) when its windows disagree beyond
    JACKKNIFE_MAX_INFLATION times the curvature's sigma (then naming a drift of the windows' offsets over the
    record, a clock-rate error, when their line explains them), or when its sigma exceeds both its estimate and
    MIN_USEFUL_SIGMA_S (neither a correction nor a confirmation of the offset given)."""
    why = []
    if np.isfinite(est.jackknife_sigma_s) and est.jackknife_sigma_s > JACKKNIFE_MAX_INFLATION * est.formal_sigma_s:
        why.append(f"its time windows disagree ({1e3 * est.jackknife_sigma_s:.1f} ms jackknife against "
                   f"{1e3 * est.formal_sigma_s:.1f} ms from the curvature): errors the smoother does not model "
                   "shape the profile" + window_trend(est.window_offsets_s, est.window_weights))
    if est.sigma_s > abs(est.offset_s) and est.sigma_s > MIN_USEFUL_SIGMA_S:
        why.append(f"its sigma ({1e3 * est.sigma_s:.1f} ms) exceeds the estimate ({1e3 * est.offset_s:+.1f} ms): the "
                   "data cannot tell it from the offset given")
    if why:
        est.determinable = False
        est.note = "; ".join(why)


def window_trend(offsets_s: list, weights: list) -> str:
    """A clause naming the drift (first to last window, ms) when a line through the windows' offsets (s, weighted
    by their chi-square curvature `weights`) explains at least 3/4 of their weighted spread, else ''."""
    y = np.asarray(offsets_s, float)
    x = np.arange(len(y), dtype=float)
    w = np.asarray(weights, float) if len(weights) == len(y) else np.ones(len(y))
    ok = np.isfinite(y) & (w > 0)
    if ok.sum() < 4:
        return ""
    slope, icpt = np.polyfit(x[ok], y[ok], 1, w=np.sqrt(w[ok]))
    ym = np.average(y[ok], weights=w[ok])
    spread = np.average((y[ok] - ym) ** 2, weights=w[ok])
    if not spread > 0 or np.average((y[ok] - slope * x[ok] - icpt) ** 2, weights=w[ok]) > 0.25 * spread:
        return ""
    return (f"; the windows' offsets drift from {1e3 * icpt:+.0f} to {1e3 * (icpt + slope * x[-1]):+.0f} ms over the "
            "record (the IMU clock's rate differs from GNSS time: a constant offset cannot describe it)")


def shifted_imu(imu, offset_s: float):
    """The IMU data with `offset_s` (s) added to every time tag (and to its bridged spans)."""
    return ImuData(imu.t + offset_s, imu.dtheta, imu.dvel, imu.rate_hz, imu.path, imu.lines,
                   [replace(b, t0=b.t0 + offset_s, t1=b.t1 + offset_s) for b in imu.bridges])


def window_edges(t0: float, t1: float, windows: int | None = None) -> np.ndarray:
    """Edges (s) of the jackknife's time windows over [t0, t1]: `windows` of them, or one per WINDOW_MIN_S within
    WINDOWS_MIN..WINDOWS_MAX."""
    n = windows or int(np.clip((t1 - t0) // WINDOW_MIN_S, WINDOWS_MIN, WINDOWS_MAX))
    return np.linspace(t0, t1, n + 1)


def window_chi2(sol, edges: np.ndarray) -> np.ndarray:
    """The solution's chi-square (twice gtsam's error) split over the time windows `edges` (s): each factor in the
    window of the latest keyframe it touches."""
    problem, values = sol.problem, sol.values
    where = problem.blocks().where
    graph = problem.graph
    n = graph.size()
    err = np.zeros(n)
    kf = np.zeros(n, np.int64)
    for i in range(n):
        f = graph.at(i)
        if f is None:
            continue
        ks = [where[key][0] for key in f.keys() if where.get(key) is not None]
        kf[i] = max(ks) if ks else 0
        err[i] = f.error(values)
    w = np.clip(np.searchsorted(edges, problem.t_key[kf], side="right") - 1, 0, len(edges) - 2)
    return 2.0 * np.bincount(w, weights=err, minlength=len(edges) - 1)


def smoother_chi2(imu, fixes, grade, opts, mode: str = "tc", gnss=None, lc_fixes=None, carrier=None,
                  windows: int | None = 0) -> Callable[[float], float | tuple]:
    """chi2(offset): the smoother's final chi-square (twice gtsam's error, both passes, no covariances) with the
    IMU's time tags shifted by `offset` s; the GNSS inputs as `dgcal.pos.smoother.batch.smooth` takes them. With
    `windows` (None: one per WINDOW_MIN_S, `window_edges`) it returns (chi-square, per-window chi-squares) for the
    block jackknife.

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
    edges = None
    if windows is None or windows:
        t_obs = (lc_fixes if lc_fixes is not None else fixes).t
        edges = window_edges(max(float(t_obs[0]), float(imu.t[0])), min(float(t_obs[-1]), float(imu.t[-1])),
                             windows)

    def chi2(offset_s: float):
        sol = smooth(shifted_imu(imu, offset_s), fixes, grade, quiet, mode=mode, gnss=gnss, lc_fixes=lc_fixes,
                     carrier=carrier)
        total = 2.0 * float(sol.info["error_final"])
        return (total, window_chi2(sol, edges)) if edges is not None else total
    return chi2
