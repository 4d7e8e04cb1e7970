"""Camera diagnostics on synthetic residuals: the poor-fit test, correlations, significance."""
import numpy as np

from dgcal.calib.selfcal.diagnostics import high_correlations, residual_pattern, significance
from dgcal.calib.camera.models import Fraser7

SIZE = (6000, 4000)
rng = np.random.default_rng(4)
uv = np.column_stack([rng.uniform(0, 5999, 20000), rng.uniform(0, 3999, 20000)])
noise = rng.normal(0, 0.3, uv.shape)
c = np.array([3000.0, 2000.0])


def test_pure_noise_is_not_a_pattern():
    p = residual_pattern(uv, noise, SIZE, c)
    assert 0.6 < p.chi2_per_dof < 1.5 and 0.6 < p.radial_chi2_per_dof < 1.8
    assert not p.systematic and not p.lens_misfit
    assert abs(p.residual_rms_px - 0.3 * np.sqrt(2)) < 0.02


def test_radial_misfit_is_a_lens_misfit():
    d = uv - c
    r = np.linalg.norm(d, axis=1, keepdims=True) / 3600
    radial = 0.4 * np.sin(3 * np.pi * r) * d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1)
    p = residual_pattern(uv, noise + radial, SIZE, c)
    assert p.lens_misfit and p.radial_pattern_rms_px > 0.15


def test_non_radial_pattern_is_systematic_but_not_a_lens_misfit():
    swirl = 0.4 * np.column_stack([np.sin(uv[:, 1] / 600), np.cos(uv[:, 0] / 700)])
    p = residual_pattern(uv, noise + swirl, SIZE, c)
    assert p.systematic and not p.lens_misfit


def test_correlations_and_significance():
    names = ["cx", "P1", "K1"]
    C = np.array([[1, 0.95, 0.1], [0.95, 1, np.nan], [0.1, np.nan, 1]])
    assert high_correlations(names, C) == [("cx", "P1", 0.95)]
    cam = Fraser7(SIZE, [4000, 3000, 2000, -0.1, 0, 0, 1e-5, 0, 0, 0])
    cam.sigmas = np.array([1, 1, 1, 0.001, 0.01, 0.01, 1e-5, 1e-5, 0.1, 0.1])
    t = significance(cam, np.ones(10, bool))
    assert abs(t["K1"] + 100) < 1e-9 and abs(t["P1"] - 1) < 1e-9 and "f" not in t
