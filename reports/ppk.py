"""Files of `dgcal pos --mode ppk`: gnss.csv (ECEF m, fix status, covariance), gnss_summary.json, HTML report."""
from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dgcal.fields.crs import ecef_to_geodetic
from dgcal.fields.frames import R_ecef_to_enu
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.pos.gnss.ppk import STATUS, write_ppk_csv
from dgcal.pos.ppk_mode import PpkRun
from dgcal.reports.gnss import TIME_CORRELATED
from dgcal.reports.honesty import add_honesty, honesty_rows, honesty_section, no_reference
from dgcal.reports.html import HtmlReport, new_figure
from dgcal.reports.tables import flat_pairs
from dgcal.reports.units import fmt_value

# summary keys shown above or left to gnss_summary.json (settings, engine internals); any other key, such as one a
# later version adds, is shown under "Further results"
PPK_SHOWN = {"rinex_obs", "rinex_base", "rinex_nav", "base_ecef_m", "base_position_source", "counts", "n_epochs",
             "fix_rate", "median_ratio_fixed", "age_s", "slips_flagged_rover", "slips_flagged_base", "warnings",
             "honesty", "options", "engine", "signals_rover", "signals_base", "forward_float_reasons",
             "backward_float_reasons", "mode", "n_fixed", "run_time_s", "time_per_epoch_ms"}

_COLOURS = {"fixed": "tab:green", "float": "tab:orange", "single": "tab:red"}


def ppk_honesty(run: PpkRun) -> dict:
    """The honesty record of a PPK run (dgcal.reports.honesty): E/N/U errors against the known antenna position
    (`run.reference_ecef`, taken as exact; ENU axes at the reference) over each epoch's sigma from its covariance,
    by solution status (fixed, float, single); without a reference the line that there is none."""
    if run.reference_ecef is None:
        return no_reference("No reference: give the rover antenna's known position (--reference X Y Z, ECEF m) to "
                            "compare the solution with it.")
    res = run.result
    ref = np.asarray(run.reference_ecef, float)
    lat, lon, _ = ecef_to_geodetic(ref)
    R = R_ecef_to_enu(lat, lon)
    rows = []
    for code, name in ((3, "fixed"), (2, "float"), (1, "single")):
        m = res.status == code
        if not m.any():
            continue
        err = (res.p[m] - ref) @ R.T
        sig = np.sqrt(np.maximum(np.diagonal(R @ res.P[m] @ R.T, axis1=1, axis2=2), 0.0))
        rows += honesty_rows(err, sig, [f"{a} {name}" for a in "ENU"], "known antenna position")
    return honesty_section(rows, ["Known antenna position (--reference), taken as exact (its own error counts "
                                  "against the fixed epochs' millimetre sigmas): each epoch's E/N/U error over its "
                                  "sigma from the solution's covariance, by solution status.", TIME_CORRELATED])


def write_ppk_report(path: str | Path, run: PpkRun) -> Path:
    """``gnss_report.html`` of a PPK run: fix status over time, position about the reference (or median)."""
    res, s = run.result, run.summary
    rep = HtmlReport("dgcal pos — carrier-phase PPK")
    rep.headline([("fix rate (fixed epochs / all)", f"{100 * s['fix_rate']:.1f} %"),
                  ("epochs fixed / float / single", f"{s['counts']['fixed']} / {s['counts']['float']} / "
                                                      f"{s['counts']['single']} of {s['n_epochs']}")],
                 "Carrier-phase PPK of the rover against the base (the honesty table below: its errors against a "
                 "known position, when one is given).")
    rep.kv_table([("rover observations (RINEX)", s.get("rinex_obs", "")),
                  ("base observations (RINEX)", s.get("rinex_base", "")),
                  ("navigation (RINEX)", s.get("rinex_nav", "")),
                  ("base position (ECEF X, Y, Z) and source",
                   f"{fmt_value(run.base_ecef, 'm', coordinate=True)} m ({s.get('base_position_source')})"),
                  ("epochs fixed / float / single", f"{s['counts']['fixed']} / {s['counts']['float']} / "
                                                      f"{s['counts']['single']} of {s['n_epochs']}"),
                  ("fix rate", f"{100 * s['fix_rate']:.1f} %"),
                  ("median ratio of the ambiguity test, fixed epochs (unitless)", s.get("median_ratio_fixed")),
                  ("age of differential median / max (s)", f"{s['age_s']['median']} / {s['age_s']['max']}"),
                  ("slips flagged rover / base", f"{s['slips_flagged_rover']} / {s['slips_flagged_base']}")])
    more = flat_pairs(s, PPK_SHOWN)
    if more:
        rep.heading("Further results")
        rep.kv_table(more)
    rep.warnings(run.warnings)
    add_honesty(rep, s.get("honesty") or ppk_honesty(run))
    ok = res.status >= 1
    if not ok.any():
        return rep.write(path)
    ref = run.reference_ecef if run.reference_ecef is not None else np.median(res.p[ok], axis=0)
    lat, lon, _ = ecef_to_geodetic(ref)
    R = R_ecef_to_enu(lat, lon)
    enu = (res.p - ref) @ R.T
    t = res.t_gps - res.t_gps[0]
    fig, axs = new_figure(9, 7, nrows=3, sharex=True)
    names = np.array([STATUS[k] for k in res.status])
    for i, (ax, lab) in enumerate(zip(axs, ("east", "north", "up"))):
        for st, col in _COLOURS.items():
            m = names == st
            if m.any():
                ax.plot(t[m], enu[m, i], ".", ms=3, color=col, label=st)
        ax.set_ylabel(f"{lab} (m)")
        ax.grid(alpha=0.3)
    axs[0].legend(loc="upper right")
    axs[-1].set_xlabel("time since first epoch (s)")
    what = "the reference position" if run.reference_ecef is not None else "the median position"
    rep.figure(fig, f"Position about {what}, coloured by solution status.")
    fig, ax = new_figure(9, 3)
    ax.step(t, res.n_sat, where="mid", label="satellites")
    ax2 = ax.twinx()
    ax2.semilogy(t, np.where(np.isfinite(res.ratio), res.ratio, np.nan), "k.", ms=2)
    ax.set_xlabel("time since first epoch (s)")
    ax.set_ylabel("satellites")
    ax2.set_ylabel("ambiguity ratio")
    rep.figure(fig, "Satellites with double differences and the ratio of the ambiguity test.")
    return rep.write(path)


def write_ppk_outputs(out_dir: str | Path, run: PpkRun, names: Mapping[str, str], report: bool = True
                      ) -> dict[str, Path]:
    """`dgcal pos --mode ppk`'s files in `out_dir`, by role in `names`: gnss (gnss.csv), gnss_summary (JSON),
    gnss_report (HTML, unless `report` is False); returns the paths by role. The summary gains the honesty record
    (`honesty`, see `ppk_honesty`)."""
    out = Path(out_dir)
    paths = {role: out / names[role] for role in ("gnss", "gnss_summary")}
    run.summary["honesty"] = ppk_honesty(run)
    write_ppk_csv(paths["gnss"], run.result)
    with atomic_write(paths["gnss_summary"]) as fh:
        json.dump(run.summary, fh, indent=2, default=float)
    if report:
        paths["gnss_report"] = out / names["gnss_report"]
        write_ppk_report(paths["gnss_report"], run)
    return paths
