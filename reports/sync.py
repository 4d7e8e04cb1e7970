"""HTML report of the time synchronisation: the checks, packet loss, PPS clock fit, exposure spikes, unmatched
images, laser (or baro) against GNSS height."""
from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.io.formats import week_sow, write_events
from dgcal.reports.honesty import add_honesty, no_reference
from dgcal.reports.glossary import label
from dgcal.reports.html import HtmlReport, new_figure

SYNC_NO_REFERENCE = ("No reference: the exposure times are not compared with known ones (the checks above test the "
                     "data's own consistency; the exposure sigmas are checked downstream, by the mounting's delay).")


def write_sync_report(path: Path, res) -> Path:
    """One-file HTML report of a `dgcal.pos.lowcost.sync.SyncResult`."""
    rep = HtmlReport("dgcal time synchronisation")
    s = res.summary()
    rep.headline([("events paired with an exposure / images", f"{s['n_events']} / {s['n_images']}"),
                  ("exposure σ, median (ms)", None if s.get("exposure_sigma_s_median") is None
                   else 1e3 * s["exposure_sigma_s_median"]),
                  ("event time bound, max (ms)", None if s.get("event_time_bound_s_max") is None
                   else 1e3 * s["event_time_bound_s_max"]),
                  ("logger clock drift (ppm)", s.get("clock_drift_ppm"))],
                 "Exposure times of the images in GPS time, from the logger's photoresistor and PPS:")
    rep.warnings(s["warnings"])
    add_honesty(rep, no_reference(SYNC_NO_REFERENCE))
    rep.heading("Checks")
    rep.table(["check", "status", "figure", "limit", "message"],
              [[c["name"], c["status"], c["figure"], c["limit"], c["message"]] for c in s["checks"]])
    lag = s.pop("shutter_lag_s") or {}
    skipped = s.pop("skipped_triggers")
    um = s.pop("unmatched_images")
    rep.heading("Summary")
    rep.kv_table([(k, v) for k, v in s.items() if k not in ("checks", "warnings", "coarse_alignment",
                                                           "unmatched_spikes_gps_s")]
                 + [(f"coarse alignment: {label(k)}", v) for k, v in s["coarse_alignment"].items()])
    rep.heading("Unmatched images")
    if um:
        rep.table(["image", "reason"], [[u["image"], u["reason"]] for u in um])
    else:
        rep.text("Every image was paired with an exposure spike.")
    if s["unmatched_spikes_gps_s"]:
        rep.text("Spikes without an image (GPS seconds of week): "
                 + ", ".join(f"{t % 604800.0:.3f}" for t in s["unmatched_spikes_gps_s"]))
    rep.heading("Triggers and shutter lag")
    rep.kv_table([("skipped triggers (index)", ", ".join(map(str, skipped)) or "none")]
                 + [(f"shutter lag, {label(k)} (s)", v) for k, v in lag.items()])
    fig, ax = new_figure(10, 3, ncols=2)
    for a, axis, name in ((ax[0], res.gnss_axis, "GNSS"), (ax[1], res.logger_axis, "logger")):
        a.plot(axis.t - axis.t[0], axis.filled.astype(int), lw=0.6)
        a.set_title(f"{name}: {axis.n_lost} lost packets")
        a.set_xlabel("time since start (s)")
        a.set_yticks([0, 1], ["recorded", "lost"])
    rep.figure(fig, "Packet loss (seed 000 Fig. 5): lost slots were filled with the previous packet")
    sp = res.spikes
    if len(sp.t_exposure):
        fig, ax = new_figure(10, 3)
        t0 = res.t_logger_gps[0]
        ax.plot(sp.t_exposure - t0, (sp.t_peak - sp.t_exposure) * 1e3, ".", label="seed's peak time - fitted exposure")
        ax.errorbar(sp.t_exposure - t0, np.zeros_like(sp.t_exposure), yerr=sp.sigma_t * 1e3, fmt="none", alpha=0.5,
                    label="exposure sigma")
        ax.set_xlabel("GPS time since logger start (s)")
        ax.set_ylabel("time (ms)")
        ax.legend()
        rep.figure(fig, "Exposure spikes: the seed's peak time lies at the end of the blackout, "
                        "the fitted centre is the exposure")
    if res.laser is not None and res.gnss_h is not None:
        fig, ax = new_figure(10, 3)
        t0 = res.t_logger_gps[0]
        ax.plot(res.gnss_axis.t - t0, res.gnss_h - np.nanmedian(res.gnss_h), lw=0.8, label="GNSS height")
        ax.plot(res.t_logger_gps - t0, res.laser - np.nanmedian(res.laser), lw=0.8, label="laser range / baro")
        ax.set_xlabel("GPS time since logger start (s)")
        ax.set_ylabel("m (median removed)")
        ax.legend()
        rep.figure(fig, "Laser range (or baro) against GNSS height after alignment (seed 000 Fig. 7)")
    return rep.write(path)


def write_exposures(path: Path, res) -> None:
    """CSV image,gps_week,gps_sow,sigma_s,bound_s,t_peak_sow of the events (exposure sigma and error bound, s)."""
    w, sow = week_sow(res.events.t)
    pk = week_sow(res.spikes.t_peak[res.event_spike])[1] if len(res.events) else np.zeros(0)
    with atomic_write(path) as fh:
        fh.write("image,gps_week,gps_sow,sigma_s,bound_s,t_peak_sow\n")
        for i in range(len(res.events)):
            fh.write(f"{res.events.image[i]},{int(w[i])},{sow[i]:.6f},{res.event_sigma_s[i]:.6f},"
                     f"{res.event_bound_s[i]:.6f},{pk[i]:.6f}\n")


def write_sync_outputs(out_dir: str | Path, res, names: Mapping[str, str]) -> dict[str, Path]:
    """`dgcal sync`'s files in `out_dir`, named by role in `names`: events (CSV image,gps_week,gps_sow), exposures
    (events with sigma and bound), summary (sync.json: figures, checks, unmatched images) and report (HTML) of a
    dgcal.pos.lowcost.sync.SyncResult; returns the paths by role."""
    out = Path(out_dir)
    paths = {role: out / names[role] for role in ("events", "summary", "report") if role in names}
    write_events(paths["events"], res.events)
    if "exposures" in names:
        paths["exposures"] = out / names["exposures"]
        write_exposures(paths["exposures"], res)
    with atomic_write(paths["summary"]) as fh:
        json.dump({**res.summary(), "honesty": no_reference(SYNC_NO_REFERENCE)}, fh, indent=1)
    write_sync_report(paths["report"], res)
    return paths
