"""Aerial-triangulation report: one HTML file (footprints, GCP and check-point residual vectors, per-image
sigmas, tables) and a JSON summary, from a `dgcal.bundle.triangulation.TriangulationResult`."""
from __future__ import annotations

import json
from functools import partial
from pathlib import Path

import numpy as np
from matplotlib.collections import PolyCollection

from dgcal.fields.io.csv_tables import atomic_write
from dgcal.reports.honesty import add_honesty, combined_sigma, honesty_rows, honesty_section, no_reference
from dgcal.reports.html import HtmlReport, new_figure
from dgcal.reports.tables import flat_pairs
from dgcal.reports.units import column_decimals, fmt_number


def triangulation_honesty(res, points=None) -> dict:
    """The honesty record of an aerial triangulation (dgcal.reports.honesty): every evaluated check point's error
    (grid E, N, Up) over its sigma from the adjustment, with the check point's survey sigma (`points`, a
    dgcal.fields.io.formats.Points; NaN or absent: taken as exact) in quadrature."""
    ev = [c for c in res.check if c.get("evaluated")]
    if not ev:
        return no_reference("No check point evaluated (none has the role check, or none is seen in two oriented "
                            "images): nothing independent to compare the adjustment with. Control points are not "
                            "a reference: the adjustment fits them.")
    err = np.array([c["dENU_m"] for c in ev], float)
    sig = np.array([c["sigma_ENU_m"] for c in ev], float)
    survey = np.zeros_like(sig)
    if points is not None:
        idx = points.index()
        survey = np.array([points.sigma[idx[c["id"]]] if c["id"] in idx else [np.nan] * 3 for c in ev], float)
    given = np.isfinite(survey).all(axis=1)
    rows = honesty_rows(err, combined_sigma(sig, np.where(np.isfinite(survey), survey, 0.0)), ("E", "N", "U"),
                        "check points")
    notes = ["Check points (role check, not in the adjustment's datum): each point's error (evaluated − given, grid "
             "E, N, height) over its sigma from the adjustment (adjusted as a tie point, or intersected from the "
             "adjusted images with their pose covariance)."]
    if given.all():
        notes.append("The check points' own survey sigmas (ground point file sx, sy, sz) are added in quadrature.")
    elif given.any():
        notes.append(f"The survey sigmas of the {int(given.sum())} check points that give them are added in "
                     f"quadrature; the other {int((~given).sum())} are taken as exact.")
    else:
        notes.append("The ground point file gives no survey sigma for the check points: they are taken as exact.")
    return honesty_section(rows, notes)


def summary_dict(res, honesty: dict | None = None) -> dict:
    """The JSON summary: global figures, per-image EOP sigmas, GCP residuals, check-point errors, the honesty record
    (`honesty`; None: `triangulation_honesty` without survey sigmas)."""
    d = dict(res.summary)
    d["images"] = [{**s, "X": res.eop.xyz[i].tolist(), "opk_deg": res.eop.opk[i].tolist()}
                   for i, s in enumerate(res.image_stats)]
    d["control_points"] = res.gcp
    d["check_points"] = res.check
    d["honesty"] = honesty if honesty is not None else triangulation_honesty(res)
    return _clean(d)


def _clean(v):
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, np.ndarray):
        return _clean(v.tolist())
    if isinstance(v, (np.floating, float)):
        return None if not np.isfinite(v) else float(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.bool_,)):
        return bool(v)
    if isinstance(v, np.str_):
        return str(v)
    return v


def write_summary_json(path: str | Path, res, honesty: dict | None = None) -> dict:
    """Write the JSON summary atomically (`summary_dict`); returns it."""
    d = summary_dict(res, honesty)
    with atomic_write(path) as fh:
        json.dump(d, fh, indent=1)
    return d


def _footprints(res) -> list[np.ndarray]:
    """Image corners projected to the mean control height, in grid E, N (m, map CRS)."""
    cam = res.camera
    w, h = cam.image_size
    corners = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], float)
    rays = cam.ray(corners)
    ctrl = np.array([res.bundle.X_world[j] for j, k in enumerate(res.point_kind) if k == "control"])
    z0 = float(np.mean(ctrl[:, 2])) if len(ctrl) else 0.0
    out = []
    for i in range(len(res.images)):
        d = rays @ res.R_world_to_cam[i]
        C = res.C_world[i]
        t = (z0 - C[2]) / np.where(np.abs(d[:, 2]) > 1e-9, d[:, 2], np.nan)
        P = C + np.where(t[:, None] > 0, t[:, None], np.nan) * d
        out.append(res.georef.to_map(P)[:, :2])
    return out


def write_bundle_report(path: str | Path, res, title: str = "Aerial triangulation", honesty: dict | None = None
                        ) -> Path:
    """Write the HTML report (one self-contained file) and return its path; `honesty`: the honesty record (None:
    `triangulation_honesty` without survey sigmas)."""
    s = res.summary
    rep = HtmlReport(title)
    if s.get("problems"):
        rep.warnings(["NOT TRUSTED (written with --accept-poor): " + "; ".join(s["problems"])])
    chk = s["check_rmse_m"]
    rep.headline([("check-point RMSE E / N / U (m)", _triple(chk)), ("check points evaluated", chk["n"]),
                  ("images oriented / given", f"{s['n_oriented']} / {s['n_images']}"),
                  ("σ0 (a posteriori, unitless)", s["sigma0"])],
                 "Aerial triangulation: the errors on the check points (not used in the adjustment).")
    rep.heading("Summary")
    rep.kv_table([("map CRS", s["crs"]), ("images oriented / given", f"{s['n_oriented']} / {s['n_images']}"),
                  ("control points used", s["n_control"]), ("tie points", s["n_tie_points"]),
                  ("observations", s["n_observations"]), ("σ0 (a posteriori, unitless)", s["sigma0"]),
                  ("redundancy", s["redundancy"]), ("RMS reprojection (px)", s["rms_px"]),
                  ("converged", s["converged"]),
                  ("control RMSE E / N / U (m)", _triple(s["control_rmse_m"])),
                  ("check RMSE E / N / U (m)", _triple(chk)), ("check points evaluated", chk["n"]),
                  ("camera", f"{s['camera']['model']}, "
                             f"refined: {', '.join(s['camera']['refined']) or 'none (fixed)'}")])
    more = flat_pairs(s, SUMMARY_SHOWN)
    if more:
        rep.heading("Datum and further results")
        rep.kv_table(more)
    rep.heading("Warnings")
    rep.warnings(s["warnings"])
    add_honesty(rep, honesty if honesty is not None else triangulation_honesty(res))
    rep.figure(partial(_map_figure, res), "Footprints at the mean control height (grey), control (green) and check "
               f"(red) points with their horizontal errors magnified {_arrow_scale(res):.0f} times.")
    rep.figure(partial(_sigma_figure, res), "Standard deviations of each image's projection centre and angles (map "
               "CRS).")
    # --- tables -----------------------------------------------------------------------------
    rep.heading("Control points")
    rep.table(["id", "images", "dE (m)", "dN (m)", "dU (m)", "RMS (px)", "max |w| (unitless)"],
              [[c["id"], c["n_images"], *c["dENU_m"], c["rms_px"],
                max([m["w"] for m in c["measurements"] if m["w"] is not None], default=float("nan"))]
               for c in res.gcp])
    rep.heading("Check points")
    rep.table(["id", "images", "dE (m)", "dN (m)", "dU (m)", "σE (m)", "σN (m)", "σU (m)"],
              [[c["id"], c["n_images"], *(c["dENU_m"] if c.get("evaluated") else [float("nan")] * 3),
                *(c["sigma_ENU_m"] if c.get("evaluated") else [float("nan")] * 3)] for c in res.check])
    rep.heading("Suspect measurements (standardised residual test)")
    if res.suspects:
        rep.table(["image", "id", "rx (px)", "ry (px)", "|w| (unitless)", "redundancy number (unitless)", "removed"],
                  [[x.image, x.point, *x.residual_px, x.w, x.redundancy, x.removed] for x in res.suspects])
    else:
        rep.text("No GCP measurement exceeds the critical standardised residual.", cls="ok")
    if s["unknown_points"]:
        rep.heading("Measured points not in the ground point file (used as tie points)")
        rep.table(["id", "images", "X coordinate (m)", "Y coordinate (m)", "Z coordinate (m)"],
                  [[u["id"], u["n_images"], *(u["xyz"] or [float("nan")] * 3)] for u in s["unknown_points"]
                   if not str(u["id"]).startswith("tie_")][:200])
    rep.heading("Images")
    rep.table(["image", "observations", "control observations", "RMS (px)", "σX (m)", "σY (m)", "σZ (m)", "σω (°)",
               "σφ (°)", "σκ (°)"],
              [[st["image"], st["n_obs"], st["n_control"], st["rms_px"], *st["sigma"]] for st in res.image_stats])
    return rep.write(path)


# summary keys the page shows in its own tables (or leaves to summary.json: the adjustment's bookkeeping); any other
# key, such as one a later version adds, is shown under "Datum and further results" (`flat_pairs`)
SUMMARY_SHOWN = {"crs", "sigma0", "redundancy", "converged", "n_images", "n_oriented", "n_control", "n_tie_points",
                 "n_observations", "rms_px", "control_rmse_m", "check_rmse_m", "camera", "warnings", "problems",
                 "unknown_points", "suspects", "images", "control_points", "check_points", "honesty", "timings_s",
                 "adjustment_runs", "rounds", "iterations", "stop_reason", "dropped_tie_observations", "trusted",
                 "n_unknown_ids"}


def _triple(d: dict) -> str:
    """E / N / U (m) of a record, one resolution for the three."""
    vals = [d.get(k) for k in ("E", "N", "U")]
    dec = column_decimals([v for v in vals if v is not None], "m")
    return " / ".join(fmt_number(v, "m", decimals=dec) for v in vals)


def _arrow_scale(res) -> float:
    """A magnification that turns typical residuals into arrows of ~5 % of the block size."""
    vals = [np.hypot(*c["dENU_m"][:2]) for c in res.gcp] + \
           [np.hypot(*c["dENU_m"][:2]) for c in res.check if c.get("evaluated")]
    span = float(np.ptp(res.eop.xyz[:, :2], axis=0).max()) if len(res.eop.xyz) > 1 else 1.0
    typical = float(np.median(vals)) if vals else 0.0
    if typical <= 0:
        return 1.0
    return float(10 ** np.round(np.log10(0.05 * max(span, 1e-3) / typical)))


def _map_figure(res):
    """Image footprints (one collection: a patch per image costs ~2 ms to make and draw), projection centres,
    control and check points with their horizontal errors magnified."""
    fig, ax = new_figure(8, 7)
    fps = [fp for fp in _footprints(res) if np.isfinite(fp).all()]
    if fps:
        ax.add_collection(PolyCollection(fps, facecolors="none", edgecolors="0.75", linewidths=0.6))
    ax.plot(res.eop.xyz[:, 0], res.eop.xyz[:, 1], ".", color="tab:blue", ms=4, label="projection centres")
    scale = _arrow_scale(res)
    if res.gcp:
        g = np.array([c["xyz"] for c in res.gcp])
        dg = np.array([c["dENU_m"] for c in res.gcp])
        ax.plot(g[:, 0], g[:, 1], "^", color="tab:green", label="control")
        ax.quiver(g[:, 0], g[:, 1], dg[:, 0], dg[:, 1], color="tab:green", angles="xy", scale_units="xy",
                  scale=1 / scale, width=0.004)
    ev = [c for c in res.check if c.get("evaluated")]
    if ev:
        c = np.array([x["xyz"] for x in ev])
        dc = np.array([x["dENU_m"] for x in ev])
        ax.plot(c[:, 0], c[:, 1], "s", color="tab:red", label="check")
        ax.quiver(c[:, 0], c[:, 1], dc[:, 0], dc[:, 1], color="tab:red", angles="xy", scale_units="xy",
                  scale=1 / scale, width=0.004)
    ax.set_aspect("equal")
    ax.set_xlabel("E (m)")
    ax.set_ylabel("N (m)")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"image footprints and horizontal residual vectors (x{scale:.0f})")
    return fig


def _sigma_figure(res):
    """Each image's projection-centre (cm) and angle (arcsec) standard deviations."""
    fig, axes = new_figure(9, 5, nrows=2, sharex=True)
    k = np.arange(len(res.images))
    for j, lab in enumerate(("σX", "σY", "σZ")):
        axes[0].plot(k, res.eop.sigma[:, j] * 100, ".-", lw=0.7, label=lab)
    for j, lab in enumerate(("σω", "σφ", "σκ")):
        axes[1].plot(k, res.eop.sigma[:, 3 + j] * 3600, ".-", lw=0.7, label=lab)
    axes[0].set_ylabel("projection centre σ (cm)")
    axes[1].set_ylabel("angle σ (arcsec)")
    axes[1].set_xlabel("image index")
    axes[0].legend(fontsize=8)
    axes[1].legend(fontsize=8)
    return fig
