"""The camera calibration report: one HTML file with the parameters and their sigmas, warnings, the model
comparison (`--model auto`), the projection-uncertainty map with the valid region, the residual vectors over the
frame, distortion curves, the correlation matrix, per-image RMS and the frames chosen from videos."""
from __future__ import annotations

from functools import partial

from pathlib import Path

import numpy as np

from dgcal.calib.selfcal.calibration import CameraCalibration, write_camera_outputs
from dgcal.calib.selfcal.diagnostics import residual_pattern
from dgcal.calib.selfcal.uncertainty import UncertaintyMap
from dgcal.reports.honesty import add_honesty, no_reference
from dgcal.reports.distortion import CAPTION as DISTORTION_CAPTION
from dgcal.reports.distortion import distortion_figure as model_distortion_figure
from dgcal.reports.html import HtmlReport, new_figure
from dgcal.reports.tables import parameter_rows, parameter_unit
from dgcal.reports.units import pm, with_unit

PLOTTED_POINTS = 200_000    # observations drawn as dots at most (an even subsample of more)


def _plotted(mask: np.ndarray) -> np.ndarray:
    """Rows where `mask` is true, every k-th of them when there are more than PLOTTED_POINTS."""
    rows = np.flatnonzero(mask)
    return rows[::-(-len(rows) // PLOTTED_POINTS)] if len(rows) > PLOTTED_POINTS else rows


def residual_vector_figure(cal: CameraCalibration, cells=(16, 11)):
    """Mean residual vectors (px, exaggerated) in cells over the frame, over the observation coverage."""
    ba = cal.ba
    w, h = ba.camera.image_size
    u = ba.used
    pat = residual_pattern(ba.obs_xy, ba.residuals, (w, h), ba.camera.pinhole_K()[:2, 2], cells=cells,
                           min_count=3, used=u)
    fig, ax = new_figure(9, 9 * h / w + 0.8)
    # at most PLOTTED_POINTS of each kind (an even subsample: 5 M dots would not show more, but cost GBs)
    used_rows, rejected_rows = _plotted(u), _plotted(~u)
    ax.plot(ba.obs_xy[used_rows, 0], ba.obs_xy[used_rows, 1], ",", color="0.7")
    if len(rejected_rows):
        ax.plot(ba.obs_xy[rejected_rows, 0], ba.obs_xy[rejected_rows, 1], "x", color="tab:red", ms=3,
                label="rejected")
        ax.legend(loc="upper right", fontsize=8)
    ok = np.isfinite(pat.mean[:, 0])
    mag = np.linalg.norm(pat.mean[ok], axis=1)
    ref = float(np.percentile(mag, 90)) if mag.size else 1.0
    ref = max(ref, 1e-3)
    scale = (w / cells[0]) / ref  # the 90th percentile vector spans about one cell
    q = ax.quiver(pat.centres[ok, 0], pat.centres[ok, 1], pat.mean[ok, 0], pat.mean[ok, 1], angles="xy",
                  scale_units="xy", scale=1 / scale, color="tab:blue", width=0.003)
    key = float(f"{ref:.1g}")
    ax.quiverkey(q, 0.12, -0.06, key, f"{key:g} px", labelpos="E", coordinates="axes")
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_aspect("equal")
    ax.set_title("mean residual (projected - measured) per cell; grey: observations")
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    return fig


def distortion_figure(cal: CameraCalibration):
    """Radial (positive outward) and tangential distortion (px) against the image radius: the one curve of every
    report (dgcal.reports.distortion)."""
    return model_distortion_figure(cal.camera)


def correlation_figure(cal: CameraCalibration):
    """The correlation matrix of the adjusted camera parameters."""
    ba = cal.ba
    idx = np.flatnonzero(ba.free)
    names = [ba.camera.PARAMS[i] for i in idx]
    C = ba.correlation[np.ix_(idx, idx)]
    fig, ax = new_figure(6.5, 5.5)
    im = ax.imshow(C, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(len(names)), names, rotation=90)
    ax.set_yticks(range(len(names)), names)
    for a in range(len(names)):
        for b in range(len(names)):
            if a != b and abs(C[a, b]) > 0.9:
                ax.text(b, a, f"{C[a, b]:.2f}", ha="center", va="center", fontsize=6)
    fig.colorbar(im, ax=ax, shrink=0.8)
    ax.set_title("parameter correlations (|r| > 0.9 labelled)")
    return fig


def per_image_figure(cal: CameraCalibration):
    """RMS residual (px) of every image."""
    rms = cal.ba.per_image_rms()
    names = list(rms)
    vals = np.array([rms[n] for n in names])
    fig, ax = new_figure(max(6, min(18, 0.12 * len(names) + 3)), 3.6)
    ax.bar(range(len(names)), np.nan_to_num(vals), color="tab:blue")
    ax.axhline(cal.ba.rms_px, color="tab:red", lw=1, label=f"overall {cal.ba.rms_px:.3f} px")
    if len(names) <= 60:
        ax.set_xticks(range(len(names)), names, rotation=90, fontsize=6)   # constrained layout makes room below
    else:
        ax.set_xlabel("image (in the order of camera.json)")
    ax.set_ylabel("RMS (px)")
    ax.set_title("per-image RMS residual")
    ax.legend(fontsize=8)
    return fig


def radial_profile_figure(cal: CameraCalibration):
    """Mean radial residual (px) against the distance from the principal point, with 2 sigma bars."""
    p = cal.diagnostics.pattern
    fig, ax = new_figure(7, 3.6)
    ok = np.isfinite(p.radial_mean)
    ax.errorbar(p.radial_centres[ok], p.radial_mean[ok], yerr=2 * p.radial_stderr[ok], fmt="o-", capsize=3)
    ax.axhline(0, color="0.5", lw=0.8)
    ax.set_xlabel("distance from principal point (px)")
    ax.set_ylabel("mean radial residual (px)")
    ax.set_title("radial residual profile (a lens the model cannot follow leaves a curve here)")
    ax.grid(alpha=0.3)
    return fig


def stations_figure(cal: CameraCalibration):
    """Projection centres of the used images around the targets: plan (x, y) and side (x, z) views, m."""
    ba = cal.ba
    C, _ = ba.camera_centres()
    ok = np.isfinite(C[:, 0])
    X = ba.points_xyz[np.bincount(ba.obs_point[ba.used], minlength=len(ba.points_xyz)) > 0]
    fig, axes = new_figure(9, 4.2, ncols=2)
    for ax, (a, b), lab in zip(axes, ((0, 1), (0, 2)), ("plan view (x, y)", "side view (x, z)")):
        ax.plot(X[:, a], X[:, b], ".", ms=1.5, color="0.5", label="targets")
        ax.plot(C[ok, a], C[ok, b], "^", color="tab:orange", ms=5, label="cameras")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(lab)
        ax.set_xlabel("xyz"[a] + " (m)")
        ax.set_ylabel("xyz"[b] + " (m)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    return fig


def _outline(ax, cal: CameraCalibration) -> None:
    """The valid region's parts on a frame plot: observed hull (solid) and the monotonic boundary (dashed)."""
    reg = cal.region
    if reg is None:
        return
    if reg.observed is not None:
        h = np.vstack([reg.observed, reg.observed[:1]])
        ax.plot(h[:, 0], h[:, 1], "-", color="white", lw=2.2)
        ax.plot(h[:, 0], h[:, 1], "-", color="black", lw=1.0, label="observed region (hull)")
    if not reg.whole_frame_monotonic:
        m = np.vstack([reg.monotonic, reg.monotonic[:1]])
        ax.plot(m[:, 0], m[:, 1], "--", color="tab:red", lw=1.2, label="fold of the model (monotonic region)")


def uncertainty_figure(cal: CameraCalibration, umap: UncertaintyMap | None = None, title: str = ""):
    """Maps of the worst-direction projection sigma (px, log colour scale) over the frame, at the map's range and
    at infinity, with the valid region outlined."""
    u = cal.uncertainty if umap is None else umap
    w, h = cal.camera.image_size
    fig, axes = new_figure(11, 11 * h / w / 2 + 1.3, ncols=2)
    reg_uv = cal.region.grid((41, 29)) if cal.region is not None else np.zeros((0, 2))
    inside = u.at(reg_uv, infinity=True) if len(reg_uv) else u.sigma_infinity.ravel()
    lo = max(float(np.nanmin(u.sigma_range)), 1e-6)
    hi = float(np.nanpercentile(inside, 100)) * 30 if len(inside) else float(np.nanmax(u.sigma_infinity))
    hi = max(hi, 2 * lo)
    from matplotlib.colors import LogNorm
    panels = ((axes[0], u.sigma_range, f"at {u.range_m:.3g} m"), (axes[1], u.sigma_infinity, "at infinity"))
    for ax, grid, lab in panels:
        im = ax.imshow(np.clip(grid, lo, hi), extent=(u.u[0], u.u[-1], u.v[-1], u.v[0]), norm=LogNorm(lo, hi),
                       cmap="viridis", aspect="equal", interpolation="bilinear")
        levels = [x for x in (0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100) if lo < x < hi]
        if levels:
            cs = ax.contour(u.u, u.v, grid, levels=levels, colors="white", linewidths=0.6)
            ax.clabel(cs, fmt="%g", fontsize=7)
        _outline(ax, cal)
        ax.set_xlim(0, w - 1)
        ax.set_ylim(h - 1, 0)
        ax.set_title(f"{title or u.model}: projection sigma {lab} (px)", fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.8)
    axes[0].legend(fontsize=7, loc="lower right")
    return fig


def build_camera_report(cal: CameraCalibration, title: str = "dgcal camera calibration") -> HtmlReport:
    """The report page (not yet written)."""
    ba, cam = cal.ba, cal.camera
    rep = HtmlReport(title)
    head = [(f"{k} (px)", pm(v, s, "px", signed=False)) for k, v, s, f in zip(cam.PARAMS, cam.params, cam.sigmas,
                                                                              ba.free)
            if parameter_unit(k) == "px" and k.lower() not in ("b1", "b2")]
    rep.headline(head + [("RMS residual per point (px)", ba.rms_px), ("σ0 (a posteriori, unitless)", ba.sigma0)],
                 f"Camera {cam.NAME}, {cam.image_size[0]} × {cam.image_size[1]} px: focal length and principal "
                 "point with 1-sigma (all parameters below).")
    rep.heading("Summary")
    rep.kv_table([("model", cam.NAME), ("image size (px)", f"{cam.image_size[0]} × {cam.image_size[1]}"),
                  ("images used", len(ba.image_names) - len(ba.dropped_images)),
                  ("observations used", ba.n_observations), ("observations rejected", ba.n_rejected),
                  ("RMS residual per point (px)", ba.rms_px), ("σ0 (a posteriori, unitless)", ba.sigma0),
                  ("redundancy", ba.redundancy), ("target coordinates refined", ba.refine_targets),
                  ("converged", bool(ba.converged))])
    rep.heading("Warnings")
    rep.warnings(cal.warnings)
    add_honesty(rep, no_reference("No reference: nothing independent of the adjustment to compare the camera with "
                                  "(a simulation's truth: the campaign report; the residuals and the cross-validation "
                                  "of --model auto check the fit, not the sigmas)."))
    if cal.comparison is not None:
        rep.heading("Model comparison (--model auto)")
        cols = ["model", "RMS (px)", "free parameters", "radial χ²/dof (unitless)", "radial pattern (px)",
                "valid fraction (unitless)", "cross-validation RMS (px)", "cross-validation max (px)",
                "cross-validation / noise (unitless)", "verdict"]
        rows = []
        for f in cal.comparison.fits.values():
            r = f.row()
            rows.append([r["model"], r["rms_px"], r["n_free_parameters"], r["radial_chi2_per_dof"],
                         r["radial_pattern_rms_px"], r["valid_fraction"], r["cv_rms_px"], r["cv_max_px"], r["cv_ratio"],
                         "chosen" if f.name == cal.comparison.chosen else (f.rejected or "not chosen")])
        rep.table(cols, rows)
        for r in cal.comparison.reasons:
            rep.text(r)
    if cal.uncertainty is not None:
        rep.heading("Projection uncertainty and valid region")
        rep.text(f"{cal.uncertainty.summary(cal.region)}. " + (cal.region.describe() if cal.region else ""))
        rep.figure(partial(uncertainty_figure, cal), "Worst-direction standard deviation of the projection of a point "
                   "seen at each pixel (the intrinsics' and the poses' covariance propagated, as mrcal does). Black: "
                   "the region the observations cover; dashed red: where the model folds. Outside the black outline "
                   "the model is an extrapolation.")
        if cal.opencv_uncertainty is not None:
            rep.figure(partial(uncertainty_figure, cal, cal.opencv_uncertainty, "OpenCV block"),
                       f"The same for the OpenCV block (a conversion fitted inside the valid region, max error "
                       f"{with_unit(cal.conversion_errors.get('opencv', 0), 'px')} there).")
    rep.heading("Parameters")
    sig = cal.diagnostics.significance
    rep.table(["parameter", "unit", "value (unit column)", "σ (unit column)", "t = value/σ (unitless)"],
              parameter_rows(cam.PARAMS, cam.params, [s if f else None for s, f in zip(cam.sigmas, ba.free)],
                             [sig.get(k) for k in cam.PARAMS]))
    rep.text("Sigmas come from the adjustment covariance scaled by σ0². px: pixels, OpenCV convention (origin at the "
             "centre of the top-left pixel); the distortion coefficients are unitless (they act on normalised image "
             "coordinates). σ '–': held fixed.", "small")
    rep.heading("Residuals over the frame")
    rep.figure(partial(residual_vector_figure, cal), "Cell means of the residual vectors, exaggerated; a systematic "
               "swirl or radial pattern means the model or the target coordinates do not fit.")
    rep.figure(partial(radial_profile_figure, cal))
    rep.heading("Distortion")
    rep.figure(partial(distortion_figure, cal), DISTORTION_CAPTION)
    rep.heading("Correlations")
    rep.figure(partial(correlation_figure, cal))
    rep.heading("Per-image RMS")
    rep.figure(partial(per_image_figure, cal))
    rep.heading("Camera stations")
    rep.figure(partial(stations_figure, cal), "Projection centres of the used images (poses.csv) in the field frame.")
    if cal.frames is not None:
        rep.heading("Frames")
        rep.text(f"frames looked at: {cal.frames.summary()}; video frames are chosen by sharpness and coverage "
                 "diversity (all of them in frames.csv)")
        rows = cal.frames.rows()
        rep.table(["frame", "source", "number", "time (s)", "corners", "sharpness (unitless)", "status"], rows[:300])
        if len(rows) > 300:
            rep.text(f"... and {len(rows) - 300} more in frames.csv.", "small")
    if ba.rejected:
        rep.heading("Rejected observations")
        shown = sorted(ba.rejected, key=lambda r: -(r.residual_px if r.residual_px == r.residual_px else 0))[:200]
        rep.table(["image", "id", "residual (px)", "reason"],
                  [[r.image, r.id, r.residual_px, r.reason] for r in shown])
        if len(ba.rejected) > len(shown):
            rep.text(f"... and {len(ba.rejected) - len(shown)} more (all listed in camera.json).", "small")
    return rep


def write_camera_report(cal: CameraCalibration, path: str | Path) -> Path:
    """Write the one-file HTML report."""
    return build_camera_report(cal).write(path)


def write_camera_files(out_dir: str | Path, cal: CameraCalibration, names: dict[str, str],
                       report: bool = True) -> dict[str, Path]:
    """`dgcal camera`'s files in `out_dir`, named by role in `names`: the camera and its conversions
    (`write_camera_outputs`) and, with `report`, the HTML report (role report); returns the paths by role."""
    paths = write_camera_outputs(cal, out_dir, names)
    if report:
        paths["report"] = write_camera_report(cal, Path(out_dir) / names["report"])
    return paths
