"""Diagnostics of a camera calibration: parameter significance, high correlations, residual patterns.

The poor-fit test bins the residual vectors over the frame (a grid of cells) and compares each cell's
mean residual with its own standard error (from the scatter inside the cell, so a misfit that inflates
sigma0 cannot hide itself). Pure noise gives chi^2/dof ~ 1; a model that cannot follow the lens leaves
a smooth pattern with chi^2/dof >> 1 that also carries a sizeable share of the residual RMS.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from dgcal.calib.camera.models import CameraModel

DISTORTION_PARAMS = ("K1", "K2", "K3", "P1", "P2", "B1", "B2", "k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2")
RADIAL_PARAMS = {"K1", "K2", "K3", "k1", "k2", "k3", "k4", "k5", "k6"}


@dataclass
class ResidualPattern:
    """Binned residuals over the frame: cell centres (px), mean vectors (px), standard errors, counts."""

    centres: np.ndarray          # (C,2) px
    mean: np.ndarray             # (C,2) px
    stderr: np.ndarray           # (C,2) px
    count: np.ndarray            # (C,)
    chi2_per_dof: float          # of the cell means against their standard errors
    pattern_rms_px: float        # RMS length of the systematic part of the cell means
    residual_rms_px: float       # RMS residual norm of all used observations
    radial_centres: np.ndarray   # (R,) px from the principal point
    radial_mean: np.ndarray      # (R,) mean radial residual component, px
    radial_stderr: np.ndarray    # (R,)
    radial_chi2_per_dof: float   # of the radial means against their standard errors
    radial_pattern_rms_px: float  # RMS of the systematic radial profile

    @property
    def systematic(self) -> bool:
        """True when the cell means are far outside their noise and carry a real share of the residual."""
        return bool(self.chi2_per_dof > 4.0 and self.pattern_rms_px > 0.25 * self.residual_rms_px)

    @property
    def lens_misfit(self) -> bool:
        """True when a radial residual profile the distortion model cannot follow dominates the residuals."""
        return bool(self.radial_chi2_per_dof > 4.0 and self.radial_pattern_rms_px > 0.2 * self.residual_rms_px)


@dataclass
class Diagnostics:
    """Significance (t = value/sigma) of distortion terms, strong correlations, pattern test, warnings."""

    significance: dict[str, float]
    high_correlations: list[tuple[str, str, float]]
    pattern: ResidualPattern
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        """JSON-ready summary."""
        p = self.pattern
        return {
            "significance_t": self.significance,
            "high_correlations": [{"a": a, "b": b, "r": r} for a, b, r in self.high_correlations],
            "residual_pattern": {"chi2_per_dof": p.chi2_per_dof, "pattern_rms_px": p.pattern_rms_px,
                                 "radial_chi2_per_dof": p.radial_chi2_per_dof,
                                 "radial_pattern_rms_px": p.radial_pattern_rms_px,
                                 "residual_rms_px": p.residual_rms_px, "systematic": p.systematic,
                                 "lens_model_misfit": p.lens_misfit},
            "warnings": list(self.warnings),
        }


def significance(camera: CameraModel, free: np.ndarray) -> dict[str, float]:
    """t = value / sigma of every adjusted distortion parameter (|t| < 2: not significant)."""
    out = {}
    for k, v, s, f in zip(camera.PARAMS, camera.params, camera.sigmas, free):
        if f and k in DISTORTION_PARAMS and s > 0:
            out[k] = float(v / s)
    return out


def high_correlations(names, corr: np.ndarray, threshold: float = 0.9) -> list[tuple[str, str, float]]:
    """Pairs of parameters whose |correlation| exceeds `threshold`, strongest first."""
    out = []
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            r = corr[a, b]
            if np.isfinite(r) and abs(r) > threshold:
                out.append((names[a], names[b], float(r)))
    return sorted(out, key=lambda x: -abs(x[2]))


def residual_pattern(uv: np.ndarray, residuals: np.ndarray, image_size, principal_point,
                     cells=(8, 6), radial_bins: int = 10, min_count: int = 8,
                     used: np.ndarray | None = None, chunk: int = 100_000) -> ResidualPattern:
    """Mean residual vectors (px) in a grid of cells over the frame and along the radius, with noise; of the rows
    `used` (bool) only when given. Sums over `chunk` rows at a time (no copy of the observations)."""
    w, h = image_size
    cx_, cy_ = cells
    C = cx_ * cy_
    pp = np.asarray(principal_point, float)
    parts = [slice(a, min(a + chunk, len(uv))) for a in range(0, len(uv), chunk)]

    def rows(s):
        if used is None:
            return uv[s], residuals[s]
        u = used[s]
        return uv[s][u], residuals[s][u]
    count = np.zeros(C, np.int64)
    s1, s2 = np.zeros((C, 2)), np.zeros((C, 2))
    rad_max, sum_r2, n = 0.0, 0.0, 0
    for s in parts:
        q, r = rows(s)
        ix = np.clip((q[:, 0] / w * cx_).astype(int), 0, cx_ - 1)
        iy = np.clip((q[:, 1] / h * cy_).astype(int), 0, cy_ - 1)
        cell = iy * cx_ + ix
        count += np.bincount(cell, minlength=C)
        for k in range(2):
            s1[:, k] += np.bincount(cell, r[:, k], C)
            s2[:, k] += np.bincount(cell, r[:, k] ** 2, C)
        if len(q):
            rad_max = max(rad_max, float(np.linalg.norm(q - pp, axis=1).max()))
        sum_r2 += float(np.sum(r ** 2))
        n += len(q)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / count[:, None]
        var = (s2 - count[:, None] * mean**2) / np.maximum(count[:, None] - 1, 1)
        se = np.sqrt(np.maximum(var, 1e-12) / count[:, None])
    ok = count >= min_count
    chi2 = float(np.sum((mean[ok] / se[ok]) ** 2))
    dof = 2 * int(ok.sum())
    # the systematic part: squared mean minus its expected noise contribution, weighted by counts
    sys2 = np.maximum(np.sum(mean[ok] ** 2 - se[ok] ** 2, axis=1), 0)
    pattern_rms = float(np.sqrt(np.sum(sys2 * count[ok]) / max(count[ok].sum(), 1)))
    gx, gy = np.meshgrid((np.arange(cx_) + 0.5) * w / cx_, (np.arange(cy_) + 0.5) * h / cy_)
    centres = np.column_stack([gx.ravel(), gy.ravel()])
    edges = np.linspace(0, max(rad_max, 1.0) * (1 + 1e-9), radial_bins + 1)
    rc = np.zeros(radial_bins, np.int64)
    sv, sv2 = np.zeros(radial_bins), np.zeros(radial_bins)
    for s in parts:
        q, r = rows(s)
        d = q - pp
        rad = np.linalg.norm(d, axis=1)
        vr = np.sum(r * (d / np.maximum(rad, 1e-9)[:, None]), axis=1)
        b = np.clip(np.searchsorted(edges, rad, side="right") - 1, 0, radial_bins - 1)
        rc += np.bincount(b, minlength=radial_bins)
        sv += np.bincount(b, vr, radial_bins)
        sv2 += np.bincount(b, vr**2, radial_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        rm = sv / rc
        rv = (sv2 - rc * rm**2) / np.maximum(rc - 1, 1)
        rse = np.sqrt(np.maximum(rv, 1e-12) / rc)
    rok = rc >= min_count
    r_chi2 = float(np.sum((rm[rok] / rse[rok]) ** 2)) / max(int(rok.sum()), 1)
    r_sys = float(np.sqrt(np.sum(np.maximum(rm[rok] ** 2 - rse[rok] ** 2, 0) * rc[rok]) / max(rc[rok].sum(), 1)))
    return ResidualPattern(centres=centres, mean=np.where(ok[:, None], mean, np.nan),
                           stderr=np.where(ok[:, None], se, np.nan), count=count,
                           chi2_per_dof=chi2 / max(dof, 1), pattern_rms_px=pattern_rms,
                           residual_rms_px=float(np.sqrt(sum_r2 / n)) if n else float("nan"),
                           radial_centres=0.5 * (edges[1:] + edges[:-1]), radial_mean=rm, radial_stderr=rse,
                           radial_chi2_per_dof=r_chi2, radial_pattern_rms_px=r_sys)


def diagnose(result, corr_threshold: float = 0.9, reject_warn_fraction: float = 0.05,
             sigmas_given: bool = False) -> Diagnostics:
    """Significance, correlation and poor-fit warnings for an `intrinsic_ba.IntrinsicBAResult`;
    `sigmas_given`: the measurement sigmas were stated in px (then sigma0 >> 1 means a poor fit too)."""
    cam = result.camera
    names = list(cam.PARAMS)
    sig = significance(cam, result.free)
    corr = high_correlations(names, result.correlation, corr_threshold)
    pattern = residual_pattern(result.obs_xy, result.residuals, cam.image_size, cam.pinhole_K()[:2, 2],
                               used=result.used)
    warnings = []
    weak = [k for k, t in sig.items() if abs(t) < 2.0]
    if weak:
        warnings.append("distortion parameter(s) not significant (|value/sigma| < 2): " + ", ".join(weak)
                        + "; consider fixing them")
    within = [(a, b, r) for a, b, r in corr if a in RADIAL_PARAMS and b in RADIAL_PARAMS]
    if within:
        terms = sorted({x for a, b, _ in within for x in (a, b)}, key=names.index)
        warnings.append(f"radial terms {', '.join(terms)} are strongly correlated among themselves (up to "
                        f"{max(abs(r) for *_, r in within):.3f}): their single values mean little, the distortion "
                        "curve they make together is what is determined")
    for a, b, r in corr:
        if (a, b, r) not in within:
            warnings.append(f"high correlation {a}-{b}: {r:+.3f} (|r| > {corr_threshold})")
    if pattern.lens_misfit:
        msg = (f"poor model fit: systematic radial residual pattern (radial profile RMS "
               f"{pattern.radial_pattern_rms_px:.2f} px of {pattern.residual_rms_px:.2f} px residual RMS, "
               f"chi2/dof {pattern.radial_chi2_per_dof:.0f})")
        if cam.NAME == "fraser7":
            msg += ("; the fraser7 model does not fit this lens (wide-angle?) - use --model opencv8 (or fisheye, or "
                    "auto to compare them)")
        else:
            msg += "; the distortion model does not follow this lens"
        warnings.append(msg)
    elif pattern.systematic:
        warnings.append(f"systematic residual pattern over the frame that is not radial (cell means chi2/dof "
                        f"{pattern.chi2_per_dof:.1f}, pattern RMS {pattern.pattern_rms_px:.2f} px of "
                        f"{pattern.residual_rms_px:.2f} px): check the target coordinates (plate flatness or "
                        "scale: --refine-targets warp for a board's bow, free for any shape) and the "
                        "measurements")
    if sigmas_given and result.sigma0 > 3.0:
        warnings.append(f"the residuals are {result.sigma0:.1f} times the measurement sigmas given in the file "
                        "(sigma0); the model, the target coordinates or the stated sigmas are off")
    frac = result.n_rejected / max(len(result.used), 1)
    if frac > reject_warn_fraction:
        warnings.append(f"{result.n_rejected} of {len(result.used)} observations ({100 * frac:.1f} %) rejected "
                        "as outliers or left out")
    if result.dropped_images:
        warnings.append(f"{len(result.dropped_images)} image(s) left out: " + ", ".join(result.dropped_images[:10]))
    if not result.rejection_settled:
        warnings.append("the set of rejected observations was still changing when outlier rejection stopped; "
                        "the residuals may hold more outliers or a model misfit")
    if not result.converged:
        warnings.append("the adjustment did not converge within its iteration limit; check the results")
    return Diagnostics(significance=sig, high_correlations=corr, pattern=pattern, warnings=warnings)


def projection_difference(cam_a: CameraModel, cam_b: CameraModel, grid=(60, 40),
                          fit_rotation: bool = True, uv: np.ndarray | None = None) -> tuple[float, float, np.ndarray]:
    """RMS and max (px) of |project_b(R ray_a(uv)) - uv| over a pixel grid covering the frame (or the pixels `uv`,
    e.g. those of a valid region).

    R is the small rotation between the two camera frames that best aligns them (when fit_rotation),
    since every pose absorbs it and it means nothing for the calibration; returns (rms, max, R_a_to_b).
    """
    w, h = cam_a.image_size
    if uv is None:
        u, v = np.meshgrid(np.linspace(0, w - 1, grid[0]), np.linspace(0, h - 1, grid[1]))
        uv = np.column_stack([u.ravel(), v.ravel()])
    rays = cam_a.ray(uv)

    def diff(rv):
        return (cam_b.project(rays @ Rotation.from_rotvec(rv).as_matrix().T) - uv).ravel()

    rv = least_squares(diff, np.zeros(3), x_scale=1e-4).x if fit_rotation else np.zeros(3)
    d = np.linalg.norm(diff(rv).reshape(-1, 2), axis=1)
    return float(np.sqrt(np.mean(d**2))), float(d.max()), Rotation.from_rotvec(rv).as_matrix()
