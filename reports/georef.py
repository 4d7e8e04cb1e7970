"""The files of `dgcal georef` (single-image georeferencing): per-pixel ground points, per-point averages,
a JSON summary and a one-file HTML report (seed Fig. 19: each point's single-image estimates around their
covariance-weighted average), from a dgcal.calib.dg.single_image.GeorefRun."""
from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.ticker import MaxNLocator

from dgcal.calib.dg.single_image import GeorefRun, ImageGeoref
from dgcal.fields.io.csv_tables import atomic_write, write_table
from dgcal.reports.honesty import add_honesty, no_reference
from dgcal.reports.html import HtmlReport, new_figure

GEOREF_NO_REFERENCE = ("No reference: the ground points are not compared with known coordinates (χ²/dof above is "
                       "how the single-image estimates of a point agree with each other; check points: dgcal check).")


def write_georef_outputs(out_dir: str | Path, run: GeorefRun, names: Mapping[str, str]) -> dict[str, Path]:
    """Write, named by role in `names`, points (every pixel's ground point, map CRS m, with sigmas), average
    (per point id), summary (JSON) and report (HTML) into `out_dir`; returns the paths by role."""
    out = Path(out_dir)
    res, opts = run.result, run.options
    paths = {role: out / names[role] for role in ("points", "average", "summary", "report")}
    sig = np.sqrt(np.einsum("nii->ni", res.cov))
    write_table(paths["points"], ["image", "id", "x", "y", "z", "sx", "sy", "sz", "ok"],
                [[res.image[i], res.id[i], *res.xyz[i], *sig[i], int(res.ok[i])] for i in range(len(res.id))],
                fmt="%.4f")
    rows, js = [], {}
    for pid, (av, z) in res.averages.items():
        s2 = np.sqrt(np.diag(av.cov_with_common))
        rows.append([pid, *av.weighted, z, *s2, av.n, av.chi2_dof, *av.mean])
        js[pid] = {"xy_weighted": av.weighted.tolist(), "sigma_xy": s2.tolist(), "xy_mean": av.mean.tolist(),
                   "z": z, "n_images": av.n, "chi2_dof": av.chi2_dof}
    write_table(paths["average"], ["id", "x", "y", "z", "sx", "sy", "n_images", "chi2_dof", "x_mean", "y_mean"],
                rows, fmt="%.4f")
    src = "DEM " + str(opts.dem) if opts.dem else "laser ranges " + str(opts.ranges) if opts.ranges else \
        f"known height {opts.height} m"
    georef_report(res, opts.crs, src).write(paths["report"])
    with atomic_write(paths["summary"]) as fh:
        json.dump({"crs": opts.crs, "n_points": int(len(res.id)), "n_ok": int(res.ok.sum()),
                   "height_source": opts.height_source(), "averages": js,
                   "rejected_gross": [{"image": i, "id": k} for i, k in res.rejected],
                   "honesty": no_reference(GEOREF_NO_REFERENCE)}, fh, indent=2)
    return paths


def georef_report(res: ImageGeoref, crs: str, height_source: str) -> HtmlReport:
    """One-file report: per point the spread of its single-image estimates around the average (seed Fig. 19)."""
    rep = HtmlReport("dgcal single-image georeferencing")
    sig = [np.sqrt(np.diag(av.cov_with_common)) for av, _ in res.averages.values()]
    rep.headline([("points averaged", len(res.averages)),
                  ("median σ x, y of the averages (m)", np.median(sig, axis=0) if sig else None)],
                 "Ground points from single images (averaged over the images that see them), with 1-sigma.")
    rep.kv_table([("CRS", crs), ("height source", height_source), ("pixels", len(res.id)),
                  ("georeferenced", int(res.ok.sum()))])
    rows = []
    for pid, (av, z) in res.averages.items():
        s = np.sqrt(np.diag(av.cov_with_common))
        rows.append([pid, av.n, *np.round(av.weighted, 3), round(z, 3), *np.round(s, 3), round(av.chi2_dof, 2)])
    rep.table(["id", "images", "x (m)", "y (m)", "z (m)", "σx (m)", "σy (m)", "χ²/dof (unitless)"], rows)
    add_honesty(rep, no_reference(GEOREF_NO_REFERENCE))
    ids = list(res.averages)[:6]
    if ids:
        ncols = min(3, len(ids))
        nrows = -(-len(ids) // ncols)
        fig, axes = new_figure(3.6 * ncols, 3.6 * nrows, ncols=ncols, nrows=nrows, squeeze=False)
        for ax in axes.ravel()[len(ids):]:
            ax.set_visible(False)
        t = np.linspace(0, 2 * np.pi, 100)
        for ax, pid in zip(axes.ravel(), ids):
            ax.xaxis.set_major_locator(MaxNLocator(nbins=4))
            ax.yaxis.set_major_locator(MaxNLocator(nbins=4))
            av, _ = res.averages[pid]
            m = (res.id == pid) & res.ok
            d = res.xyz[m][:, :2] - av.weighted
            ax.scatter(d[:, 0], d[:, 1], s=14, label="single images")
            w, V = np.linalg.eigh(res.cov[m][:, :2, :2].mean(axis=0))
            ell = (V * np.sqrt(np.maximum(w, 0) * 5.99)) @ np.vstack([np.cos(t), np.sin(t)])
            ax.plot(ell[0], ell[1], "C1", lw=1, label="mean single-image 95 %")
            ax.plot(0, 0, "k+", ms=12, label="weighted average")
            ax.set_title(str(pid))
            ax.set_xlabel("dE (m)")
            ax.set_ylabel("dN (m)")
            ax.set_aspect("equal", adjustable="datalim")
        axes[0][0].legend(fontsize=7)
        rep.figure(fig, "Single-image estimates around their covariance-weighted average")
    return rep
