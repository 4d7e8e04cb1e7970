"""The HTML page of a GNSS single-point positioning run, drawn from its plotted series alone (plain arrays; see
dgcal.reports.gnss.spp_report_series): this module imports matplotlib but none of the GNSS modules, so a
process can import it while another positions the epochs."""
from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np

from dgcal.reports.honesty import add_honesty
from dgcal.reports.html import HtmlReport, new_figure
from dgcal.reports.tables import flat_pairs
from dgcal.reports.units import fmt_value


def draw_spp_report(path: str | Path, series: dict, summary: dict) -> Path:
    """Write ``gnss_report.html`` from an SPP run's summary and its `series` (times s since the first fix, ENU m
    about the reference or the median position, sigmas m, residuals m, sky directions degrees)."""
    rep = HtmlReport("dgcal pos — GNSS single-point positioning")
    rep.headline([("median σ east, north, up (m)", summary["median_sigma_enu_m"]),
                  ("epochs with a fix / all", f"{summary['n_fixed']} / {summary['n_epochs']}")],
                 "Single-point positioning (code): each fix's 1-sigma.")
    rep.kv_table([("observations (RINEX)", summary.get("rinex_obs", "")),
                  ("navigation (RINEX)", summary.get("rinex_nav", "")),
                  ("signals", "; ".join(f"{k}: {fmt_value(v)}" for k, v in summary.get("signals", {}).items())),
                  ("satellites used, mean (count)", summary["mean_n_sat"]),
                  ("median PDOP", summary["median_pdop"]),
                  ("satellite observations rejected by RAIM", summary["n_rejected"])])
    warn = []
    if summary["n_fixed"] < summary["n_epochs"]:
        warn.append(f"{summary['n_epochs'] - summary['n_fixed']} epochs without a fix "
                    "(fewer satellites than unknowns, or GDOP > 30).")
    if summary["n_rejected"]:
        warn.append(f"{summary['n_rejected']} satellite observations rejected by RAIM.")
    warn += list(summary.get("warnings", []))
    more = flat_pairs(summary, SPP_SHOWN)
    if more:
        rep.heading("Further results")
        rep.kv_table(more)
    rep.warnings(warn)
    add_honesty(rep, summary.get("honesty"))
    if not len(series["t_fix_s"]):
        return rep.write(path)
    what = "the reference position" if series["reference_known"] else "the median position"
    rep.heading("Position")
    rep.figure(partial(_position_figure, series),
               f"Position about {what} with the reported 1-sigma envelope (grey, centred on zero).")
    rep.figure(partial(_track_figure, series), "Horizontal track.")
    rep.heading("Satellites and geometry")
    rep.figure(partial(_geometry_figure, series), "Satellites used and PDOP per epoch.")
    res = series["residuals_m"]
    if res:
        rep.figure(partial(_residual_figure, res), "Post-fit pseudorange residuals by constellation (satellites in "
                   "brackets); satellites with over twice the median RMS are named at their largest residual.")
        rep.table(["satellite", "epochs", "mean residual (m)", "RMS (m)"],
                  [[s, len(r), float(np.mean(r)), float(np.sqrt(np.mean(r ** 2)))]
                   for s, (_, r) in sorted(res.items())])
    if len(series["sky_azim_deg"]):
        rep.figure(partial(_sky_figure, series), "Sky plot of the satellites used (radius = zenith angle, degrees).")
    return rep.write(path)


def _position_figure(s: dict):
    fig, axs = new_figure(9, 7, nrows=3, sharex=True)
    t, enu, sig = s["t_fix_s"], s["enu_m"], s["sigma_enu_m"]
    for i, (ax, name) in enumerate(zip(axs, ("east", "north", "up"))):
        ax.plot(t, enu[:, i], ".", ms=3, label=name)
        ax.fill_between(t, -sig[:, i], sig[:, i], alpha=0.2, color="gray", label="±1σ")
        ax.set_ylabel(f"{name} (m)")
        ax.grid(alpha=0.3)
    axs[0].legend(loc="upper right")
    axs[-1].set_xlabel("time since first fix (s)")
    return fig


def _track_figure(s: dict):
    fig, ax = new_figure(6, 6)
    ax.plot(s["enu_m"][:, 0], s["enu_m"][:, 1], ".-", ms=3, lw=0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.grid(alpha=0.3)
    return fig


def _geometry_figure(s: dict):
    fig, ax = new_figure(9, 3.5)
    ax.step(s["t_s"], s["n_sat"], where="mid", label="satellites used")
    ax2 = ax.twinx()
    ax2.plot(s["t_s"], s["pdop"], "r.", ms=3, label="PDOP")
    ax.set_xlabel("time since first fix (s)")
    ax.set_ylabel("satellites")
    ax2.set_ylabel("PDOP", color="r")
    ax.grid(alpha=0.3)
    return fig


# summary keys shown above or left to gnss_summary.json (settings); any other is shown under "Further results"
SPP_SHOWN = {"rinex_obs", "rinex_nav", "signals", "n_epochs", "n_fixed", "mean_n_sat", "median_pdop",
             "median_sigma_enu_m", "n_rejected", "warnings", "honesty", "options", "code_noise"}

SYSTEMS = {"G": "GPS", "E": "Galileo", "C": "BeiDou", "J": "QZSS", "R": "GLONASS"}


def _residual_figure(res: dict):
    """Residuals coloured by constellation (per-satellite colours repeat after ten and tell nothing apart); the
    satellites whose RMS is over twice the median satellite's are named at their largest residual."""
    fig, ax = new_figure(9, 4.5)
    for sys_ in sorted({sat[0] for sat in res}):
        sats = [sat for sat in sorted(res) if sat[0] == sys_]
        ax.plot(np.concatenate([res[s][0] for s in sats]), np.concatenate([res[s][1] for s in sats]), ".", ms=2,
                label=f"{SYSTEMS.get(sys_, sys_)} ({len(sats)})")
    rms = {sat: float(np.sqrt(np.mean(r ** 2))) for sat, (_, r) in res.items()}
    limit = 2.0 * float(np.median(list(rms.values())))
    for sat in sorted(rms, key=rms.get, reverse=True)[:5]:
        if rms[sat] > limit:
            t, r = res[sat]
            k = int(np.argmax(np.abs(r)))
            ax.annotate(sat, (t[k], r[k]), xytext=(4, 0), textcoords="offset points", fontsize=7, va="center")
    ax.set_xlabel("time since first fix (s)")
    ax.set_ylabel("code residual (m)")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=5, fontsize=8, markerscale=3, frameon=False)
    return fig


def _sky_figure(s: dict):
    fig, ax = new_figure(6, 6, subplot_kw={"projection": "polar"})
    ax.plot(np.radians(s["sky_azim_deg"]), 90.0 - s["sky_elev_deg"], "b.", ms=1)
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    ax.set_ylim(0, 90)
    ax.set_yticks([30, 60, 90], ["60°", "30°", "0°"])   # elevation at the rings (radius: zenith angle)
    ax.set_title("satellites used: azimuth clockwise from north, elevation on the rings", fontsize=9)
    return fig
