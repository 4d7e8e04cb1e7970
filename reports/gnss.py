"""Files of a GNSS single-point positioning run: gnss.csv, its summary and the HTML report (track, sigma
envelopes, satellites, DOP, residuals), and the series the report plots.

matplotlib (through dgcal.reports.gnss_page) is imported only when a report is drawn: `write_spp_outputs(...,
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
from dgcal.reports.honesty import honesty_rows, honesty_section, no_reference

if TYPE_CHECKING:
    from dgcal.pos.gnss.spp import SppRun, SppSolution

SKY_EPOCHS = 200   # the sky plot shows the satellites of at most this many epochs, evenly spread


def spp_report_series(sol: SppSolution, ref_ecef: np.ndarray | None = None) -> dict:
    """What the SPP report plots, as plain arrays (no dgcal types: it pickles without the GNSS modules): ENU (m)
    of the fixes about ``ref_ecef`` (ECEF m; None: their median) with their ENU sigmas, satellites and PDOP of
    every epoch, post-fit code residuals (m) per satellite, and the sky directions (degrees) of the satellites used;
    times in s since the first fix."""
    ok = sol.ok
    empty = np.zeros(0)
    if not ok.any():
        return {"t_fix_s": empty, "reference_known": ref_ecef is not None, "residuals_m": {},
                "sky_azim_deg": empty, "sky_elev_deg": empty}
    ref = np.asarray(ref_ecef, float) if ref_ecef is not None else np.median(sol.p_ecef[ok], axis=0)
    lat, lon, _ = ecef_to_geodetic(ref)
    _, s_enu = enu_sigmas(sol.p_ecef[ok], sol.cov_p[ok])
    t0 = sol.t_gps[ok][0]
    rows: dict[str, list[tuple[float, float]]] = {}
    for k in np.nonzero(ok)[0]:
        for sat, r in sol.residuals_m[k].items():
            rows.setdefault(sat, []).append((sol.t_gps[k] - t0, r))
    used = [e for e in sol.epochs if e is not None]
    eps = used[:: max(1, len(used) // SKY_EPOCHS)]
    return {"t_fix_s": sol.t_gps[ok] - t0, "enu_m": (sol.p_ecef[ok] - ref) @ R_ecef_to_enu(lat, lon).T,
            "sigma_enu_m": s_enu, "reference_known": ref_ecef is not None,
            "t_s": sol.t_gps - t0, "n_sat": np.asarray(sol.n_sat), "pdop": np.asarray(sol.dop["pdop"]),
            "residuals_m": {sat: tuple(np.array(v).T) for sat, v in rows.items()},
            "sky_azim_deg": np.concatenate([e.azim_deg for e in eps]) if eps else empty,
            "sky_elev_deg": np.concatenate([e.elev_deg for e in eps]) if eps else empty}


TIME_CORRELATED = ("Errors of consecutive epochs are correlated in time: n overstates the number of independent "
                   "values.")


def spp_honesty(sol: SppSolution, ref_ecef: np.ndarray | None) -> dict:
    """The honesty record of an SPP run (dgcal.reports.honesty): every fix's E/N/U error against the known antenna
    position `ref_ecef` (ECEF m, taken as exact; ENU axes at the reference) over its sigma from the fix's covariance;
    without a reference the line that there is none."""
    if ref_ecef is None:
        return no_reference("No reference: give the antenna's known position (--reference X Y Z, ECEF m) to "
                            "compare the fixes with it.")
    ok = sol.ok
    ref = np.asarray(ref_ecef, float)
    lat, lon, _ = ecef_to_geodetic(ref)
    err = (sol.p_ecef[ok] - ref) @ R_ecef_to_enu(lat, lon).T
    sig = enu_sigmas(sol.p_ecef[ok], sol.cov_p[ok])[1] if ok.any() else np.zeros((0, 3))
    return honesty_section(honesty_rows(err, sig, ("E", "N", "U"), "known antenna position"),
                           ["Known antenna position (--reference), taken as exact: each fix's E/N/U error over "
                            "its sigma from the fix's covariance.", TIME_CORRELATED])


def write_spp_report(path: str | Path, sol: SppSolution, summary: dict, ref_ecef: np.ndarray | None = None) -> Path:
    """Write ``gnss_report.html`` for an ``SppSolution`` (``ref_ecef``: known position, else the median)."""
    from dgcal.reports.gnss_page import draw_spp_report   # why: matplotlib only when a report is drawn
    return draw_spp_report(path, spp_report_series(sol, ref_ecef), summary)


def write_spp_files(out_dir: str | Path, run: SppRun, names: Mapping[str, str]) -> dict[str, Path]:
    """gnss.csv (ECEF m) and the JSON summary of an SPP run in `out_dir`, named by role (`gnss`, `gnss_summary`) in
    `names`; returns the paths by role. The summary gains the honesty record (`honesty`, see `spp_honesty`)."""
    out = Path(out_dir)
    paths = {role: out / names[role] for role in ("gnss", "gnss_summary")}
    run.summary["honesty"] = spp_honesty(run.solution, run.reference_ecef)
    write_gnss_csv(paths["gnss"], run.solution)
    with atomic_write(paths["gnss_summary"]) as fh:
        json.dump(run.summary, fh, indent=2)
    return paths


def write_spp_outputs(out_dir: str | Path, run: SppRun, names: Mapping[str, str],
                      report: bool = True) -> dict[str, Path]:
    """`dgcal pos --mode spp`'s files in `out_dir`, named by role in `names`: gnss (gnss.csv, ECEF m),
    gnss_summary (JSON) and, unless `report` is False, gnss_report (HTML); returns the paths written by role.
    `run`: a dgcal.pos.gnss.spp.SppRun (or anything with its solution, summary and reference_ecef)."""
    paths = write_spp_files(out_dir, run, names)
    if report:
        paths["gnss_report"] = write_spp_report(Path(out_dir) / names["gnss_report"], run.solution, run.summary,
                                                run.reference_ecef)
    return paths
