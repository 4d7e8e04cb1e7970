"""Seed 000's time synchronisation end to end: restore both streams, align the logger to GPS time by PPS,
find the exposures, match triggers and image files, and produce an events table."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dgcal.fields.io.csv_tables import read_table
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import Events, gps_seconds
from dgcal.pos.lowcost.exposure import Spikes, TriggerMatch, detect_spikes, match_images, match_triggers
from dgcal.pos.lowcost.stream_align import ClockFit, fit_clock_to_pps
from dgcal.pos.lowcost.time_axis import RestoredAxis, restore_from_counter, restore_from_time_tags


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
    laser: np.ndarray | None       # laser range on the restored logger axis (m)

    def summary(self) -> dict:
        """Figures for reports and JSON output."""
        return {
            "gnss_lost_packets": self.gnss_axis.n_lost, "gnss_gaps": len(self.gnss_axis.gaps()),
            "logger_lost_packets": self.logger_axis.n_lost,
            "clock_offset_s": self.clock.offset_s, "clock_drift": self.clock.drift,
            "clock_max_error_s": self.clock.max_error_s, "pps_edges": self.clock.n_edges,
            "n_exposures": int(len(self.spikes.t_exposure)),
            "exposure_sigma_s_median": float(np.nanmedian(self.spikes.sigma_t)) if len(self.spikes.t_exposure) else None,
            "skipped_triggers": [] if self.triggers is None else [int(i) for i in self.triggers.skipped],
            "shutter_lag_s": None if self.triggers is None else self.triggers.lag_stats(),
            "n_events": len(self.events),
        }


def synchronise(gnss_t: np.ndarray, logger_counter: np.ndarray, pps: np.ndarray, photo: np.ndarray,
                images: list[str], rate_hz: float = 50.0, gnss_rate_hz: float | None = None,
                counter_bits: int | None = 16, trigger: np.ndarray | None = None,
                image_clock: np.ndarray | None = None, tau: float = 0.05, blackout_s: float = 0.06,
                gnss_h: np.ndarray | None = None, laser: np.ndarray | None = None) -> SyncResult:
    """Synchronise a GNSS stream (GPS time tags, s) and a logger stream (counter, PPS, photoresistor) into events."""
    dt = 1.0 / rate_hz
    g_ax = restore_from_time_tags(gnss_t, 1.0 / (gnss_rate_hz or rate_hz))
    l_ax = restore_from_counter(logger_counter, dt, bits=counter_bits)
    rec = ~l_ax.filled
    clock = fit_clock_to_pps(l_ax.t, l_ax.fill(pps), g_ax.t[-1], l_ax.t[-1], valid=rec)
    t_gps = clock.to_gps(l_ax.t)
    spikes = detect_spikes(t_gps[rec], l_ax.fill(photo)[rec], tau=tau, blackout_s=blackout_s)
    trig = None
    if trigger is not None:
        on = l_ax.fill(trigger)[rec] > 0.5
        trig = match_triggers(t_gps[rec][on], spikes.t_exposure)
    pairs = match_images(list(images), spikes.t_exposure, image_clock)
    ev = Events(np.array([p[0] for p in pairs], dtype=object), np.array([spikes.t_exposure[p[1]] for p in pairs]))
    return SyncResult(g_ax, l_ax, clock, spikes, trig, ev, t_gps,
                      None if gnss_h is None else g_ax.fill(gnss_h), None if laser is None else l_ax.fill(laser))


@dataclass
class SyncOptions:
    """Inputs and settings of `dgcal sync`: the GNSS packet log, the logger stream, the images (folder or CSV)
    and the logger's rates (Hz), counter width, light-sensor time constant and blackout (s)."""

    gnss_log: Path
    logger: Path
    images: Path
    rate_hz: float = 50.0
    gnss_rate_hz: float | None = None       # default: rate_hz
    counter_bits: int | None = 16           # None: no wrap-around
    tau: float = 0.05
    blackout_s: float = 0.06


def synchronise_logger_files(opts: SyncOptions) -> SyncResult:
    """`dgcal sync`: `synchronise_files` with the files and settings of `opts`."""
    return synchronise_files(opts.gnss_log, opts.logger, opts.images, rate_hz=opts.rate_hz,
                             gnss_rate_hz=opts.gnss_rate_hz, counter_bits=opts.counter_bits, tau=opts.tau,
                             blackout_s=opts.blackout_s)


def synchronise_files(gnss_log: Path, logger_log: Path, images: Path, **kw) -> SyncResult:
    """`synchronise` on files: GNSS log CSV `gps_week,gps_sow[,h]`, logger CSV `counter,pps,photo[,trigger][,laser]`,
    and an image list CSV `image[,camera_time_s]` or a folder of images (sorted by name)."""
    g = read_table(gnss_log, ("gps_week", "gps_sow"), ("h",))
    lg = read_table(logger_log, ("counter", "pps", "photo"), ("trigger", "laser"))
    images = Path(images)
    if images.is_dir():
        names = sorted(p.name for p in images.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".tif", ".png"))
        clock = None
        if not names:
            raise InputError("no images (.jpg, .tif, .png) in the folder", images)
    else:
        im = read_table(images, ("image",), ("camera_time_s",))
        names = [str(x) for x in im["image"]]
        clock = im.get("camera_time_s")
    return synchronise(gps_seconds(g["gps_week"], g["gps_sow"]), lg["counter"].astype(np.int64), lg["pps"],
                       lg["photo"], names, trigger=lg.get("trigger"), image_clock=clock, gnss_h=g.get("h"),
                       laser=lg.get("laser"), **kw)
