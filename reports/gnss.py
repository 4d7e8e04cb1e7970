"""HTML report of a GNSS single-point positioning run: track, sigma envelopes, satellites, DOP, residuals.

matplotlib (through dgcal.reports.html) is imported only when a report is drawn: `write_spp_outputs(...,
report=False)` (`dgcal pos --mode spp --no-report`) writes gnss.csv and the summary without it."""
from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dgcal.fields.crs import ecef_to_geodetic
from dgcal.fields.frames import R_ecef_to_enu
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.pos.gnss.spp import enu_sigmas, write_gnss_csv

if TYPE_CHECKING:
    from dgcal.pos.gnss.spp import SppRun


def _enu(sol, ref_ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ENU coordinates (m) of the fixes about ``ref_ecef`` and their ENU sigmas."""
    lat, lon, _ = ecef_to_geodetic(ref_ecef)
    R = R_ecef_to_enu(lat, lon)
    ok = sol.ok
    _, s_enu = enu_sigmas(sol.p_ecef[ok], sol.cov_p[ok])
    return (sol.p_ecef[ok] - ref_ecef) @ R.T, s_enu


def write_spp_report(path: str | Path, sol, summary: dict, ref_ecef: np.ndarray | None = None) -> Path:
    """Write ``gnss_report.html`` for an ``SppSolution`` (``ref_ecef``: known position, else the median)."""
    from dgcal.reports.html import HtmlReport, new_figure   # why: matplotlib only when a report is drawn
    ok = sol.ok
    rep = HtmlReport("dgcal pos — GNSS single-point positioning")
    rep.kv_table([("observations", summary.get("rinex_obs", "")),
                  ("navigation", summary.get("rinex_nav", "")),
                  ("signals", ", ".join(f"{k}:{v}" for k, v in summary.get("signals", {}).items())),
                  ("epochs / with fix", f"{summary['n_epochs']} / {summary['n_fixed']}"),
                  ("mean satellites used", summary["mean_n_sat"]),
                  ("median PDOP", summary["median_pdop"]),
                  ("median sigma E/N/U (m)", " / ".join(f"{v:.2f}" for v in summary["median_sigma_enu_m"])),
                  ("satellites rejected by RAIM", summary["n_rejected"])])
    warn = []
    if summary["n_fixed"] < summary["n_epochs"]:
        warn.append(f"{summary['n_epochs'] - summary['n_fixed']} epochs without a fix "
                    "(fewer satellites than unknowns, or GDOP > 30).")
    if summary["n_rejected"]:
        warn.append(f"{summary['n_rejected']} satellite observations rejected by RAIM.")
    warn += list(summary.get("warnings", []))
    rep.warnings(warn)
    if not ok.any():
        return rep.write(path)
    ref = np.asarray(ref_ecef, float) if ref_ecef is not None else np.median(sol.p_ecef[ok], axis=0)
    t = sol.t_gps[ok] - sol.t_gps[ok][0]
    enu, s_enu = _enu(sol, ref)
    what = "the reference position" if ref_ecef is not None else "the median position"
    rep.heading("Position")
    fig, axs = new_figure(9, 7, nrows=3, sharex=True)
    for i, (ax, name) in enumerate(zip(axs, ("east", "north", "up"))):
        ax.plot(t, enu[:, i], ".", ms=3, label=name)
        ax.fill_between(t, -s_enu[:, i], s_enu[:, i], alpha=0.2, color="gray", label="±1σ")
        ax.set_ylabel(f"{name} (m)")
        ax.grid(alpha=0.3)
    axs[0].legend(loc="upper right")
    axs[-1].set_xlabel("time since first fix (s)")
    rep.figure(fig, f"Position about {what} with the reported 1-sigma envelope (grey, centred on zero).")
    fig, ax = new_figure(6, 6)
    ax.plot(enu[:, 0], enu[:, 1], ".-", ms=3, lw=0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.grid(alpha=0.3)
    rep.figure(fig, "Horizontal track.")
    rep.heading("Satellites and geometry")
    fig, ax = new_figure(9, 3.5)
    ax.step(sol.t_gps - sol.t_gps[ok][0], sol.n_sat, where="mid", label="satellites used")
    ax2 = ax.twinx()
    ax2.plot(sol.t_gps - sol.t_gps[ok][0], sol.dop["pdop"], "r.", ms=3, label="PDOP")
    ax.set_xlabel("time since first fix (s)")
    ax.set_ylabel("satellites")
    ax2.set_ylabel("PDOP", color="r")
    ax.grid(alpha=0.3)
    rep.figure(fig, "Satellites used and PDOP per epoch.")
    rows = {}
    for k in np.nonzero(ok)[0]:
        for sat, r in sol.residuals_m[k].items():
            rows.setdefault(sat, []).append((sol.t_gps[k] - sol.t_gps[ok][0], r))
    if rows:
        fig, ax = new_figure(9, 4.5)
        for sat in sorted(rows):
            a = np.array(rows[sat])
            ax.plot(a[:, 0], a[:, 1], ".", ms=2, label=sat)
        ax.set_xlabel("time since first fix (s)")
        ax.set_ylabel("code residual (m)")
        ax.grid(alpha=0.3)
        ax.legend(ncol=8, fontsize=6, loc="upper right")
        rep.figure(fig, "Post-fit pseudorange residuals per satellite.")
        rep.table(["satellite", "epochs", "mean residual (m)", "RMS (m)"],
                  [[s, len(rows[s]), float(np.mean(np.array(rows[s])[:, 1])),
                    float(np.sqrt(np.mean(np.array(rows[s])[:, 1] ** 2)))] for s in sorted(rows)])
    eps = [e for e in sol.epochs if e is not None]
    if eps:
        fig, ax = new_figure(6, 6, subplot_kw={"projection": "polar"})
        for e in eps[:: max(1, len(eps) // 200)]:
            ax.plot(np.radians(e.azim_deg), 90.0 - e.elev_deg, "b.", ms=1)
        ax.set_theta_zero_location("N")
        ax.set_theta_direction(-1)
        ax.set_ylim(0, 90)
        rep.figure(fig, "Sky plot of the satellites used (radius = zenith angle, degrees).")
    return rep.write(path)


def write_spp_outputs(out_dir: str | Path, run: SppRun, names: Mapping[str, str],
                      report: bool = True) -> dict[str, Path]:
    """`dgcal pos --mode spp`'s files in `out_dir`, named by role in `names`: gnss (gnss.csv, ECEF m),
    gnss_summary (JSON) and, unless `report` is False, gnss_report (HTML); returns the paths written by role.
    `run`: a dgcal.pos.gnss.spp.SppRun (or anything with its solution, summary and reference_ecef)."""
    out = Path(out_dir)
    roles = ("gnss", "gnss_summary") + (("gnss_report",) if report else ())
    paths = {role: out / names[role] for role in roles}
    write_gnss_csv(paths["gnss"], run.solution)
    with atomic_write(paths["gnss_summary"]) as fh:
        json.dump(run.summary, fh, indent=2)
    if report:
        write_spp_report(paths["gnss_report"], run.solution, run.summary, run.reference_ecef)
    return paths
