"""SPP's structured error model (dgcal.pos.gnss.spp_error_model) on simulated receivers whose errors have the
structure it assumes: Klobuchar wrong by a common share and by gradients (drawn from the model's prior), the
troposphere's zenith error common to all satellites, a constant orbit-and-clock error per satellite, code noise, and
a second code with hardware biases. The ionosphere's field is measured from the second code, and the positions'
error/sigma per axis over the receivers is about one."""
from __future__ import annotations

import numpy as np
import pytest

from dgcal.fields.constants import C_LIGHT
from dgcal.fields.crs import R_ecef_to_enu_at
from dgcal.pos.gnss.corrections import SISRE_M, ZTD_SIGMA_M, tropo_mapping
from dgcal.pos.gnss.ephemeris import group_delay_s
from dgcal.pos.gnss.rinex import read_rinex_nav
from dgcal.pos.gnss.spp import SppOptions, prepare_epochs, spp
from dgcal.pos.gnss.spp_error_model import IONO_LOCAL_SHARE, PRIOR_DOF, PRIOR_SIGMA, pierce_offsets_deg

SEEDS = range(12)


def _receiver(shared_data, seed: int, nav, gamma_e=(1575.42 / 1176.45) ** 2):
    """A static receiver's raw epochs (120 s) with structured errors and a second code; its truth and the drawn
    field (common share, gradients north and east per degree)."""
    from dgcal.sim.gnss import DEFAULT_T0_GPS, circle_trajectory, simulate_gnss
    rng = np.random.default_rng(100 + seed)
    lat, lon = 35.0 + rng.uniform(-1, 1), 139.0 + rng.uniform(-1, 1)
    t = DEFAULT_T0_GPS + 600.0 * seed + np.arange(0.0, 120.0)
    p, v = circle_trajectory(t, lat, lon, 50.0, 0.0, 0.0)
    obs = simulate_gnss(t, p, v, nav, seed=seed, sigma_pr=0.15, sigma_doppler=0.05, systems=("G", "E", "J"),
                        prepare=False)
    model = prepare_epochs(obs.epochs, nav, p, SppOptions(model_errors=False, elev_mask_deg=0.0))
    field = rng.standard_normal(3) * PRIOR_SIGMA
    ztd = ZTD_SIGMA_M * rng.standard_normal()
    sats = sorted({s for ep in obs.epochs for s in ep.sat})
    orbit = {s: SISRE_M[s[0]] * rng.standard_normal() for s in sats}
    local = {s: IONO_LOCAL_SHARE * rng.standard_normal() for s in sats}
    hw = {s: 0.3 * rng.standard_normal() for s in sats}              # the satellites' code biases the TGD misses
    rx_bias = {"G": 1.0, "J": -0.5, "E": 2.0}                          # the receiver's, per system
    for raw, mod in zip(obs.epochs, model):
        k = [mod.sat.index(s) for s in raw.sat]
        iono = mod.iono_m[k]
        el, az = np.radians(mod.elev_deg[k]), np.radians(mod.azim_deg[k])
        dn, de = pierce_offsets_deg(el, az)
        d_iono = iono * (field[0] + field[1] * dn + field[2] * de + np.array([local[s] for s in raw.sat]))
        raw.pr_m = raw.pr_m + d_iono + ztd * tropo_mapping(el) + np.array([orbit[s] for s in raw.sat])
        gam = np.where(raw.system == "E", gamma_e, (1575.42 / 1227.60) ** 2)
        tgd = C_LIGHT * group_delay_s(nav, list(raw.sat), np.full(raw.n, raw.t_gps))
        raw.pr2_m = (raw.pr_m + (gam - 1.0) * (iono + d_iono + tgd + np.array([hw[s] for s in raw.sat]))
                     + np.array([rx_bias[s] for s in raw.system]) + 0.3 * rng.standard_normal(raw.n))
        raw.wavelength2_m = raw.wavelength_m * np.sqrt(gam)
    return obs, p, field


@pytest.fixture(scope="module")
def runs(shared_data):
    nav = read_rinex_nav(shared_data / "rinex-sept/SEPT078M.21P")
    out = []
    for seed in SEEDS:
        obs, p, field = _receiver(shared_data, seed, nav)
        sol = spp(obs, nav, SppOptions())
        ok = sol.ok
        R = R_ecef_to_enu_at(p[ok])
        e = np.einsum("nij,nj->ni", R, sol.p_ecef[ok] - p[ok])
        s = np.sqrt(np.diagonal(R @ sol.cov_p[ok] @ np.swapaxes(R, 1, 2), axis1=1, axis2=2))
        out.append((sol, field, e, s))
    return out


def test_the_field_is_measured(runs):
    """The common share and the gradients come back from the second code within their stated sigmas (the
    satellites' hardware biases are what limits them)."""
    z = []
    for sol, field, *_ in runs:
        assert sol.error_model["model"] == "structured"
        f = sol.error_model["ionosphere"]
        got = np.array([f["common"], f["gradient_north_per_deg"], f["gradient_east_per_deg"]])
        sd = np.array([f["common_sigma"], f["gradient_north_per_deg_sigma"], f["gradient_east_per_deg_sigma"]])
        assert f["satellites"] >= 15 and np.all(sd > 0)
        z.append((got - field) / sd)
    zr = np.sqrt(np.mean(np.square(z), axis=0))
    print("field error/sigma RMS (common, north, east):", zr.round(2))
    assert np.all((zr > 0.4) & (zr < 1.8)), zr


def test_positions_honest_per_axis(runs):
    """Error/sigma RMS per axis over the 12 receivers (each one draw of its slow errors) within 0.7-1.4; no epoch
    beyond 5 sigma; the sigmas of a good epoch stay metres, not tens."""
    per = np.array([np.sqrt(np.mean((e / s) ** 2, axis=0)) for _, _, e, s in runs])
    pooled = np.sqrt(np.mean(per ** 2, axis=0))
    allz = np.concatenate([e / s for _, _, e, s in runs])
    print("per receiver E/N/U:", per.round(2).tolist(), "pooled", pooled.round(2))
    assert np.all((pooled > 0.7) & (pooled < 1.4)), pooled
    assert np.mean(np.abs(allz) > 5.0) < 0.01
    med = np.median(np.concatenate([s for *_, s in runs]), axis=0)
    assert np.all(med < [1.5, 1.5, 4.0]), med


def test_single_code_files_keep_the_independent_budget(shared_data):
    """Without a second code nothing measures the ionosphere: the independent per-satellite budget, its slow part
    scaled by the residuals (no slow errors were simulated: the scale falls towards zero, held up by the prior)."""
    from dgcal.sim.gnss import DEFAULT_T0_GPS, circle_trajectory, simulate_gnss
    nav = read_rinex_nav(shared_data / "rinex-sept/SEPT078M.21P")
    t = DEFAULT_T0_GPS + np.arange(0.0, 60.0)
    p, v = circle_trajectory(t, 35.3, 139.5, 50.0, 0.0, 0.0)
    obs = simulate_gnss(t, p, v, nav, seed=3, sigma_pr=0.3, systems=("G", "E"), prepare=False)
    sol = spp(obs, nav, SppOptions())
    em = sol.error_model
    assert em["model"] == "independent" and "ionosphere" not in em
    assert em["slow_scale_file"] < 0.3 and em["slow_scale"] == pytest.approx(
        (em["slow_dof"] * em["slow_scale_file"] + PRIOR_DOF) / (em["slow_dof"] + PRIOR_DOF))


@pytest.mark.parametrize("scale, high", [(0.5, 1.4), (1.0, 1.4), (2.0, 1.75)])
def test_simulator_code_error_family(shared_data, scale, high):
    """The simulator's slow code errors (`CodeErrorModel`: the front end's budget x `scale`, independent per
    satellite, 30 min correlation; no second code): the residuals' variance component brings the budget to the
    data. Error/sigma RMS per axis over 8 static receivers of 120 s within 0.7-1.4 at 0.5 and 1 times the budget
    (the independent budget alone: 0.76-0.82 at 0.5); at twice the budget below 1.75 (was 1.7-2.2: RAIM removes the
    largest slow errors before the residuals are read, so the scale comes out ~2.7 for 4). No epoch beyond 5 sigma."""
    from dgcal.sim.gnss import DEFAULT_T0_GPS, CodeErrorModel, circle_trajectory, simulate_gnss
    nav = read_rinex_nav(shared_data / "rinex-sept/SEPT078M.21P")
    per, allz = [], []
    for seed in range(8):
        t = DEFAULT_T0_GPS + 900.0 * seed + np.arange(0.0, 120.0)
        p, v = circle_trajectory(t, 35.3, 139.5, 100.0, 0.0, 0.0)
        obs = simulate_gnss(t, p, v, nav, seed=seed, sigma_pr=0.5, systems=("G", "E", "J"), prepare=False,
                            code_errors=CodeErrorModel(scale=scale))
        sol = spp(obs, nav, SppOptions())
        assert sol.error_model["model"] == "independent"
        ok = sol.ok
        R = R_ecef_to_enu_at(p[ok])
        e = np.einsum("nij,nj->ni", R, sol.p_ecef[ok] - p[ok])
        z = e / np.sqrt(np.diagonal(R @ sol.cov_p[ok] @ np.swapaxes(R, 1, 2), axis1=1, axis2=2))
        per.append(np.sqrt(np.mean(z ** 2, axis=0)))
        allz.append(z)
    pooled = np.sqrt(np.mean(np.square(per), axis=0))
    print(f"x{scale}: error/sigma RMS E/N/U {pooled.round(2)}")
    assert np.all((pooled > 0.7) & (pooled < high)), pooled
    assert np.mean(np.abs(np.concatenate(allz)) > 5.0) < 0.01


def test_the_summary_says_which_model(shared_data):
    """`dgcal pos --mode spp`'s summary names the model of its sigmas and what the file measured (JSON-ready)."""
    import json
    from dgcal.pos.gnss.spp import spp_files
    run = spp_files(shared_data / "rinex-sept/SEPT078M1.21O", [shared_data / "rinex-sept/SEPT078M.21P"], SppOptions())
    em = json.loads(json.dumps(run.summary["error_model"]))
    assert em["model"] == "structured" and em["slow_dof"] >= 10 and 0.0 < em["slow_scale"] < 10.0
    assert em["ionosphere"]["satellites"] == 23 and em["ionosphere"]["common_sigma"] > 0
