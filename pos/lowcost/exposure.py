"""Exposure times from a photoresistor (or flash-sync) channel, matched to triggers and image files (seed 000, 3.2).

The photoresistor behind an SLR viewfinder sees the view blacked out while the mirror is up;
its signal is a first-order response (time constant tau) to that rectangular blackout. The seed
takes each spike's peak as the exposure time; the peak is the END of the blackout, so dgcal fits
the first-order pulse model to every spike and returns the blackout centre (`t_exposure`),
keeping the seed's peak time (`t_peak`) beside it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import median_filter
from scipy.optimize import least_squares
from scipy.signal import find_peaks

from dgcal.fields.errors import InputError


def pulse_response(t: np.ndarray, t_center: float, duration: float, tau: float) -> np.ndarray:
    """First-order (time constant tau, s) response to a unit pulse of `duration` s centred at `t_center` (s)."""
    t0, t1 = t_center - duration / 2, t_center + duration / 2
    t = np.asarray(t, float)
    rise = 1 - np.exp(-np.clip(t - t0, 0, None) / tau)
    fall = (1 - np.exp(-duration / tau)) * np.exp(-np.clip(t - t1, 0, None) / tau)
    return np.where(t < t0, 0.0, np.where(t < t1, rise, fall))


@dataclass
class Spikes:
    """Detected exposure spikes: fitted blackout centre (s), the seed's peak time (s), blackout length, amplitude, fit RMS, sigma of the centre (s)."""

    t_exposure: np.ndarray
    t_peak: np.ndarray
    duration: np.ndarray
    amplitude: np.ndarray
    fit_rms: np.ndarray
    sigma_t: np.ndarray


def detect_spikes(t: np.ndarray, signal: np.ndarray, tau: float = 0.05, blackout_s: float = 0.06,
                  polarity: int = 0, min_interval_s: float = 0.15, threshold_sigma: float = 8.0) -> Spikes:
    """Find exposure spikes in a photoresistor channel sampled at times `t` (s) and fit each one.

    `tau` (s) is the sensor's time constant and `blackout_s` the camera's mirror-up time, both
    calibrated once on the bench (seed Fig. 12-13): for a blackout much shorter than tau the spike's
    shape fixes its END sharply but not its length, so the length is not fitted per spike.
    `polarity` +1 for spikes upwards, -1 downwards, 0 to take the sign of the largest excursion.
    """
    t = np.asarray(t, float)
    x = np.asarray(signal, float)
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
    out = {k: np.full(len(peaks), np.nan) for k in ("t_exposure", "t_peak", "duration", "amplitude", "fit_rms",
                                                     "sigma_t")}
    # spikes closer than a few time constants overlap: fit each cluster jointly, on a quadratic baseline (light changes)
    cuts = np.nonzero(np.diff(t[peaks]) > 6 * tau + blackout_s)[0] + 1
    for group in np.split(np.arange(len(peaks)), cuts):
        if not len(group):
            continue
        kk = peaks[group]
        w = (t > t[kk[0]] - 2 * tau - 0.3) & (t < t[kk[-1]] + 5 * tau)
        tw, xw = t[w], polarity * x[w]
        tmid = 0.5 * (tw[0] + tw[-1])
        n = len(kk)

        def model(p, tw=tw, n=n, tmid=tmid):
            y = p[2 * n] + (tw - tmid) * (p[2 * n + 1] + p[2 * n + 2] * (tw - tmid))
            for j in range(n):
                y = y + p[2 * j + 1] * pulse_response(tw, p[2 * j], blackout_s, tau)
            return y

        amp0 = polarity * r[kk] / (1 - np.exp(-blackout_s / tau))
        p0 = np.r_[np.column_stack([t[kk] - blackout_s / 2, amp0]).ravel(), np.median(polarity * base[w]), 0.0, 0.0]
        lo = np.r_[np.column_stack([t[kk] - blackout_s / 2 - 2 * dt, np.zeros(n)]).ravel(), -np.inf, -np.inf, -np.inf]
        hi = np.r_[np.column_stack([t[kk] - blackout_s / 2 + 2 * dt, np.full(n, np.inf)]).ravel(), np.inf, np.inf, np.inf]
        sol = least_squares(lambda p: model(p) - xw, p0, bounds=(lo, hi),
                            x_scale=np.r_[np.tile([0.01, np.median(np.abs(amp0)) + 1e-9], n), noise, noise, noise])
        dof = max(1, len(tw) - len(p0))
        s2 = float(sol.fun @ sol.fun) / dof
        try:
            cov = s2 * np.linalg.pinv(sol.jac.T @ sol.jac)
            sig = np.sqrt(np.diag(cov)[0:2 * n:2])
        except np.linalg.LinAlgError:
            sig = np.full(n, np.nan)
        out["t_exposure"][group] = sol.x[0:2 * n:2]
        out["amplitude"][group] = polarity * sol.x[1:2 * n:2]
        out["duration"][group] = blackout_s
        out["fit_rms"][group] = np.sqrt(s2)
        out["sigma_t"][group] = sig
        # the seed's estimate: the sample extreme refined by a parabola through its neighbours
        y0, y1, y2 = polarity * r[kk - 1], polarity * r[kk], polarity * r[np.minimum(kk + 1, len(r) - 1)]
        den = y0 - 2 * y1 + y2
        out["t_peak"][group] = t[kk] + np.where(den < 0, 0.5 * (y0 - y2) / np.where(den < 0, den, 1) * dt, 0.0)
    return Spikes(**out)


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
    lag = t_spike - t_trigger[np.clip(owner, 0, None)]
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


def match_images(images: list[str], t_spike: np.ndarray, t_image_clock: np.ndarray | None = None,
                 tolerance_s: float = 1.0) -> list[tuple[str, int]]:
    """Pair image files (in shooting order) with spikes; returns (image, spike index) pairs.

    Without image clock times the counts must agree. With them (e.g. EXIF times, which mark storage,
    not exposure) the constant clock offset is found robustly and each image takes the spike nearest
    its corrected time (within `tolerance_s`), keeping the order.
    """
    t_spike = np.asarray(t_spike, float)
    if t_image_clock is None:
        if len(images) != len(t_spike):
            raise InputError(f"{len(images)} images but {len(t_spike)} exposure spikes; give image times "
                             "(EXIF) to match them", field="images")
        return list(zip(images, range(len(t_spike))))
    ti = np.asarray(t_image_clock, float)
    # candidate offsets: every image/spike pair; keep the one that explains most images
    cand = (ti[:, None] - t_spike[None, :]).ravel()
    score = [(np.abs(ti[:, None] - c - t_spike[None, :]).min(axis=1) < tolerance_s / 2).sum() for c in cand]
    off = cand[int(np.argmax(score))]
    near = np.abs(ti[:, None] - off - t_spike[None, :])
    inl = near.min(axis=1) < tolerance_s / 2
    off = np.median((ti - t_spike[near.argmin(axis=1)])[inl])
    pairs, last = [], -1
    for i, name in enumerate(images):
        j = int(np.argmin(np.abs(ti[i] - off - t_spike)))
        if abs(ti[i] - off - t_spike[j]) < tolerance_s and j > last:
            pairs.append((name, j))
            last = j
    return pairs
