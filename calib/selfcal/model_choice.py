"""Which camera model fits this lens: fraser7, opencv8 and fisheye fitted on the same data and compared.

Evidence, per model:
- the fit: RMS residual, and the residual pattern (dgcal.calib.selfcal.diagnostics): a radial profile the model
  cannot follow (lens misfit) rejects it;
- the valid region (dgcal.calib.camera.region): a model that folds inside the observed part of the frame is
  rejected;
- cross-validation: the images are split into two halves (alternate images), each half re-adjusted from the
  full solution, and the two halves' cameras compared over the valid region (projection difference after the best
  common rotation, which the poses absorb). A model that follows the lens and the data reproduces itself: the
  difference is what the noise explains (`cv_ratio`, the RMS difference over the one the halves' projection
  covariance predicts once the common rotation is removed, is about 1); a model that cannot follow the lens
  gives a ratio well above 1.

The choice (`--model auto`): among the models not rejected and whose RMS is within `rms_tolerance` of the best,
the one with the smallest cross-validation difference, or the one with fewest free parameters whose difference is
within `cv_tolerance` of that smallest (simpler when the data cannot tell them apart). Every step is given as a
reason.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dgcal.calib.camera.models import model_class
from dgcal.calib.camera.region import ValidRegion, hull_candidates
from dgcal.calib.selfcal.adjustment import IntrinsicBAResult, adjust, refit
from dgcal.calib.selfcal.diagnostics import Diagnostics, diagnose, projection_difference
from dgcal.calib.selfcal.uncertainty import aligned_difference_expectation
from dgcal.fields.errors import InputError

COMPARED = ("fraser7", "opencv8", "fisheye")


@dataclass
class ModelFit:
    """One model fitted on the data, with its diagnostics, valid region and cross-validation figures."""

    name: str
    ba: IntrinsicBAResult
    diagnostics: Diagnostics
    region: ValidRegion
    n_free: int
    cv_rms_px: float = float("nan")     # RMS projection difference of the two halves over the valid region
    cv_max_px: float = float("nan")
    cv_ratio: float = float("nan")      # cv_rms / the RMS difference the halves' uncertainty predicts
    rejected: str = ""                  # why the model was rejected ("" = a candidate)

    def row(self) -> dict:
        """Figures for camera.json and the report."""
        p = self.diagnostics.pattern
        return {"model": self.name, "rms_px": self.ba.rms_px, "n_free_parameters": self.n_free,
                "radial_chi2_per_dof": p.radial_chi2_per_dof, "radial_pattern_rms_px": p.radial_pattern_rms_px,
                "cell_chi2_per_dof": p.chi2_per_dof, "lens_model_misfit": p.lens_misfit,
                "valid_fraction": self.region.fractions()["valid"], "cv_rms_px": self.cv_rms_px,
                "cv_max_px": self.cv_max_px, "cv_ratio": self.cv_ratio, "rejected": self.rejected or None}


@dataclass
class ModelComparison:
    """All fits, the chosen model's name and the reasons for the choice."""

    fits: dict[str, ModelFit]
    chosen: str
    reasons: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON form."""
        return {"chosen": self.chosen, "reasons": list(self.reasons),
                "models": [f.row() for f in self.fits.values()],
                "cross_validation": "images split into alternate halves, each re-adjusted; projection difference "
                                    "of the two halves' cameras over the valid region after the best common rotation"}


def cross_validate(ba: IntrinsicBAResult, region: ValidRegion) -> tuple[float, float, float]:
    """(RMS, max, ratio to the noise expectation) of the projection difference (px) between cameras adjusted on
    alternate halves of the images, over the valid region; NaN when there are too few images."""
    names = [n for n, c in zip(ba.image_names, np.bincount(ba.obs_image[ba.used], minlength=len(ba.image_names)))
             if c > 0 and n not in ba.dropped_images]
    if len(names) < 6:
        return float("nan"), float("nan"), float("nan")
    halves = [refit(ba, names[0::2]), refit(ba, names[1::2])]
    uv = region.grid((41, 29))
    if len(uv) < 10:
        uv = region.grid((121, 81))
    if len(uv) < 3:
        return float("nan"), float("nan"), float("nan")
    with np.errstate(all="ignore"):
        rms, mx, _ = projection_difference(halves[0].camera, halves[1].camera, uv=uv)
        sub = uv[:: max(1, len(uv) // 400)]      # the joint covariance of at most ~400 pixels
        expect = aligned_difference_expectation(halves, sub)
    return float(rms), float(mx), float(rms / expect) if expect > 0 else float("nan")


def fit_model(name: str, args: tuple, fixed=(), sigmas_given: bool = False, **kw) -> ModelFit:
    """Adjust one model (`args` = adjust's positional inputs, `fixed` filtered to the model's parameters)."""
    cls = model_class(name)
    fx = tuple(k for k in fixed if k in cls.PARAMS)
    ba = adjust(*args, model=name, fixed=fx, **kw)
    dg = diagnose(ba, sigmas_given=sigmas_given)
    region = ValidRegion.of(ba.camera, hull_candidates(ba.obs_xy, ba.used))
    return ModelFit(name, ba, dg, region, int(ba.free.sum()))


def compare_models(field_ids, field_xyz, meas_image, meas_id, meas_xy, image_size, meas_sigma=None,
                   models=COMPARED, fixed=(), rms_tolerance: float = 0.10, cv_tolerance: float = 0.25,
                   progress=None, sigmas_given: bool = False, **adjust_kw) -> ModelComparison:
    """Fit `models` on the same measurements, cross-validate each, and choose one (see the module doc)."""
    args = (field_ids, field_xyz, meas_image, meas_id, meas_xy, image_size)
    fits: dict[str, ModelFit] = {}
    errors = {}
    for name in models:
        try:
            f = fit_model(name, args, fixed, sigmas_given, meas_sigma=meas_sigma, progress=progress, **adjust_kw)
        except InputError as exc:
            errors[name] = str(exc)
            continue
        fits[name] = f
    if not fits:
        raise InputError("no camera model could be fitted: " + "; ".join(f"{k}: {v}" for k, v in errors.items()))
    reasons = [f"{k}: not fitted ({v})" for k, v in errors.items()]
    best_rms = min(f.ba.rms_px for f in fits.values())
    for f in fits.values():
        p = f.diagnostics.pattern
        obs_frac = f.region.fractions()
        if p.lens_misfit:
            f.rejected = (f"radial residual pattern: the model does not follow the lens (profile RMS "
                          f"{p.radial_pattern_rms_px:.2f} px, chi2/dof {p.radial_chi2_per_dof:.0f}; "
                          f"RMS {f.ba.rms_px:.3g} px)")
        elif f.ba.rms_px > (1 + rms_tolerance) * best_rms:
            f.rejected = (f"RMS {f.ba.rms_px:.3g} px is {100 * (f.ba.rms_px / best_rms - 1):.0f} % above the best "
                          f"({best_rms:.3g} px)")
        elif obs_frac["valid"] < 0.98 * obs_frac["observed"]:
            f.rejected = "the model folds (d r_d/d r <= 0) inside the observed part of the frame"
        elif not f.ba.converged:
            f.rejected = "the adjustment did not converge"
    for f in fits.values():
        if not f.rejected:
            f.cv_rms_px, f.cv_max_px, f.cv_ratio = cross_validate(f.ba, f.region)
    cands = [f for f in fits.values() if not f.rejected]
    if not cands:
        # nothing passes: the best RMS, said loudly
        chosen = min(fits.values(), key=lambda f: f.ba.rms_px)
        reasons += [f"{f.name} rejected: {f.rejected}" for f in fits.values()]
        reasons.append(f"no model passes; {chosen.name} has the lowest RMS and is kept, but do not trust it")
        return ModelComparison(fits, chosen.name, reasons)
    with_cv = [f for f in cands if np.isfinite(f.cv_rms_px)]
    if with_cv:
        cv_best = min(f.cv_rms_px for f in with_cv)
        near = [f for f in with_cv if f.cv_rms_px <= (1 + cv_tolerance) * cv_best]
        chosen = min(near, key=lambda f: (f.n_free, f.cv_rms_px))
    else:
        cv_best = float("nan")
        chosen = min(cands, key=lambda f: (f.ba.rms_px, f.n_free))
    for f in fits.values():
        if f.rejected:
            reasons.append(f"{f.name} rejected: {f.rejected}")
    for f in cands:
        if f is chosen:
            continue
        if np.isfinite(f.cv_rms_px) and np.isfinite(cv_best) and f.cv_rms_px > (1 + cv_tolerance) * cv_best:
            reasons.append(f"{f.name}: cross-validation difference {f.cv_rms_px:.3g} px RMS, more than "
                           f"{100 * cv_tolerance:.0f} % above {chosen.name}'s {chosen.cv_rms_px:.3g} px")
        else:
            reasons.append(f"{f.name}: fits as well (RMS {f.ba.rms_px:.3g} px, cross-validation "
                           f"{f.cv_rms_px:.3g} px) with {f.n_free} free parameters; {chosen.name} has {chosen.n_free}"
                           + (" (fewer: preferred)" if chosen.n_free < f.n_free else ""))
    cv_txt = (f"cross-validation difference {chosen.cv_rms_px:.3g} px RMS over the valid region "
              f"({chosen.cv_ratio:.1f} x the noise expectation)" if np.isfinite(chosen.cv_rms_px)
              else "too few images to cross-validate")
    reasons.append(f"chose {chosen.name}: RMS {chosen.ba.rms_px:.3g} px, no lens misfit, {cv_txt}")
    return ModelComparison(fits, chosen.name, reasons)
