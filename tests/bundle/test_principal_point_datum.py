"""The principal point against the horizontal datum in aerial triangulation with cx/cy refined
(`dgcal.bundle.datum.principal_point_correlation`): a flat nadir block cannot separate cx/cy from the centres'
shift along the image axes (a shift of d px is a shift of H d/f of the centres), which is warned about with the
figure and the remedies; tilted images with cross strips at two heights separate them; the figure is the multiple
correlation of the adjustment's covariance, checked against the inverse of the whole normal matrix.

The blocks are `dgcal.sim.block`'s: the RTK-drone family (35 mm on 8192 x 5460 px, 150 m, RTK centres 2/2/5 cm,
0 GCPs) over flat ground, and the same camera in cross strips at 150 and 250 m with 15 deg tilts."""
import html
import json
import warnings

import numpy as np
import pytest

from dgcal.bundle import triangulation as triangulation_mod
from dgcal.bundle.datum import PP_CORRELATION, pp_combinations, principal_point_correlation
from dgcal.bundle.triangulation import TriangulationOptions, triangulate
from dgcal.sim.block import BlockPattern, p1_35mm_camera, simulate_block, simulate_rtk_block
from test_gnss_supported_at import RTK, approx_of, triangulate_block_cli

WARNING = "principal point and horizontal datum are correlated"


def _run(sim, refine=("cx", "cy")):
    """Triangulate with `refine`; (result, the UserWarnings' texts)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = triangulate(sim.camera, sim.points, sim.measurements, sim.crs, TriangulationOptions(refine=refine),
                          approx=approx_of(sim), centre_priors=sim.centres)
    return res, [str(w.message) for w in caught if issubclass(w.category, UserWarning)]


def _separating_pattern(n_strips=(3, 2), per_strip=(8, 6), cross=2) -> BlockPattern:
    """Cross strips at 150 and 250 m over flat ground, images tilted by 15 deg (sigma per axis)."""
    return BlockPattern(heights_m=(150.0, 250.0), n_strips=n_strips, images_per_strip=per_strip, cross_strips=cross,
                        forward_overlap=0.8, side_overlap=0.7, terrain_amplitude_m=0.0, jitter_deg=(15.0, 15.0, 1.0),
                        jitter_m=(1.0, 1.0, 0.5))


@pytest.fixture(scope="module")
def flat_nadir():
    """The 48-image RTK block over flat ground, cx/cy refined: (sim, result, warnings)."""
    sim = simulate_rtk_block(0, n_images=48, terrain_amplitude_m=0.0)
    return (sim, *_run(sim))


def test_a_flat_nadir_block_warns_that_the_principal_point_follows_the_centres(flat_nadir):
    sim, res, caught = flat_nadir
    pp = res.summary["principal_point"]
    assert res.summary["f_height"] is None and pp["parameters"] == ["cx", "cy"]
    for k, p in enumerate(pp["parameters"]):
        # a principal-point shift is a shift of the centres along the image axis: the correlation is with them
        assert pp["rho"][k] > 0.93 and pp["variance_inflation"][k] > 7
        assert pp["rho_centres"][k] > 0.9 and pp["rho_ground"][k] < 0.2
        assert pp["variance_inflation"][k] == pytest.approx(1 / (1 - pp["rho"][k] ** 2))
        # the sigma is honest and the figure in metres is sigma/f x the height above ground
        assert abs(res.camera[p] - sim.camera[p]) < 4 * pp["sigma_px"][k]
        assert pp["sigma_px"][k] == pytest.approx(res.summary["camera"]["sigmas"][p], rel=1e-6)
        assert pp["shift_per_sigma_m"][k] == pytest.approx(pp["sigma_px"][k] / sim.camera["f"] * 150, rel=0.05)
    assert pp["mostly"] == "centres" and pp["text"].startswith(f"cx/cy: ρ {pp['rho'][0]:.2f}/{pp['rho'][1]:.2f}")
    w = [x for x in res.warnings if WARNING in x]
    assert len(w) == 1 and w[0] in caught
    assert f"ρ = {pp['rho'][0]:.2f}/{pp['rho'][1]:.2f}" in w[0] and "mostly the centres' shift" in w[0]
    assert all(s in w[0] for s in ("tilted or oblique images", "cross strips", "second flying height",
                                   "GCPs well spread", "cx/cy from a lab calibration", "leave cx/cy out of --refine"))
    json.dumps(res.summary)   # the figures are JSON


def test_tilted_images_in_cross_strips_at_two_heights_separate_it(flat_nadir):
    _, nadir, _ = flat_nadir
    sim = simulate_block(0, _separating_pattern(), camera=p1_35mm_camera(), n_control=0, n_check=6, n_tie=4000,
                         centre_sigma_m=RTK)
    res, caught = _run(sim)
    pp, pn = res.summary["principal_point"], nadir.summary["principal_point"]
    for k, p in enumerate(("cx", "cy")):
        assert pp["rho"][k] < 0.85 < PP_CORRELATION < pn["rho"][k]
        assert pp["rho_centres"][k] < pn["rho_centres"][k] - 0.3
        assert pp["sigma_px"][k] < 0.5 * pn["sigma_px"][k]
        assert abs(res.camera[p] - sim.camera[p]) < 4 * pp["sigma_px"][k]
    assert not any(WARNING in x for x in res.warnings + caught)


def test_the_figures_are_those_of_the_inverse_of_the_whole_normal_matrix(monkeypatch):
    # a small block: the whole normal matrix (poses, intrinsics and points) inverted densely, without the Schur
    # complement and the solves with it that the adjustment's covariance uses
    sim = simulate_block(2, _separating_pattern((2, 1), (5, 4), 1), camera=p1_35mm_camera(), n_control=0,
                         n_check=4, n_tie=500, centre_sigma_m=RTK)
    seen = []

    def capture(res):
        seen.append(res)
        return principal_point_correlation(res)

    monkeypatch.setattr(triangulation_mod, "principal_point_correlation", capture)
    res, _ = _run(sim, refine=("f", "cx", "cy"))
    pp = res.summary["principal_point"]
    bres = seen[0]
    nrm, N = bres.normals, bres.problem.n_poses
    W = nrm.W.toarray()
    V = np.zeros((len(nrm.V) * 3,) * 2)
    for j, b in enumerate(nrm.V):
        V[3 * j:3 * j + 3, 3 * j:3 * j + 3] = b
    full = np.block([[nrm.U, W], [W.T, V]])
    ok = np.r_[nrm.observed_c, nrm.observed_x]
    assert len(full) == len(ok) and ok.sum() > 900
    Sigma = np.zeros_like(full)
    Sigma[np.ix_(ok, ok)] = np.linalg.inv(full[np.ix_(ok, ok)])
    assert pp["parameters"] == ["cx", "cy"]
    for axis, p in enumerate(("cx", "cy")):
        g = 6 * N + list(bres.refine).index(p)
        l_c, l_x = pp_combinations(bres, axis)
        L = np.vstack([np.eye(len(full))[g], np.vstack([l_c, l_x]).T])
        C = L @ Sigma @ L.T
        # 1 - rho^2 = 1 / (C_00 (C^-1)_00): the variance of p with the combinations known over its variance
        vif = C[0, 0] * np.linalg.inv(C)[0, 0]
        assert pp["variance_inflation"][axis] == pytest.approx(vif, rel=1e-5)
        assert pp["rho"][axis] == pytest.approx(np.sqrt(1 - 1 / vif), rel=1e-6)
        assert pp["rho_tilt"][axis] == pytest.approx(abs(C[0, 4]) / np.sqrt(C[0, 0] * C[4, 4]), rel=1e-6)
        assert pp["rho_centres"][axis] == pytest.approx(abs(C[0, 1]) / np.sqrt(C[0, 0] * C[1, 1]), rel=1e-6)
        assert pp["sigma_px"][axis] == pytest.approx(np.sqrt(Sigma[g, g] * bres.scale2), rel=1e-6)
    # the combinations are what a principal-point shift moves: 1 px of cx is f/H px of centre shift along x
    l_c, _ = pp_combinations(bres, 0)
    dC = np.zeros(len(l_c))
    H = bres.C_world[:, 2] - np.median(bres.X_world[bres.obs_point, 2])
    dC[:6 * N].reshape(N, 6)[:, :3] = bres.R_world_to_cam[:, 0, :] * (H / bres.camera["f"])[:, None]
    assert l_c[:, 0] @ dC == pytest.approx(1.0, rel=1e-9)
    # ... and a tilt of 1/f about the camera y axis, and a shift of the whole ground by 1 m east is 1 m
    dth = np.zeros(len(l_c))
    dth[6 * np.arange(N) + 4] = 1 / bres.camera["f"]
    assert l_c[:, 3] @ dth == pytest.approx(1.0, rel=1e-9)
    _, l_x = pp_combinations(bres, 0)
    assert l_x[0::3, 1].sum() == pytest.approx(1.0) and not l_x[1::3, 1].any() and not l_x[:, [0, 3]].any()


def test_no_figure_without_cx_and_cy_and_the_cli_writes_it(tmp_path):
    sim = simulate_rtk_block(0, n_images=10, terrain_amplitude_m=0.0, n_check=4)
    res, _ = _run(sim, refine=("f",))
    assert res.summary["principal_point"] is None and not any(WARNING in x for x in res.warnings)
    rc, out = triangulate_block_cli(sim, tmp_path, "cy")
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    pp = s["principal_point"]
    assert pp["parameters"] == ["cy"] and len(pp["rho"]) == len(pp["sigma_px"]) == 1
    assert 0 < pp["rho"][0] <= 1 and pp["sigma_px"][0] > 0 and pp["text"].startswith("cy: ρ")
    # the page shows the line and the figures
    page = html.unescape((out / "report.html").read_text())
    assert pp["text"] in page and "principal point and horizontal datum: correlation ρ" in page
