"""HTML report of the time synchronisation: packet loss, PPS clock fit, exposure spikes, laser vs GNSS height."""
from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path

import numpy as np

from fields.csvio import atomic_write


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def write_sync_report(path: Path, res) -> None:
    """One-file HTML report of a `pos.sync_pipeline.SyncResult`."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs = []
    fig, ax = plt.subplots(1, 2, figsize=(10, 3))
    for a, axis, name in ((ax[0], res.gnss_axis, "GNSS"), (ax[1], res.logger_axis, "logger")):
        a.plot(axis.t - axis.t[0], axis.filled.astype(int), lw=0.6)
        a.set_title(f"{name}: {axis.n_lost} lost packets")
        a.set_xlabel("time since start (s)")
        a.set_yticks([0, 1], ["recorded", "lost"])
    figs.append(("Packet loss (seed Fig. 5)", _png(fig)))
    sp = res.spikes
    if len(sp.t_exposure):
        fig, ax = plt.subplots(figsize=(10, 3))
        ax.plot(sp.t_exposure - res.t_logger_gps[0], (sp.t_peak - sp.t_exposure) * 1e3, ".", label="peak - fitted exposure")
        ax.errorbar(sp.t_exposure - res.t_logger_gps[0], np.zeros_like(sp.t_exposure), yerr=sp.sigma_t * 1e3, fmt="none",
                    alpha=0.5, label="exposure sigma")
        ax.set_xlabel("GPS time since logger start (s)")
        ax.set_ylabel("ms")
        ax.legend()
        figs.append(("Exposure spikes: the seed's peak time against the fitted blackout centre", _png(fig)))
    if res.laser is not None and res.gnss_h is not None:
        fig, ax = plt.subplots(figsize=(10, 3))
        ax.plot(res.gnss_axis.t - res.t_logger_gps[0], res.gnss_h - np.median(res.gnss_h), lw=0.8, label="GNSS height")
        ax.plot(res.t_logger_gps - res.t_logger_gps[0], res.laser - np.median(res.laser), lw=0.8, label="laser range")
        ax.set_xlabel("GPS time since logger start (s)")
        ax.set_ylabel("m (median removed)")
        ax.legend()
        figs.append(("Laser range against GNSS height after alignment (seed Fig. 7)", _png(fig)))
    body = "".join(f"<h2>{html.escape(t)}</h2><img src='data:image/png;base64,{b}'>" for t, b in figs)
    summary = html.escape(json.dumps(res.summary(), indent=1))
    with atomic_write(path) as fh:
        fh.write(f"<!doctype html><html><head><meta charset='utf-8'><title>dgcal time synchronisation</title></head>"
                 f"<body><h1>Time synchronisation</h1><pre>{summary}</pre>{body}</body></html>")
