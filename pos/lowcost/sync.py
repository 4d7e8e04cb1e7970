"""Seed 000's time synchronisation end to end, checked at every stage: restore both streams, fit the logger
clock to its PPS, take the whole second from a coarse alignment (laser / baro against the GNSS height, GNSS
time the logger received, or stream ends within a declared gap), find the exposures, match triggers and image
files, and produce an events table — or stop with the check that failed.

Checks (name: what is compared; a failure raises `dgcal.fields.errors.ResultError` naming it):
- `gnss-packets`, `logger-packets`: lost packets against the record (warn > 5 %, fail > 50 %);
- `pps-edges`: PPS rising edges found against those the fitted clock expects, and edges that fit no second;
- `clock-fit`: edge residuals against the sampling interval (every edge inside its two samples, or within one
  sample by least squares);
- `drift`: the crystal's drift against its plausible range (`max_drift_ppm`);
- `coarse-alignment`: the coarse figure's bound against the 0.45 s needed to pick the whole second;
- `coarse-vs-pps`: coarse minus PPS time after the whole second, against the coarse bound (the PPS fit
  contradicts the coarse alignment otherwise); and stream ends against a laser/baro alignment when both exist;
- `clock-bound`: the clock's error bound over the record against `max_time_error_s`;
- `spike-fit`: the pulse model's fit RMS against the light channel's noise (wrong `tau` / `blackout`);
- `exposure-precision`: clock bound + 3 sigma of every exposure against `max_time_error_s` (imprecise ones
  are listed as unmatched; fail when more than a fifth of the images are);
- `spikes-vs-triggers`: spikes with no trigger before them (false detections);
- `images-vs-spikes`: pairing of image files and spikes (order, or the camera clock), unmatched images listed.
"""
from __future__ import annotations

import datetime
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image
from threadpoolctl import threadpool_limits

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.errors import InputError, ResultError
from dgcal.fields.io.csv_tables import read_table
from dgcal.fields.io import validate
from dgcal.fields.io.formats import Events
from dgcal.pos.lowcost.exposure import ImageMatch, Spikes, TriggerMatch, detect_spikes, pair_images, match_triggers
from dgcal.pos.lowcost.logger_format import (LENGTH_UNITS, LoggerFormat, read_gnss_log, read_logger,
                                            read_logger_format)
from dgcal.pos.lowcost.stream_align import (ClockFit, CoarseAlignment, coarse_by_correlation, coarse_by_ends,
                                            coarse_by_time_tags, fit_pps_clock, resolve_whole_seconds)
from dgcal.fields.io.image_folders import list_image_files
from dgcal.pos.lowcost.time_axis import RestoredAxis, restore_from_counter, restore_from_time_tags


@dataclass
class Check:
    """One stage's evidence: `name`, `status` ('pass', 'warn', 'fail'), the `figure` found and the `limit` it was
    held against (text), and a one-line `message`."""

    name: str
    status: str
    figure: str
    limit: str
    message: str = ""

    def as_dict(self) -> dict:
        """JSON-ready."""
        return {"name": self.name, "status": self.status, "figure": self.figure, "limit": self.limit,
                "message": self.message}


class Checks(list):
    """The checks of one run, in order; `fail` records a failure and raises ResultError naming it."""

    def add(self, name: str, status: str, figure: str, limit: str, message: str = "") -> Check:
        """Record a check and return it."""
        c = Check(name, status, figure, limit, message)
        self.append(c)
        return c

    def fail(self, name: str, figure: str, limit: str, message: str, field: str | None = None):
        """Record a failed check and raise ResultError with its one-line message."""
        self.add(name, "fail", figure, limit, message)
        raise ResultError(f"check '{name}' failed: {message}", field=field)

    @property
    def warnings(self) -> list[str]:
        """Messages of the checks that warned."""
        return [f"{c.name}: {c.message}" for c in self if c.status == "warn"]


@dataclass
class SyncResult:
    """Everything the synchronisation found; `events` is ready for `dgcal.fields.io.formats.write_events`."""

    gnss_axis: RestoredAxis
    logger_axis: RestoredAxis
    clock: ClockFit
    spikes: Spikes
    triggers: TriggerMatch | None
    events: Events
    t_logger_gps: np.ndarray      # GPS time of every restored logger slot (s)
    gnss_h: np.ndarray | None      # GNSS height on the restored GNSS axis (m)
    laser: np.ndarray | None       # laser range (or baro height) on the restored logger axis (m)
    coarse: CoarseAlignment | None = None
    coarse_figures: dict = field(default_factory=dict)
    image_match: ImageMatch | None = None
    checks: Checks = field(default_factory=Checks)
    event_sigma_s: np.ndarray = field(default_factory=lambda: np.zeros(0))   # exposure sigma of each event (s)
    event_bound_s: np.ndarray = field(default_factory=lambda: np.zeros(0))   # clock bound + 3 sigma (s)
    event_spike: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    unmatched: dict = field(default_factory=dict)   # image -> reason
    n_images: int = 0

    def summary(self) -> dict:
        """Figures for reports and JSON output."""
        ms = self.image_match.unmatched_spikes(len(self.spikes.t_exposure)) if self.image_match else []
        return {
            "gnss_lost_packets": self.gnss_axis.n_lost, "gnss_gaps": len(self.gnss_axis.gaps()),
            "logger_lost_packets": self.logger_axis.n_lost,
            "clock_offset_s": self.clock.offset_s, "clock_drift": self.clock.drift,
            "clock_drift_ppm": self.clock.drift * 1e6,
            "clock_max_error_s": self.clock.max_error_s, "pps_edges": self.clock.n_edges,
            "pps_edges_expected": self.clock.n_expected, "pps_edges_spurious": self.clock.n_spurious,
            "clock_residual_rms_s": self.clock.residual_rms_s, "clock_residual_max_s": self.clock.residual_max_s,
            "coarse_alignment": self.coarse_figures,
            "n_exposures": int(len(self.spikes.t_exposure)),
            "exposure_sigma_s_median": (float(np.nanmedian(self.spikes.sigma_t)) if len(self.spikes.t_exposure)
                                        else None),
            "skipped_triggers": [] if self.triggers is None else [int(i) for i in self.triggers.skipped],
            "shutter_lag_s": None if self.triggers is None else self.triggers.lag_stats(),
            "n_images": int(self.n_images), "n_events": len(self.events),
            "image_pairing": None if self.image_match is None else self.image_match.method,
            "unmatched_images": [{"image": k, "reason": v} for k, v in self.unmatched.items()],
            "unmatched_spikes_gps_s": [float(self.spikes.t_exposure[j]) for j in ms],
            "event_time_bound_s_max": float(np.max(self.event_bound_s)) if len(self.event_bound_s) else None,
            "checks": [c.as_dict() for c in self.checks],
            "warnings": self.checks.warnings,
        }


@dataclass
class SyncSettings:
    """Settings of the synchronisation: logger and GNSS rates (Hz), counter width (bits, None = no wrap), light
    sensor time constant and blackout (s) and polarity, PPS inversion, the declared bound on how far apart the
    recorders stopped (s, None = unknown), the coarse search range (s), the plausible crystal drift (ppm), the
    time error the events must meet (s) and the longest trigger-to-exposure lag (s)."""

    rate_hz: float = 50.0
    gnss_rate_hz: float | None = None
    counter_bits: int | None = 16
    tau: float = 0.05
    blackout_s: float = 0.06
    photo_polarity: int = 0
    pps_inverted: bool = False
    end_gap_s: float | None = None
    search_s: float | None = None
    max_drift_ppm: float = 200.0
    max_time_error_s: float = 0.005
    max_lag_s: float = 2.0


def _packets_check(checks: Checks, name: str, ax: RestoredAxis) -> None:
    frac = ax.n_lost / max(len(ax.t), 1)
    fig, lim = f"{ax.n_lost} of {len(ax.t)} lost ({100 * frac:.1f} %)", "warn > 5 %, fail > 50 %"
    if frac > 0.5:
        checks.fail(name, fig, lim, f"{fig}: the record is mostly gaps")
    checks.add(name, "warn" if frac > 0.05 else "pass", fig, lim,
               f"{fig} packets" if frac > 0.05 else "")


def synchronise(gnss_t: np.ndarray, logger_counter: np.ndarray, pps: np.ndarray, photo: np.ndarray,
                images: list[str], rate_hz: float = 50.0, gnss_rate_hz: float | None = None,
                counter_bits: int | None = 16, trigger: np.ndarray | None = None,
                image_clock: np.ndarray | None = None, tau: float = 0.05, blackout_s: float = 0.06,
                gnss_h: np.ndarray | None = None, laser: np.ndarray | None = None, baro: np.ndarray | None = None,
                logger_gps_time: np.ndarray | None = None, settings: SyncSettings | None = None) -> SyncResult:
    """Synchronise a GNSS stream (GPS time tags, s) and a logger stream (counter, PPS, photoresistor) into events.

    `settings` (SyncSettings) overrides the rate / counter / tau / blackout arguments. Raises ResultError naming
    the check that failed when the result cannot be trusted (see the module documentation).
    """
    st = settings or SyncSettings(rate_hz=rate_hz, gnss_rate_hz=gnss_rate_hz, counter_bits=counter_bits, tau=tau,
                                  blackout_s=blackout_s)
    with threadpool_limits(1):  # small matrices: BLAS threads only cost
        return _synchronise(gnss_t, logger_counter, pps, photo, images, trigger, image_clock, gnss_h, laser, baro,
                            logger_gps_time, st)


def _synchronise(gnss_t, logger_counter, pps, photo, images, trigger, image_clock, gnss_h, laser, baro,
                 logger_gps_time, st: SyncSettings) -> SyncResult:
    """The stages of `synchronise` with its settings resolved."""
    checks = Checks()
    dt = 1.0 / st.rate_hz
    g_ax = restore_from_time_tags(gnss_t, 1.0 / (st.gnss_rate_hz or st.rate_hz))
    l_ax = restore_from_counter(logger_counter, dt, bits=st.counter_bits)
    _packets_check(checks, "gnss-packets", g_ax)
    _packets_check(checks, "logger-packets", l_ax)
    _coverage_check(checks, g_ax, l_ax)
    rec = ~l_ax.filled
    # 1. the PPS: drift and sub-second phase
    clock = fit_pps_clock(l_ax.t, l_ax.fill(pps), valid=rec, inverted=st.pps_inverted, dt_s=dt,
                          max_drift=st.max_drift_ppm * 1e-6)
    _pps_checks(checks, clock, st, dt)
    # 2. the whole second
    clock, coarse, figs, sig_val = _whole_second(checks, st, clock, g_ax, l_ax, rec, gnss_h, laser, baro,
                                                 logger_gps_time, dt)
    t_gps = clock.to_gps(l_ax.t)
    # 3. exposures
    spikes, trig = _exposures(checks, st, t_gps, l_ax, rec, photo, trigger)
    # 4. images
    images = list(images)
    match = pair_images(images, spikes.t_exposure, image_clock)
    unmatched = {n: "no exposure spike" for n in match.unmatched_images}
    pairs = match.pairs
    sig = np.array([spikes.sigma_t[j] for _, j in pairs]) if pairs else np.zeros(0)
    bound = clock.max_error_s + 3 * np.nan_to_num(sig, nan=np.inf)
    good = bound <= st.max_time_error_s
    for (n, _), b in zip(pairs, bound):
        if not b <= st.max_time_error_s:
            unmatched[n] = f"exposure time uncertain: +-{b * 1e3:.1f} ms"
    n_bad = int((~good).sum())
    fig = (f"{n_bad} of {len(pairs)} exposure times beyond {st.max_time_error_s * 1e3:.1f} ms"
           + (f" (worst +-{bound.max() * 1e3:.1f} ms)" if len(bound) else ""))
    if len(images) and n_bad > 0.2 * len(images):
        checks.fail("exposure-precision", fig, "<= 20 % of the images",
                    f"{fig}: a slow or noisy light sensor (--tau?) or too little of each spike recorded")
    checks.add("exposure-precision", "warn" if n_bad else "pass", fig, "<= 20 % of the images")
    n_um = len(match.unmatched_images)
    fig = (f"{len(images) - n_um} of {len(images)} images paired ({match.method}), "
           f"{len(match.unmatched_spikes(len(spikes)))} spikes without an image")
    if len(images) and len(images) - n_um < 0.5 * len(images):
        checks.fail("images-vs-spikes", fig, ">= 50 % paired", f"{fig}: wrong image folder or camera clock?")
    coarse_clock = match.method.startswith("order (")
    msg = (f"unmatched: {', '.join(match.unmatched_images[:10])}" + (" ..." if n_um > 10 else "")) if n_um else ""
    if coarse_clock:
        msg = (f"the camera clock is too coarse ({match.residual_spread_s:.2f} s spread) to check the pairing; "
               "paired in shooting order" + ("; " + msg if msg else ""))
    checks.add("images-vs-spikes", "warn" if n_um or coarse_clock else "pass", fig, ">= 50 % paired", msg)
    keep = [i for i, ok in enumerate(good) if ok]
    ev = Events(np.array([pairs[i][0] for i in keep], dtype=object),
                np.array([spikes.t_exposure[pairs[i][1]] for i in keep], float))
    h_l = sig_val if sig_val is not None else None
    return SyncResult(g_ax, l_ax, clock, spikes, trig, ev, t_gps,
                      None if gnss_h is None else g_ax.fill(gnss_h), None if h_l is None else l_ax.fill(h_l),
                      coarse, figs, match, checks, sig[keep], bound[keep],
                      np.array([pairs[i][1] for i in keep], int), unmatched, len(images))


MIN_GNSS_COVERAGE = 0.5        # share of the logger's span the GNSS log must cover to fix the whole second


def _coverage_check(checks: Checks, g_ax: RestoredAxis, l_ax: RestoredAxis) -> None:
    """The GNSS log must cover most of the logger's record: a few rows cannot fix the whole second (a log cut to
    10 rows moved every event by minutes)."""
    g_span = float(g_ax.t[-1] - g_ax.t[0]) if len(g_ax.t) > 1 else 0.0
    l_span = float(l_ax.t[-1] - l_ax.t[0]) if len(l_ax.t) > 1 else 0.0
    fig = f"GNSS log {g_span:.1f} s of the logger's {l_span:.1f} s"
    if l_span > 0 and g_span < MIN_GNSS_COVERAGE * l_span:
        checks.fail("gnss-coverage", fig, f">= {MIN_GNSS_COVERAGE:.0%} of the logger's span",
                    f"{fig}: the GNSS log is cut short or belongs to another record", field="gnss_log")
    checks.add("gnss-coverage", "pass", fig, f">= {MIN_GNSS_COVERAGE:.0%} of the logger's span")


def _pps_checks(checks: Checks, clock, st: SyncSettings, dt: float) -> None:
    """Checks of the PPS fit: edges found vs expected, residuals vs the sampling interval, a plausible drift."""
    found, exp_, spur = clock.n_edges, clock.n_expected, clock.n_spurious
    fig = f"{found} edges of {exp_} expected, {spur} spurious"
    if found < 0.8 * exp_ or spur > max(2, 0.05 * found):
        checks.fail("pps-edges", fig, "found >= 80 % of expected, spurious <= 5 %",
                    f"{fig}: PPS line noisy or intermittent (or an inverted PPS: pps_inverted = true under "
                    "[signals] of --logger-format)", field="pps")
    checks.add("pps-edges", "warn" if found < exp_ or spur else "pass", fig, "found >= 80 % of expected")
    fig = (f"residual RMS {clock.residual_rms_s * 1e3:.2f} ms, max {clock.residual_max_s * 1e3:.2f} ms, "
           f"sampling interval {dt * 1e3:.1f} ms")
    if not clock.consistent and clock.residual_max_s > dt:
        checks.fail("clock-fit", fig, "max <= sampling interval",
                    f"{fig}: the PPS edges do not follow one linear clock (clock jumps, wrong --rate, jitter?)")
    checks.add("clock-fit", "pass" if clock.consistent else "warn", fig,
               "every edge inside its two samples" if clock.consistent else "max <= sampling interval",
               "" if clock.consistent else "no clock is consistent with every edge: least squares used")
    ppm = clock.drift * 1e6
    fig = f"{ppm:+.1f} ppm" + (f" ({clock.drift_range[0] * 1e6:+.0f} to {clock.drift_range[1] * 1e6:+.0f} ppm "
                               "consistent with the edges)" if clock.consistent else " (least squares)")
    if abs(ppm) > st.max_drift_ppm:
        checks.fail("drift", fig, f"|drift| <= {st.max_drift_ppm:g} ppm",
                    f"logger clock drift {fig} is beyond a crystal's +-{st.max_drift_ppm:g} ppm (wrong --rate?)")
    checks.add("drift", "pass", fig, f"|drift| <= {st.max_drift_ppm:g} ppm")


def _whole_second(checks: Checks, st: SyncSettings, clock, g_ax, l_ax, rec, gnss_h, laser, baro, logger_gps_time,
                  dt: float):
    """The whole GPS second of the logger clock from the coarse alignment (height signal, GNSS time column or
    stream ends) with its checks; returns (clock, coarse alignment, its figures, the height signal used)."""
    sig_name = "laser" if laser is not None and np.isfinite(laser).sum() > 10 else (
        "baro" if baro is not None and np.isfinite(baro).sum() > 10 else None)
    sig_val = laser if sig_name == "laser" else baro
    coarse, figs = _coarse(checks, st, clock, g_ax, l_ax, rec, gnss_h, sig_name, sig_val, logger_gps_time)
    clock, figs = resolve_whole_seconds(clock, coarse)
    fig = f"{coarse.method}: bound {figs['bound_s']:.3f} s"
    if not figs["resolvable"]:
        checks.fail("coarse-alignment", fig, "bound < 0.45 s", f"{fig}: cannot pick the whole GPS second"
                    + (f" (correlation peak {figs.get('peak_correlation')}, next {figs.get('second_peak_correlation')};"
                       " a longer record, or --end-gap if the recorders stopped together)"
                       if "peak_correlation" in figs else ""))
    checks.add("coarse-alignment", "pass", fig, "bound < 0.45 s")
    fig = f"coarse - PPS = {figs['residual_s'] * 1e3:+.1f} ms after the whole second"
    lim = f"|.| <= {figs['residual_limit_s'] * 1e3:.0f} ms"
    if figs["contradicted"]:
        checks.fail("coarse-vs-pps", fig, lim, f"{fig}: the PPS fit contradicts the {coarse.method} alignment")
    checks.add("coarse-vs-pps", "pass", fig, lim)
    if st.end_gap_s is not None and not coarse.method.startswith("stream ends"):
        ends = coarse_by_ends(g_ax.t[-1], l_ax.t[-1], st.end_gap_s)
        d = float(ends.gps_at_ref - clock.to_gps(ends.t_ref))
        fig = f"stream ends - clock = {d:+.2f} s"
        if abs(d) > st.end_gap_s + figs["bound_s"] + 0.02:
            checks.fail("coarse-vs-pps", fig, f"|.| <= --end-gap {st.end_gap_s:g} s",
                        f"{fig}: the recorders did not stop within the declared {st.end_gap_s:g} s")
        checks.add("coarse-vs-pps", "pass", fig, f"|.| <= --end-gap {st.end_gap_s:g} s")
    fig = f"+-{clock.max_error_s * 1e3:.2f} ms"
    lim = f"<= {st.max_time_error_s * 1e3:.1f} ms"
    if not clock.max_error_s <= st.max_time_error_s:
        sweep = abs(clock.drift) * (l_ax.t[-1] - l_ax.t[0])
        checks.fail("clock-bound", fig, lim, f"the PPS pins the logger clock only to {fig} over the record (the "
                    f"sampling phase swept about {sweep * 1e3:.0f} ms against the {dt * 1e3:.0f} ms sample interval; "
                    "about two intervals pin it: a longer record helps; --max-time-error to accept)")
    checks.add("clock-bound", "pass", fig, lim)
    return clock, coarse, figs, sig_val


def _exposures(checks: Checks, st: SyncSettings, t_gps, l_ax, rec, photo, trigger):
    """Exposure spikes of the light sensor (GPS s) and their triggers, with the fit and trigger checks."""
    spikes = detect_spikes(t_gps[rec], l_ax.fill(photo)[rec], tau=st.tau, blackout_s=st.blackout_s,
                           polarity=st.photo_polarity)
    if len(spikes):
        q = float(np.median(spikes.fit_rms) / spikes.noise)
        fig = f"fit RMS {q:.2f} x the channel noise"
        if q > 2.5:
            checks.fail("spike-fit", fig, "<= 2.5", f"{fig}: the pulse model does not fit the spikes (check --tau "
                        f"{st.tau:g} s and --blackout {st.blackout_s:g} s)")
        checks.add("spike-fit", "pass" if q <= 1.5 else "warn", fig, "<= 2.5")
    trig = None
    if trigger is not None:
        trig = match_triggers(trigger_times(t_gps[rec], l_ax.fill(trigger)[rec] > 0.5), spikes.t_exposure,
                              st.max_lag_s)
        nu = len(trig.unmatched_spikes)
        fig = f"{nu} of {len(spikes)} spikes without a trigger in the {st.max_lag_s:g} s before"
        if nu > max(2, 0.1 * len(spikes)):
            checks.fail("spikes-vs-triggers", fig, "<= 10 %", f"{fig}: false detections (light changes, wrong "
                        "polarity?) or a trigger channel that misses commands")
        checks.add("spikes-vs-triggers", "warn" if nu else "pass", fig, "<= 10 %",
                   f"{fig} (a lost trigger packet?)" if nu else "")
    return spikes, trig


def trigger_times(t: np.ndarray, on: np.ndarray) -> np.ndarray:
    """Times (s) of the shutter commands in a trigger channel: the first sample of every run of 'on' samples."""
    on = np.asarray(on, bool)
    return np.asarray(t, float)[on & ~np.r_[False, on[:-1]]]


def _coarse(checks: Checks, st: SyncSettings, clock: ClockFit, g_ax: RestoredAxis, l_ax: RestoredAxis,
            rec: np.ndarray, gnss_h, sig_name, sig_val, logger_gps_time) -> tuple[CoarseAlignment, dict]:
    """The coarse alignment from the best evidence there is: GNSS time in the logger, laser/baro against the GNSS
    height, or the stream ends within a declared gap; fails the 'coarse-alignment' check when there is none."""
    tried = []
    if logger_gps_time is not None and np.isfinite(logger_gps_time).sum() > 3:
        return coarse_by_time_tags(l_ax.t[rec], l_ax.fill(logger_gps_time)[rec]), {}
    if sig_name is not None and gnss_h is not None:
        okg = ~g_ax.filled
        try:
            centre = float(g_ax.t[-1] - l_ax.t[-1]) if st.search_s is not None else None
            c = coarse_by_correlation(g_ax.t[okg], g_ax.fill(gnss_h)[okg], l_ax.t[rec], l_ax.fill(sig_val)[rec],
                                      clock, sig_name, search_s=st.search_s, centre_offset_s=centre)
        except InputError as exc:
            tried.append(str(exc))
        else:
            f = c.figures
            amb = f.get("ambiguity_ratio")
            if f["peak_correlation"] >= 0.5 and (amb is None or amb < 0.8) and c.bound_s < 0.45:
                return c, {}
            tried.append(f"{sig_name} vs GNSS height inconclusive (peak correlation {f['peak_correlation']:.2f}, "
                         f"next {f.get('second_peak_correlation')}, bound {c.bound_s:.2f} s)")
    elif gnss_h is None:
        tried.append("no GNSS height in the GNSS log")
    else:
        tried.append("no laser or baro channel in the logger")
    if st.end_gap_s is not None:
        c = coarse_by_ends(g_ax.t[-1], l_ax.t[-1], st.end_gap_s)
        if tried:
            checks.add("coarse-alignment", "warn", "; ".join(tried), "", "fell back to the stream ends")
        return c, {}
    checks.fail("coarse-alignment", "; ".join(tried) or "no evidence", "one of: laser/baro + GNSS height, GNSS "
                "time in the logger, --end-gap", "nothing fixes the whole GPS second: " + "; ".join(tried)
                + " (give --end-gap S < 0.45 if the recorders stopped within S s of each other)")
    raise AssertionError  # unreachable


@dataclass
class SyncOptions:
    """Inputs and settings of `dgcal sync`: the GNSS packet log, the logger stream, the images (folder or CSV),
    the logger format description (TOML, None: dgcal's CSV) with column overrides `ROLE=COLUMN`, and the
    settings; fields left None take the format's or SyncSettings' defaults."""

    gnss_log: Path
    logger: Path
    images: Path
    rate_hz: float | None = None
    gnss_rate_hz: float | None = None
    counter_bits: int | None = None        # None: the format's (16); 0: the counter never wraps
    tau: float = 0.05
    blackout_s: float = 0.06
    logger_format: Path | None = None
    logger_columns: tuple[str, ...] = ()
    laser_unit: str | None = None
    end_gap_s: float | None = None
    search_s: float | None = None
    max_drift_ppm: float = 200.0
    max_time_error_s: float = 0.005


def synchronise_logger_files(opts: SyncOptions) -> SyncResult:
    """`dgcal sync`: read the files of `opts` (through the logger format description) and synchronise them."""
    fmt = read_logger_format(opts.logger_format) if opts.logger_format else LoggerFormat()
    fmt = fmt.with_columns(opts.logger_columns)
    if opts.laser_unit:
        if opts.laser_unit not in LENGTH_UNITS:
            raise InputError(f"unknown unit (one of {', '.join(LENGTH_UNITS)})", field="laser_unit")
        fmt.units["laser"] = opts.laser_unit
    rate = opts.rate_hz or fmt.rate_hz
    st = SyncSettings(rate_hz=rate, gnss_rate_hz=opts.gnss_rate_hz or fmt.gnss.rate_hz,
                      counter_bits=(fmt.counter_bits if opts.counter_bits is None else opts.counter_bits) or None,
                      tau=opts.tau, blackout_s=opts.blackout_s, photo_polarity=fmt.photo_polarity,
                      pps_inverted=fmt.pps_inverted, end_gap_s=opts.end_gap_s, search_s=opts.search_s,
                      max_drift_ppm=opts.max_drift_ppm, max_time_error_s=opts.max_time_error_s)
    for name, v in (("tau", st.tau), ("blackout_s", st.blackout_s), ("rate_hz", st.rate_hz),
                    ("max_time_error_s", st.max_time_error_s), ("max_drift_ppm", st.max_drift_ppm)):
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"must be positive, not {v}", field=name)
    if st.end_gap_s is not None and not (np.isfinite(st.end_gap_s) and st.end_gap_s >= 0):
        raise InputError(f"must be >= 0, not {st.end_gap_s}", field="end_gap_s")
    g = read_gnss_log(opts.gnss_log, fmt.gnss)
    week = int(np.floor(g.t[0] / SECONDS_PER_WEEK))
    lg = read_logger(opts.logger, fmt, gps_week=week)
    names, clock = read_images(opts.images)
    try:
        return synchronise(g.t, lg.counter, lg.pps, lg.photo, names, trigger=lg.trigger, image_clock=clock,
                           gnss_h=g.h, laser=lg.laser, baro=lg.baro, logger_gps_time=lg.gps_time, settings=st)
    except InputError as exc:
        packet = getattr(exc, "packet", None)
        if exc.path is not None or packet is None:
            raise
        path, lines, col = ((opts.logger, lg.lines, fmt.columns.get("counter")) if exc.field == "counter"
                            else (opts.gnss_log, g.lines, fmt.gnss.time))
        raise InputError(exc.reason, path, int(lines[packet]) if packet < len(lines) else None,
                         str(col)) from None


def read_images(images: Path) -> tuple[list[str], np.ndarray | None]:
    """Image names in shooting order and their camera-clock times (s, any origin; None when unknown): a CSV
    `image[,camera_time_s]`, or a folder (sorted by name; EXIF DateTimeOriginal + SubSecTimeOriginal when
    every image has them)."""
    images = Path(images)
    if images.is_dir():
        files = list_image_files(images, raw=True)
        times = [_exif_time(p) for p in files]
        clock = None if any(t is None for t in times) else np.array(times, float)
        return [p.name for p in files], clock
    im = read_table(images, ("image",), ("camera_time_s",))
    clock = im.get("camera_time_s")
    if clock is not None and not np.all(np.isfinite(clock)):
        validate.values_in_range(clock, -MAX_CAMERA_CLOCK_S, MAX_CAMERA_CLOCK_S, images, "camera_time_s", im.lines,
                                 allow_nan=True, unit="s")
        clock = None     # some times missing: the images are paired by order
    if clock is not None:
        validate.values_in_range(clock, -MAX_CAMERA_CLOCK_S, MAX_CAMERA_CLOCK_S, images, "camera_time_s", im.lines,
                                 unit="s")
        span = float(clock.max() - clock.min()) if len(clock) else 0.0
        if span > MAX_CAMERA_SPAN_S:
            i = int(np.argmax(np.abs(clock - np.median(clock))))
            raise InputError(f"the camera times span {span:.6g} s: more than {MAX_CAMERA_SPAN_S:g} s for one flight",
                             images, int(im.lines[i]), "camera_time_s")
    names = [str(x) for x in im["image"]]
    _check_capture_order(names, clock, images, im.lines)
    return names, clock


def _check_capture_order(names: list[str], clock, path, lines) -> None:
    """Rows of an images CSV in capture order: camera times that increase, or (without them, when the images are
    paired by order) image numbers that do; InputError naming the first row out of order."""
    if clock is not None:
        back = np.flatnonzero(np.diff(clock) < 0)
        if len(back):
            i = int(back[0]) + 1
            raise InputError(f"camera time goes back ({clock[i]:.3f} s after {clock[i - 1]:.3f} s): the rows must be "
                             "in capture order", path, int(lines[i]), "camera_time_s")
        return
    nums = [re.findall(r"\d+", n) for n in names]
    if len(names) < 2 or not all(nums):
        return
    idx = np.array([int(n[-1]) for n in nums])
    back = np.flatnonzero(np.diff(idx) < 0)
    if len(back) and not (len(back) == 1 and idx[back[0] + 1] <= 1):      # a counter's one wrap (9999 -> 0001)
        i = int(back[0]) + 1
        raise InputError(f"{names[i]} comes after {names[i - 1]}: without camera times the images are paired with the "
                         "exposures in row order, so the rows must be in capture order (sort them, or add "
                         "camera_time_s)", path, int(lines[i]), "image")


MAX_CAMERA_CLOCK_S = 1e11      # s, |camera time| (any origin; Unix seconds are 1.7e9)
MAX_CAMERA_SPAN_S = 7 * 86400.0  # s, the camera times of one flight span less than a week


def _exif_time(path: Path) -> float | None:
    """Camera-clock time (s since 1970, local camera time) of an image from EXIF, or None."""
    try:
        with Image.open(path) as im:
            ex = im.getexif()
            sub = ex.get_ifd(0x8769)
            s = sub.get(0x9003) or ex.get(0x0132)
            frac = sub.get(0x9291) or "0"
    except Exception:  # noqa: BLE001 - an unreadable EXIF block is just no time
        return None
    if not s:
        return None
    try:
        t = datetime.datetime.strptime(str(s).strip("\x00 "), "%Y:%m:%d %H:%M:%S").replace(
            tzinfo=datetime.timezone.utc)
        return t.timestamp() + float("0." + str(frac).strip("\x00 ") or "0")
    except ValueError:
        return None


def synchronise_files(gnss_log: Path, logger_log: Path, images: Path, **kw) -> SyncResult:
    """`synchronise_logger_files` with keyword settings (SyncOptions fields) instead of an options object."""
    return synchronise_logger_files(SyncOptions(Path(gnss_log), Path(logger_log), Path(images), **kw))
