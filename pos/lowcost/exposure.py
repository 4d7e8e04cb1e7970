"""Exposure times from a photoresistor (or flash-sync) channel, matched to triggers and image files (seed 000, 3.2).

The photoresistor behind an SLR viewfinder sees the view blacked out while the mirror is up;
its signal is a first-order response (time constant tau) to that rectangular blackout. The seed
takes each spike's peak as the exposure time; the peak is the END of the blackout, so dgcal fits
the first-order pulse model to every spike and returns the blackout centre (`t_exposure`),
keeping the seed's peak time (`t_peak`) beside it.

Image files are paired with spikes in order when the counts agree, or by the camera clock (EXIF
times, which mark storage, not exposure): its offset and rate against GPS time are found robustly and
an image takes a spike only when each is the other's nearest within a tolerance set by the residual
spread, so an image whose spike is missing is listed as unmatched instead of taking a neighbour's.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import median_filter
from scipy.optimize import least_squares
from scipy.signal import find_peaks

from dgcal.fields.errors import InputError, ResultError


def pulse_response(t: np.ndarray, t_center: float, duration: float, tau: float) -> np.ndarray:
    """First-order (time constant tau, s) response to a unit pulse of `duration` s centred at `t_center` (s)."""
    t0, t1 = t_center - duration / 2, t_center + duration / 2
    t = np.asarray(t, float)
    rise = 1 - np.exp(-np.clip(t - t0, 0, None) / tau)
    fall = (1 - np.exp(-duration / tau)) * np.exp(-np.clip(t - t1, 0, None) / tau)
    return np.where(t < t0, 0.0, np.where(t < t1, rise, fall))


def pulse_response_dt(t: np.ndarray, t_center: float, duration: float, tau: float) -> np.ndarray:
    """Derivative (1/s) of `pulse_response` with respect to the pulse centre `t_center` (s)."""
    t0, t1 = t_center - duration / 2, t_center + duration / 2
    t = np.asarray(t, float)
    rise = -np.exp(-np.clip(t - t0, 0, None) / tau) / tau
    fall = (1 - np.exp(-duration / tau)) * np.exp(-np.clip(t - t1, 0, None) / tau) / tau
    return np.where(t < t0, 0.0, np.where(t < t1, rise, fall))


@dataclass
class Spikes:
    """Detected exposure spikes: fitted blackout centre (s), the seed's peak time (s), blackout length (s),
    amplitude (signal units), fit RMS (signal units), sigma of the centre (s); `noise` is the channel's
    robust noise level (signal units) the fits are judged against."""

    t_exposure: np.ndarray
    t_peak: np.ndarray
    duration: np.ndarray
    amplitude: np.ndarray
    fit_rms: np.ndarray
    sigma_t: np.ndarray
    noise: float = float("nan")

    def __len__(self) -> int:
        return len(self.t_exposure)


def detect_spikes(t: np.ndarray, signal: np.ndarray, tau: float = 0.05, blackout_s: float = 0.06,
                  polarity: int = 0, min_interval_s: float = 0.15, threshold_sigma: float = 8.0) -> Spikes:
    """Find exposure spikes in a photoresistor channel sampled at times `t` (s) and fit each one.

    `tau` (s) is the sensor's time constant and `blackout_s` the camera's mirror-up time, both
    calibrated once on the bench (seed Fig. 12-13): for a blackout much shorter than tau the spike's
    shape fixes its END sharply but not its length, so the length is not fitted per spike.
    `polarity` +1 for spikes upwards, -1 downwards, 0 to take the sign of the largest excursion.
    Spikes closer than a few time constants are fitted jointly on a quadratic baseline.
    """
    t = np.asarray(t, float)
    x = np.asarray(signal, float)
    if len(t) < 5:
        raise InputError(f"only {len(t)} light-sensor samples", field="photo")
    dt = float(np.median(np.diff(t)))
    base = median_filter(x, size=max(3, int(round(3.0 / dt)) | 1), mode="nearest")
    r = x - base
    noise = 1.4826 * np.median(np.abs(r - np.median(r))) + 1e-12
    if polarity == 0:
        polarity = 1 if r.max() >= -r.min() else -1
    peaks, props = find_peaks(polarity * r, height=threshold_sigma * noise, prominence=threshold_sigma * noise,
                              distance=max(1, int(min_interval_s / dt)))
    if len(peaks):  # wiggles on a spike's tail are not spikes: keep the prominent ones
        peaks = peaks[props["prominences"] > 0.3 * np.median(props["prominences"])]
    peaks = peaks[(peaks > 0) & (peaks < len(t) - 1)]
    out = {k: np.full(len(peaks), np.nan) for k in ("t_exposure", "t_peak", "duration", "amplitude", "fit_rms",
                                                     "sigma_t")}
    # a group's window (2 tau + 0.3 s before its first spike, 5 tau after its last) must not hold another's spike
    cuts = np.nonzero(np.diff(t[peaks]) > 8 * tau + blackout_s + 0.3)[0] + 1
    for group in np.split(np.arange(len(peaks)), cuts):
        if len(group):
            _fit_group(t, x, r, base, peaks[group], group, out, tau, blackout_s, polarity, noise, dt)
    return Spikes(**out, noise=float(noise))


def _fit_group(t, x, r, base, kk, group, out, tau, blackout_s, polarity, noise, dt) -> None:
    """Fit one cluster of overlapping spikes (peak samples `kk`) jointly; results into `out[...][group]`."""
    w = (t > t[kk[0]] - 2 * tau - 0.3) & (t < t[kk[-1]] + 5 * tau)
    tmid = 0.5 * (t[w][0] + t[w][-1])
    tw, xw = t[w] - tmid, polarity * x[w]  # window-relative times: GPS seconds (~1e9) would swamp xtol
    n = len(kk)

    def model(p):
        y = p[2 * n] + tw * (p[2 * n + 1] + p[2 * n + 2] * tw)
        for j in range(n):
            y = y + p[2 * j + 1] * pulse_response(tw, p[2 * j], blackout_s, tau)
        return y

    def jac(p):
        J = np.empty((len(tw), 2 * n + 3))
        for j in range(n):
            J[:, 2 * j] = p[2 * j + 1] * pulse_response_dt(tw, p[2 * j], blackout_s, tau)
            J[:, 2 * j + 1] = pulse_response(tw, p[2 * j], blackout_s, tau)
        J[:, 2 * n], J[:, 2 * n + 1], J[:, 2 * n + 2] = 1.0, tw, tw * tw
        return J

    amp0 = polarity * r[kk] / (1 - np.exp(-blackout_s / tau))
    tk = t[kk] - tmid
    p0 = np.r_[np.column_stack([tk - blackout_s / 2, amp0]).ravel(), np.median(polarity * base[w]), 0.0, 0.0]
    lo = np.r_[np.column_stack([tk - blackout_s / 2 - 2 * dt, np.zeros(n)]).ravel(), -np.inf, -np.inf, -np.inf]
    hi = np.r_[np.column_stack([tk - blackout_s / 2 + 2 * dt, np.full(n, np.inf)]).ravel(), np.inf, np.inf, np.inf]
    p0 = np.clip(p0, lo + 1e-12, hi - 1e-12)
    sol = least_squares(lambda p: model(p) - xw, p0, jac=lambda p: jac(p), bounds=(lo, hi),
                        x_scale=np.r_[np.tile([0.01, np.median(np.abs(amp0)) + 1e-9], n), noise, noise, noise])
    dof = max(1, len(tw) - len(p0))
    s2 = float(sol.fun @ sol.fun) / dof
    J = jac(sol.x)
    try:
        sig = np.sqrt(np.diag(s2 * np.linalg.pinv(J.T @ J))[0:2 * n:2])
    except np.linalg.LinAlgError:
        sig = np.full(n, np.nan)
    out["t_exposure"][group] = tmid + sol.x[0:2 * n:2]
    out["amplitude"][group] = polarity * sol.x[1:2 * n:2]
    out["duration"][group] = blackout_s
    out["fit_rms"][group] = np.sqrt(s2)
    out["sigma_t"][group] = sig
    # the seed's estimate: the sample extreme refined by a parabola through its neighbours
    y0, y1, y2 = polarity * r[kk - 1], polarity * r[kk], polarity * r[np.minimum(kk + 1, len(r) - 1)]
    den = y0 - 2 * y1 + y2
    out["t_peak"][group] = t[kk] + np.where(den < 0, 0.5 * (y0 - y2) / np.where(den < 0, den, 1) * dt, 0.0)


@dataclass
class TriggerMatch:
    """Each trigger's spike (index or -1 if the camera skipped it), lags (s) of the matched ones, unmatched spikes."""

    spike_of_trigger: np.ndarray
    lag_s: np.ndarray
    skipped: np.ndarray
    unmatched_spikes: np.ndarray

    def lag_stats(self) -> dict[str, float]:
        """Shutter-lag statistics (s) of the matched triggers."""
        lag = self.lag_s[np.isfinite(self.lag_s)]
        if not len(lag):
            return {"n": 0}
        return {"n": int(len(lag)), "mean": float(lag.mean()), "std": float(lag.std(ddof=1) if len(lag) > 1 else 0.0),
                "min": float(lag.min()), "max": float(lag.max()), "median": float(np.median(lag))}


def match_triggers(t_trigger: np.ndarray, t_spike: np.ndarray, max_lag_s: float = 2.0) -> TriggerMatch:
    """Pair spikes with the trigger commands that caused them: each spike takes the latest trigger before it.

    A trigger whose next spike is claimed by a later trigger was skipped by the camera.
    """
    t_trigger, t_spike = np.asarray(t_trigger, float), np.asarray(t_spike, float)
    owner = np.searchsorted(t_trigger, t_spike, side="right") - 1
    lag = t_spike - t_trigger[np.clip(owner, 0, None)] if len(t_trigger) else np.full(len(t_spike), np.nan)
    ok = (owner >= 0) & (lag >= 0) & (lag <= max_lag_s)
    spike_of = np.full(len(t_trigger), -1)
    lags = np.full(len(t_trigger), np.nan)
    for j in np.nonzero(ok)[0]:
        i = owner[j]
        if spike_of[i] < 0:  # two spikes after one trigger: keep the first, the second is unmatched
            spike_of[i], lags[i] = j, lag[j]
    matched = np.zeros(len(t_spike), bool)
    matched[spike_of[spike_of >= 0]] = True
    return TriggerMatch(spike_of, lags, np.nonzero(spike_of < 0)[0], np.nonzero(~matched)[0])


@dataclass
class ImageMatch:
    """Images paired with spikes: `spike_of_image` (index or -1), the unmatched images and spikes, and how the
    pairing was made (`method` 'order' or 'camera clock', with the clock's offset (s), rate error and the
    residual spread (s, 95th percentile of |residual|) against the spacing of the spikes (s))."""

    images: list[str]
    spike_of_image: np.ndarray
    method: str
    clock_offset_s: float = float("nan")
    clock_rate: float = 0.0
    residual_spread_s: float = float("nan")
    tolerance_s: float = float("nan")
    min_spacing_s: float = float("nan")
    residual_s: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def pairs(self) -> list[tuple[str, int]]:
        """(image, spike index) of the matched images, in image order."""
        return [(n, int(j)) for n, j in zip(self.images, self.spike_of_image) if j >= 0]

    @property
    def unmatched_images(self) -> list[str]:
        """Images with no spike."""
        return [n for n, j in zip(self.images, self.spike_of_image) if j < 0]

    def unmatched_spikes(self, n_spikes: int) -> np.ndarray:
        """Indices of spikes with no image."""
        used = np.zeros(n_spikes, bool)
        used[self.spike_of_image[self.spike_of_image >= 0]] = True
        return np.nonzero(~used)[0]


def _pair_at_offset(ti: np.ndarray, ts: np.ndarray, off: float, tol: float) -> dict:
    """Mutual-nearest, order-keeping pairs of camera times `ti` with spike times `ts` (s) around the clock offset
    `off` (s), with the clock offset and rate refined on the pairs; figures of the pairing."""
    ts0 = float(np.median(ts))
    rate = 0.0
    for _ in range(3):
        pred = off + (1 + rate) * (ts - ts0) + ts0
        r_all = ti[:, None] - pred[None, :]
        j = np.argmin(np.abs(r_all), axis=1)
        res = r_all[np.arange(len(ti)), j]
        inl = np.abs(res - np.median(res)) < tol
        if inl.sum() >= 5 and np.ptp(ts[j[inl]]) > 0:
            A = np.column_stack([np.ones(inl.sum()), ts[j[inl]] - ts0])
            off, rate = (float(c) for c in np.linalg.lstsq(A, ti[inl] - ts[j[inl]], rcond=None)[0])
        elif inl.any():
            off += float(np.median(res[inl]))
    pred = off + (1 + rate) * (ts - ts0) + ts0
    r_all = ti[:, None] - pred[None, :]
    j_near = np.argmin(np.abs(r_all), axis=1)
    i_near = np.argmin(np.abs(r_all), axis=0)
    res = r_all[np.arange(len(ti)), j_near]
    mutual = i_near[j_near] == np.arange(len(ti))
    core = mutual & (np.abs(res) < tol)
    med = float(np.median(res[core])) if core.any() else 0.0
    # spread: the 95th percentile of |residual| (storage delays are bounded, often uniform, rarely Gaussian)
    spread = float(np.percentile(np.abs(res[core] - med), 95)) if core.sum() >= 3 else np.inf
    tol_use = min(tol, max(1.5 * spread, 0.02))
    spike_of = np.where(mutual & (np.abs(res - med) < tol_use), j_near, -1)
    last = -1
    for i in range(len(spike_of)):  # keep the order: a pair that runs backwards is not trusted
        if spike_of[i] >= 0:
            if spike_of[i] <= last:
                spike_of[i] = -1
            else:
                last = spike_of[i]
    return {"spike_of": spike_of, "n": int((spike_of >= 0).sum()), "off": float(off), "rate": float(rate),
            "spread": spread, "tol": float(tol_use), "res": np.where(spike_of >= 0, res, np.nan),
            "core": int(core.sum()), "all_spread": float(np.percentile(np.abs(res - med), 95))}


def pair_images(images: list[str], t_spike: np.ndarray, t_image_clock: np.ndarray | None = None,
                max_tolerance_s: float = 1.0) -> ImageMatch:
    """Pair image files (shooting order) with spikes (GPS s): in order when there are no camera times (the counts
    must agree), else by the camera clock (s, any origin): every clock offset the image-minus-spike differences
    favour is tried (with the clock rate refined), each giving mutual-nearest pairs within 1.5 residual spreads
    (95th percentile; at most `max_tolerance_s` and 45 % of the spike spacing), and the offset pairing the most
    images wins. A regular burst shifted by one frame pairs all but its ends, so the winner must pair clearly
    more images than any other offset.

    Raises ResultError ('images-vs-spikes') when the pairing cannot be trusted: counts differ without camera
    times, the camera clock's residual spread is too large for the spacing of the exposures, or another offset
    pairs nearly as many images (when the counts agree the images are then paired in order, `method` says so).
    """
    t_spike = np.asarray(t_spike, float)
    images = list(images)
    gaps = np.diff(np.sort(t_spike))
    spacing = float(gaps.min()) if len(gaps) else np.inf
    if t_image_clock is None or not np.all(np.isfinite(np.asarray(t_image_clock, float))):
        if len(images) != len(t_spike):
            raise ResultError(f"check 'images-vs-spikes' failed: {len(images)} images but {len(t_spike)} exposure "
                              "spikes and no camera times (EXIF, images CSV camera_time_s) to pair them",
                              field="images")
        return ImageMatch(images, np.arange(len(images)), "order", min_spacing_s=spacing)
    ti = np.asarray(t_image_clock, float)
    if len(ti) != len(images):
        raise InputError(f"{len(ti)} camera times for {len(images)} images", field="camera_time_s")
    if not len(t_spike) or not len(ti):
        return ImageMatch(images, np.full(len(images), -1), "camera clock", min_spacing_s=spacing)
    tol = min(max_tolerance_s, 0.45 * spacing)
    # candidate offsets: peaks of the histogram of all image-minus-spike differences
    d = (ti[:, None] - t_spike[None, :]).ravel()
    h = min(0.1, 0.2 * spacing) if np.isfinite(spacing) else 0.1
    ub, cnt = np.unique(np.floor(d / h).astype(np.int64), return_counts=True)
    full = np.zeros(int(ub[-1] - ub[0]) + 3)
    full[ub - ub[0] + 1] = cnt
    c3 = full[:-2] + full[1:-1] + full[2:]
    order = np.argsort(c3)[::-1]
    cands: list[float] = []
    for k in order[:200]:
        if c3[k] < 0.3 * c3[order[0]] or len(cands) >= 12:
            break
        o = (ub[0] + k + 0.5) * h
        if all(abs(o - c) > tol for c in cands):
            cands.append(o)
    tried = sorted((_pair_at_offset(ti, t_spike, o, tol) for o in cands),
                   key=lambda r: (-r["n"], r["spread"]))
    best = tried[0]
    rivals = [r for r in tried[1:] if abs(r["off"] - best["off"]) > tol]
    rival = max((r["n"] for r in rivals), default=0)
    n_min = max(min(len(ti), len(t_spike)), 1)
    margin = max(2, int(np.ceil(0.03 * n_min)))
    ambiguous = (not np.isfinite(best["spread"]) or best["spread"] > 0.4 * spacing
                 or best["core"] < 0.8 * n_min or rival > best["n"] - margin)
    if ambiguous:
        if len(images) == len(t_spike):  # counts agree: shooting order, the camera clock only unhelpful
            return ImageMatch(images, np.arange(len(images)), "order (camera clock too coarse)", best["off"],
                              best["rate"], best["spread"], min_spacing_s=spacing)
        raise ResultError(f"check 'images-vs-spikes' failed: the camera clock pairs {best['n']} of {len(ti)} images "
                          f"(another offset {rival}) within {best['tol']:.2f} s of an exposure (residual spread "
                          f"{best['all_spread']:.3f} s against {spacing:.3f} s between exposures): ambiguous "
                          "(whole-second EXIF times?)", field="camera_time_s")
    return ImageMatch(images, best["spike_of"], "camera clock", best["off"], best["rate"], best["spread"],
                      best["tol"], spacing, best["res"])


def match_images(images: list[str], t_spike: np.ndarray, t_image_clock: np.ndarray | None = None,
                 tolerance_s: float = 1.0) -> list[tuple[str, int]]:
    """Pair image files (in shooting order) with spikes; returns (image, spike index) pairs (see `pair_images`).

    Without image clock times the counts must agree. With them (e.g. EXIF times, which mark storage,
    not exposure) images whose spike is missing are left out rather than paired with a neighbour's.
    """
    return pair_images(images, t_spike, t_image_clock, tolerance_s).pairs
