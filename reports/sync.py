"""HTML report of the time synchronisation: packet loss, PPS clock fit, exposure spikes, laser vs GNSS height."""
from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dgcal.fields.io.formats import write_events
from dgcal.reports.html import HtmlReport, new_figure


def write_sync_report(path: Path, res) -> Path:
    """One-file HTML report of a `dgcal.pos.lowcost.sync.SyncResult`."""
    rep = HtmlReport("dgcal time synchronisation")
    s = res.summary()
    lag = s.pop("shutter_lag_s") or {}
    skipped = s.pop("skipped_triggers")
    rep.kv_table(s.items())
    rep.heading("Triggers and shutter lag")
    rep.kv_table([("skipped triggers (index)", ", ".join(map(str, skipped)) or "none")]
                 + [(f"lag {k} (s)", v) for k, v in lag.items()])
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
        ax.set_ylabel("ms")
        ax.legend()
        rep.figure(fig, "Exposure spikes: the seed's peak time lies at the end of the blackout, "
                        "the fitted centre is the exposure")
    if res.laser is not None and res.gnss_h is not None:
        fig, ax = new_figure(10, 3)
        t0 = res.t_logger_gps[0]
        ax.plot(res.gnss_axis.t - t0, res.gnss_h - np.median(res.gnss_h), lw=0.8, label="GNSS height")
        ax.plot(res.t_logger_gps - t0, res.laser - np.median(res.laser), lw=0.8, label="laser range")
        ax.set_xlabel("GPS time since logger start (s)")
        ax.set_ylabel("m (median removed)")
        ax.legend()
        rep.figure(fig, "Laser range against GNSS height after alignment (seed 000 Fig. 7)")
    return rep.write(path)


def write_sync_outputs(out_dir: str | Path, res, names: Mapping[str, str]) -> dict[str, Path]:
    """`dgcal sync`'s files in `out_dir`, named by role in `names`: events (CSV image,gps_week,gps_sow),
    summary (sync.json) and report (HTML) of a dgcal.pos.lowcost.sync.SyncResult; returns the paths by role."""
    out = Path(out_dir)
    paths = {role: out / names[role] for role in ("events", "summary", "report")}
    write_events(paths["events"], res.events)
    paths["summary"].write_text(json.dumps(res.summary(), indent=1))
    write_sync_report(paths["report"], res)
    return paths
