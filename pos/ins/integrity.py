"""IMU data integrity before smoothing: time order, duplicates, gaps and spikes found, repaired and listed.

`check_imu(imu)` returns the repaired `ImuData` and an `ImuIntegrity` record (what was found, where, and what
was done); everything is vectorised NumPy (files have millions of samples).

- Out-of-order samples are sorted into time order; duplicated time stamps keep the first sample.
- Gaps: an interval longer than 1.5 nominal steps whose increment covers one step only (samples lost: the
  increment divided by the whole gap would be a near-zero rate, i.e. free fall), or any interval longer than
  `gap_factor` steps. Lost samples are filled at the nominal rate with rates interpolated linearly between
  the mean rates just before and just after the gap (`edge_s`); an increment that covers the whole gap is kept.
- Spikes: a gyro or accelerometer sample whose deviation from the running median of its neighbours exceeds
  `spike_mads` robust sigmas (the sample noise from the median absolute sample-to-sample change around it)
  AND a physical floor (`spike_gyro_rad_s`, `spike_accel_m_s2`: no vibration or manoeuvre moves one sample
  that far from its neighbours) is replaced by the interpolation of its clean neighbours.
- Every bridged span (gap or spike) carries a `Bridge`: the white-noise density (body axes) that the smoother
  adds to the IMU noise over the span, so that its preintegration carries the error of the interpolation.
  The density is measured on the flight itself: over windows of the gap's length elsewhere in the record,
  the same interpolation (mean rates before and after, trapezoid) misses the true increment integral by an
  error whose mean square (per axis) over the window length is the density, or the largest error over three
  when that is more (heavy tails: a climb-out or a bank reversal hidden in a gap is rare but must stay within
  three sigmas). All windows count: the rates on either side of a gap do not tell whether a manoeuvre happened
  inside it (equal rates before and after a bank reversal), so the density is the flight's own, conservative
  in straight flight and honest in the manoeuvres.
  A gap longer than `max_gap_s`, or too long for the record to measure that error, cannot be bridged:
  `ResultError`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dgcal.fields.errors import ResultError
from dgcal.pos.ins.imu_data import ImuData
from dgcal.pos.ins.plausibility import check_imu_units


@dataclass
class ImuIntegrityOptions:
    """Thresholds of `check_imu` (seconds, rad/s, m/s^2)."""

    gap_factor: float = 3.0            # an interval longer than this many nominal steps is a gap in any case
    max_gap_s: float = 10.0            # longer gaps are not bridged: ResultError
    spike_window: int = 9              # samples of the running median (odd)
    spike_mads: float = 12.0           # deviation from the running median in robust sigmas ...
    spike_gyro_rad_s: float = 1.0      # ... and beyond this (57 deg/s in one sample) for a gyro spike
    spike_accel_m_s2: float = 20.0     # ... or this (2 g) for an accelerometer spike
    edge_s: float = 0.05               # mean rates before and after a gap over this span
    min_windows: int = 20              # windows of a gap's length needed to measure the bridge noise


@dataclass
class ImuIssue:
    """One finding: `kind` duplicate | out_of_order | gap | spike, the span [t0, t1] (GPS s), the samples
    concerned (dropped, moved, filled or replaced) and what was done."""

    kind: str
    t0: float
    t1: float
    n: int
    detail: str

    def as_dict(self) -> dict:
        return {"kind": self.kind, "t0_gps": round(self.t0, 6), "t1_gps": round(self.t1, 6), "n": self.n,
                "detail": self.detail}


@dataclass
class Bridge:
    """A bridged span (t0, t1] (GPS s) and the white-noise densities the smoother adds over it: `q_gyro`
    (3,3) rad^2/s and `q_accel` (3,3) (m/s)^2/s, body axes; their integral over the span is the covariance of
    the interpolation's rotation and velocity increment errors."""

    t0: float
    t1: float
    q_gyro: np.ndarray
    q_accel: np.ndarray

    def rotated(self, R_sensor_to_body: np.ndarray) -> "Bridge":
        """The same densities in body axes, from the IMU sensor's (`ImuData.rotated`)."""
        return Bridge(self.t0, self.t1, R_sensor_to_body @ self.q_gyro @ R_sensor_to_body.T,
                      R_sensor_to_body @ self.q_accel @ R_sensor_to_body.T)


@dataclass
class ImuIntegrity:
    """What `check_imu` found and did: the issues in time order and the bridges handed to the smoother."""

    issues: list[ImuIssue] = field(default_factory=list)
    bridges: list[Bridge] = field(default_factory=list)
    n_in: int = 0
    n_out: int = 0
    rate_hz: float = 0.0

    def count(self, kind: str) -> int:
        return sum(1 for i in self.issues if i.kind == kind)

    def warnings(self, max_times: int = 8) -> list[str]:
        """One line per kind of issue, naming the times (continuous GPS s) of the first `max_times`."""
        out = []
        what = {"out_of_order": ("sample", "out of time order: sorted"),
                "duplicate": ("duplicated time stamp", "the later sample dropped"),
                "gap": ("time gap", "bridged (rates interpolated, the smoother's IMU noise raised there)"),
                "spike": ("spike", "replaced by the interpolation of the neighbours")}
        for kind, (noun, done) in what.items():
            rows = [i for i in self.issues if i.kind == kind]
            if not rows:
                continue
            n = len(rows) if kind == "gap" else sum(i.n for i in rows)
            head = f"IMU: {n} {noun}{'s' if n != 1 else ''} {done}"
            if kind == "gap":
                longest = max(rows, key=lambda i: i.t1 - i.t0)
                head += (f", {sum(i.t1 - i.t0 for i in rows):.3f} s in all, longest {longest.t1 - longest.t0:.3f} s "
                         f"from t={longest.t0:.3f}")
            times = ", ".join(f"{i.t0:.3f}" + (f"-{i.t1:.3f}" if i.t1 > i.t0 else "") for i in rows[:max_times])
            more = f" (+{len(rows) - max_times} more, see pos_summary.json)" if len(rows) > max_times else ""
            out.append(f"{head}; at t = {times}{more}")
        return out

    def summary(self, max_rows: int = 1000) -> dict:
        """The record for pos_summary.json: counts per kind and every issue (the first `max_rows`)."""
        return {"samples_in": self.n_in, "samples_out": self.n_out, "rate_hz": self.rate_hz,
                "counts": {k: self.count(k) for k in ("out_of_order", "duplicate", "gap", "spike")},
                "bridged_s": round(float(sum(b.t1 - b.t0 for b in self.bridges)), 6),
                "issues": [i.as_dict() for i in self.issues[:max_rows]],
                "issues_not_listed": max(0, len(self.issues) - max_rows)}


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (inclusive) indices of the runs of True in a boolean array."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1


def _order(t, g, a, tol: float, issues: list):
    """Sort into time order (stable) and drop repeated time stamps (first kept); issues appended."""
    before = np.maximum.accumulate(np.r_[-np.inf, t[:-1]])           # the latest time before each sample
    late = t < before
    if late.any():
        for i in np.flatnonzero(late):
            issues.append(ImuIssue("out_of_order", float(t[i]), float(t[i]), 1,
                                   f"sample {i} at t={t[i]:.6f} after t={before[i]:.6f}: sorted"))
        o = np.argsort(t, kind="stable")
        t, g, a = t[o], g[o], a[o]
    dup = np.r_[False, np.diff(t) <= tol]
    if dup.any():
        for i in np.flatnonzero(dup):
            same = np.array_equal(g[i], g[i - 1]) and np.array_equal(a[i], a[i - 1])
            issues.append(ImuIssue("duplicate", float(t[i]), float(t[i]), 1,
                                   "repeated time stamp, " + ("same values" if same else "different values")
                                   + ": dropped"))
        keep = ~dup
        t, g, a = t[keep], g[keep], a[keep]
    return t, g, a


def _edge_rates(t, inc, dt_own, i: np.ndarray, ne: int):
    """Mean rates over the `ne` samples ending at i-1 (before the interval of sample i) and starting at i."""
    n = len(t)
    c = np.vstack([np.zeros((1, 3)), np.cumsum(inc, axis=0)])      # c[j] = sum of inc[:j]
    cd = np.r_[0.0, np.cumsum(dt_own)]
    lo = np.clip(i - ne, 0, n)
    hi = np.clip(i + ne, 0, n)
    before = (c[i] - c[lo]) / np.maximum(cd[i] - cd[lo], 1e-12)[:, None]
    after = (c[hi] - c[i]) / np.maximum(cd[hi] - cd[i], 1e-12)[:, None]
    return before, after


def _spikes(rate, window: int, k: float, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """Samples whose deviation from the running median of `window` samples exceeds both k robust sigmas
    (per axis and block of samples, from the median absolute sample-to-sample change) and the physical floor;
    and the deviations (rate units, 0 where not tested). The median is taken only near sample-to-sample jumps
    beyond a quarter of the threshold (a run of up to window//2 bad samples must jump that much somewhere)."""
    n = len(rate)
    h = window // 2
    bad = np.zeros(n, bool)
    dev = np.zeros((n, 3))
    if n < window:
        return bad, dev
    d = np.abs(np.diff(rate, axis=0))
    block = max(20 * window, 200)
    nb = int(np.ceil(len(d) / block))
    pad = np.concatenate([d, np.repeat(d[-1:], nb * block - len(d), axis=0)])
    s = 1.4826 / np.sqrt(2.0) * _block_medians(pad.reshape(nb, block, 3))        # per-sample noise sigma
    thr = np.maximum(k * np.repeat(s, block, axis=0)[:n], floor)
    thr = np.vstack([thr, thr[-1:]])[:n]
    jump = np.any(d > 0.25 * np.minimum(thr[1:], thr[:-1]), axis=1)
    near = np.convolve(np.r_[jump, False].astype(float), np.ones(2 * h + 3), mode="same") > 0
    ci = np.flatnonzero(near)
    if not len(ci):
        return bad, dev
    idx = np.clip(ci[:, None] + np.arange(-h, h + 1), 0, n - 1)
    med = np.median(rate[idx], axis=1)
    dev[ci] = np.abs(rate[ci] - med)
    bad[ci] = np.any(dev[ci] > thr[ci], axis=1)
    return bad, dev


def _block_medians(x: np.ndarray) -> np.ndarray:
    """np.median(x, axis=1) of finite x (nb, m, 3) by one partition (a third of np.median's time on an hour of
    200 Hz data)."""
    m = x.shape[1]
    y = np.ascontiguousarray(np.swapaxes(x, 1, 2))
    k = m // 2
    if m % 2:
        return np.partition(y, k, axis=2)[..., k]
    p = np.partition(y, [k - 1, k], axis=2)
    return 0.5 * (p[..., k - 1] + p[..., k])


def _replace(t_mid, rate, bad: np.ndarray) -> np.ndarray:
    """Rates with the `bad` samples replaced by linear interpolation (in time) of the good ones."""
    out = rate.copy()
    good = ~bad
    for j in range(3):
        out[bad, j] = np.interp(t_mid[bad], t_mid[good], rate[good, j])
    return out


def interpolation_errors(t, inc, dt_own, T: float, ne: int, bad: np.ndarray, max_windows: int = 4000):
    """How well `ne`-sample mean rates before and after a span of T seconds predict the increment integral over
    it, on windows of that length over clean parts of the record: the errors (W,3) of the trapezoid and the
    windows' lengths (W,) s."""
    n = len(t)
    c = np.vstack([np.zeros((1, 3)), np.cumsum(inc, axis=0)])            # c[j] = sum of inc[:j]
    cd = np.r_[0.0, np.cumsum(dt_own)]
    cbad = np.r_[0, np.cumsum(bad)]
    t_start = t - dt_own                                                   # interval start of each sample
    a = np.arange(ne, n, max(1, n // max_windows))                         # window: samples a .. b-1
    b = np.searchsorted(t_start, t_start[a] + T)
    ok = (b + ne <= n) & (b > a)
    a, b = a[ok], b[ok]
    ok = (cbad[b + ne] - cbad[a - ne]) == 0
    a, b = a[ok], b[ok]
    span = cd[b] - cd[a]
    before = (c[a] - c[a - ne]) / (cd[a] - cd[a - ne])[:, None]
    after = (c[b + ne] - c[b]) / (cd[b + ne] - cd[b])[:, None]
    e = (c[b] - c[a]) - 0.5 * (before + after) * span[:, None]
    return e, span


def _density(e: np.ndarray, span: np.ndarray) -> np.ndarray:
    """White-noise density (3,) per axis from interpolation errors e (W,3) over windows of length span (W,):
    the mean square error per second, or (the largest error / 3)^2 per second when that is more (the errors
    are heavy-tailed: a climb-out or a bank reversal hidden in a gap happens in few windows but must stay
    within three sigmas)."""
    e2 = e ** 2 / span[:, None]
    return np.maximum(np.mean(e2, axis=0), np.max(e2, axis=0) / 9.0)


def _find_gaps(t, a, dt, step: float, gap_factor: float):
    """Gap samples (index of the sample after each gap), whether its samples were lost (its increment covers
    one step: its own interval is then one step) and every sample's own interval."""
    long_ = np.flatnonzero(dt > 1.5 * step)
    long_ = long_[long_ > 0]
    dt_own = dt.copy()
    lost = np.zeros(len(long_), bool)
    if len(long_):
        f_norm = np.linalg.norm(a / np.maximum(dt, 1e-12)[:, None], axis=1)
        ref = np.median(f_norm)                                             # typical specific force, ~g
        as_step = np.linalg.norm(a[long_], axis=1) / step
        as_gap = f_norm[long_]
        lost = np.abs(np.log(np.maximum(as_step, 1e-9) / ref)) < np.abs(np.log(np.maximum(as_gap, 1e-9) / ref))
        dt_own[long_[lost]] = step
        is_gap = lost | (dt[long_] > gap_factor * step)      # an increment over a little longer interval: jitter
        long_, lost = long_[is_gap], lost[is_gap]
    return long_, lost, dt_own


def _fix_spikes(t, g, a, dt_own, opts: ImuIntegrityOptions) -> dict:
    """Replace the spikes of gyro and accelerometer (in place, in the increments `g`, `a`); returns per sensor
    the mask of replaced samples and the deviations from the running median (rate units)."""
    t_mid = t - 0.5 * dt_own
    spk = {}
    for name, inc, floor in (("gyro", g, opts.spike_gyro_rad_s), ("accel", a, opts.spike_accel_m_s2)):
        rate = inc / dt_own[:, None]
        bad, dev = _spikes(rate, opts.spike_window, opts.spike_mads, floor)
        if bad.any():
            inc[:] = _replace(t_mid, rate, bad) * dt_own[:, None]
            spk[name] = (bad, dev)
    return spk


def _make_bridges(t, g, a, dt_own, long_, lost, spans, runs, step, ne, bad, opts, path) -> list:
    """One Bridge per gap (first) and per spike run, with the interpolation noise measured on the record."""
    runs0, runs1 = runs
    all_spans = np.r_[spans, (t[runs1] - t[runs0] + dt_own[runs0]) if len(runs0) else np.zeros(0)]
    if not len(all_spans):
        return []
    # the errors per length on a logarithmic grid (many short gaps share one), at the cell's upper edge
    cells = np.round(np.log(np.maximum(all_spans, step)) / np.log(1.25))
    out: list = [None] * len(all_spans)
    for c in np.unique(cells):
        T = 1.25 ** (c + 0.5)
        eg, sp = interpolation_errors(t, g, dt_own, T, ne, bad)
        ea, _ = interpolation_errors(t, a, dt_own, T, ne, bad)
        if len(sp) < opts.min_windows:
            raise ResultError(f"IMU gap of {all_spans[cells == c].max():.3f} s: the record ({t[-1] - t[0]:.0f} s) is "
                              f"too short to measure how well that much IMU data can be interpolated; it cannot be "
                              "bridged", path)
        qg, qa = np.diag(_density(eg, sp)), np.diag(_density(ea, sp))
        for j in np.flatnonzero(cells == c):
            if j < len(spans):
                k = long_[j]
                t0b, t1b = float(t[k - 1]), float(t[k] - (dt_own[k] if lost[j] else 0.0))
            else:
                r = j - len(spans)
                t0b, t1b = float(t[runs0[r]] - dt_own[runs0[r]]), float(t[runs1[r]])
            out[j] = Bridge(t0b, t1b, qg, qa)
    return out


def _fill(t, g, a, dt_own, kk, step: float, ne: int):
    """Insert samples at the nominal step into the gaps before samples `kk` (lost samples), their rates
    interpolated linearly between the mean rates before and after the gap."""
    S = t[kk] - t[kk - 1] - step
    m = np.maximum(1, np.round(S / step).astype(int))
    h = S / m
    bg, ag = _edge_rates(t, g, dt_own, kk, ne)
    ba, aa = _edge_rates(t, a, dt_own, kk, ne)
    idx = np.repeat(np.arange(len(kk)), m)
    j = np.arange(m.sum()) - np.repeat(np.cumsum(m) - m, m) + 1          # 1..m within each gap
    frac = (j - 0.5) / m[idx]
    t_new = t[kk - 1][idx] + j * h[idx]
    g_new = (bg[idx] + frac[:, None] * (ag[idx] - bg[idx])) * h[idx, None]
    a_new = (ba[idx] + frac[:, None] * (aa[idx] - ba[idx])) * h[idx, None]
    pos = np.repeat(kk, m)
    return np.insert(t, pos, t_new), np.insert(g, pos, g_new, axis=0), np.insert(a, pos, a_new, axis=0)


def check_imu(imu, opts: ImuIntegrityOptions | None = None):
    """The repaired IMU data and what was done (`ImuIntegrity`); see the module docstring. Raises ResultError
    for a gap that cannot be bridged honestly (longer than `max_gap_s` or than the record can model)."""
    opts = opts or ImuIntegrityOptions()
    rep = ImuIntegrity(n_in=len(imu), rate_hz=float(imu.rate_hz), n_out=len(imu))
    if len(imu) < 3:
        return imu, rep
    check_imu_units(imu)                  # g for m/s^2, a z axis up, deg/s for rad/s: refused by their cause
    t = np.asarray(imu.t, float)
    dt0 = float(imu.dt[0])
    g, a = np.array(imu.dtheta, float), np.array(imu.dvel, float)          # copies: repaired in place
    t, g, a = _order(t, g, a, min(1e-6, 0.01 / float(imu.rate_hz)), rep.issues)
    dt = np.r_[dt0, np.diff(t)]
    step = float(np.median(dt[1:]))                                         # the nominal step of the data
    ne = max(1, int(round(opts.edge_s / step)))
    long_, lost, dt_own = _find_gaps(t, a, dt, step, opts.gap_factor)
    spans = t[long_] - t[long_ - 1] - np.where(lost, step, 0.0)
    if len(spans) and spans.max() > opts.max_gap_s:
        k = long_[int(np.argmax(spans))]
        raise ResultError(f"IMU gap of {spans.max():.3f} s from t={t[k - 1]:.3f} to {t[k - 1] + spans.max():.3f} "
                          f"GPS s is longer than the {opts.max_gap_s:g} s that can be bridged: process the parts "
                          "before and after separately (--t-start/--t-end), or raise --set imu_max_gap_s", imu.path)
    spk = _fix_spikes(t, g, a, dt_own, opts)
    bad = np.zeros(len(t), bool)
    bad[long_] = True
    spike_bad = np.zeros(len(t), bool)
    for m, _ in spk.values():
        spike_bad |= m
    runs = _runs(spike_bad)
    bridges = _make_bridges(t, g, a, dt_own, long_, lost, spans, runs, step, ne, bad | spike_bad, opts, imu.path)
    for j, k in enumerate(long_):
        s, b = spans[j], bridges[j]
        sg = np.degrees(np.sqrt(b.q_gyro.diagonal().max() * s))
        sv = np.sqrt(b.q_accel.diagonal().max() * s)
        how = f"{int(round(s / step))} samples missing, filled" if lost[j] else "one increment spans the gap, kept"
        rep.issues.append(ImuIssue("gap", float(t[k - 1]), float(t[k - 1] + s), int(round(s / step)) if lost[j]
                                   else 0, f"{s:.3f} s: {how}; bridge sigma {sg:.3f} deg, {sv:.3f} m/s"))
    for i0, i1 in zip(*runs):
        parts = []
        for name, (m, dev) in spk.items():
            if m[i0:i1 + 1].any():
                d = dev[i0:i1 + 1][m[i0:i1 + 1]].max()
                parts.append(f"gyro {np.degrees(d):.1f} deg/s" if name == "gyro" else f"accel {d:.1f} m/s^2")
        rep.issues.append(ImuIssue("spike", float(t[i0]), float(t[i1]), int(i1 - i0 + 1),
                                   "deviation from the neighbours' median " + ", ".join(parts) + ": interpolated"))
    if lost.any():
        t, g, a = _fill(t, g, a, dt_own, long_[lost], step, ne)
    rep.issues.sort(key=lambda i: i.t0)
    rep.bridges = list(getattr(imu, "bridges", [])) + bridges
    rep.n_out = len(t)
    if not rep.issues:
        return imu, rep
    return ImuData(t, g, a, imu.rate_hz, imu.path, None, rep.bridges), rep


def bridge_densities(bridges: list, t_key: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Added white-noise densities per keyframe interval (K-1, 3, 3) for gyro and accelerometer: each bridge's
    covariance (density times its overlap with the interval) spread evenly over the interval; None without
    bridges in the keyframe span."""
    if not bridges:
        return None
    K = len(t_key)
    T = np.diff(t_key)
    qg = np.zeros((K - 1, 3, 3))
    qa = np.zeros((K - 1, 3, 3))
    hit = False
    for b in bridges:
        o = np.clip(np.minimum(t_key[1:], b.t1) - np.maximum(t_key[:-1], b.t0), 0.0, None)
        if not np.any(o > 0):
            continue
        hit = True
        w = o / T
        qg += w[:, None, None] * b.q_gyro
        qa += w[:, None, None] * b.q_accel
    return (qg, qa) if hit else None
