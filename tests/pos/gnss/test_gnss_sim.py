"""GNSS simulator: the front-end model reproduces simulated truth; SPP on simulated data is unbiased and honest."""
import json

import numpy as np
import pytest

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.pos.gnss.observations import CLOCK_GROUP
from dgcal.pos.gnss.rinex import read_rinex_nav
from dgcal.pos.gnss.spp import SppOptions, spp
from dgcal.sim.gnss import DEFAULT_T0_GPS, circle_trajectory, simulate_gnss, synthetic_nav


@pytest.fixture(scope="module")
def nav(shared_data):
    return read_rinex_nav(shared_data / "rinex-sept/SEPT078M.21P")


@pytest.fixture(scope="module")
def flight(nav):
    t = DEFAULT_T0_GPS + 300.0 + np.arange(0.0, 90.0)
    p, v = circle_trajectory(t, 35.3, 139.5, 120.0, 150.0, 15.0)
    obs = simulate_gnss(t, p, v, nav, seed=7, sigma_pr=0.5, sigma_doppler=0.05,
                        systems=("G", "E", "J"), outages=[(t[60], t[69], 3)])
    return t, p, v, obs


def test_prepared_epochs_match_the_documented_model(flight):
    """pr_corr = |sat - p| + clk[group] + noise and rr_corr = e.(v_sat - v) + drift + noise."""
    t, p, v, obs = flight
    tr = obs.truth
    z_pr, z_rr = [], []
    for ep in obs.epochs:
        k = int(np.searchsorted(t, ep.t_gps - 1e-9))
        d = ep.sat_pos_ecef - p[k]
        rho = np.linalg.norm(d, axis=1)
        clk = np.array([tr["clk_m"][CLOCK_GROUP[s]] [k] if CLOCK_GROUP[s] in tr["clk_m"]
                        else tr["clk_m"][s][k] for s in ep.system])
        z_pr.append((ep.pr_corr_m - rho - clk) / ep.sigma_pr_m)
        e = d / rho[:, None]
        rr = np.sum(e * (ep.sat_vel_ecef - v[k]), axis=1) + tr["drift_mps"][k]
        z_rr.append((ep.rr_corr_mps - rr) / ep.sigma_rr_mps)
    z_pr, z_rr = np.concatenate(z_pr), np.concatenate(z_rr)
    assert len(z_pr) > 1000
    assert abs(z_pr.mean()) < 0.1 and 0.9 < z_pr.std() < 1.1
    assert abs(z_rr.mean()) < 0.1 and 0.9 < z_rr.std() < 1.1


def test_spp_on_simulated_flight_is_unbiased_and_honest(flight, nav):
    t, p, v, obs = flight
    sol = spp(obs, nav, SppOptions(code_sigma_zenith_m=0.5, doppler_sigma_zenith_mps=0.05,
                                   model_errors=False))
    # simulated data keep the noise they were made with (the residuals tell only real receivers')
    assert not sol.code_noise["estimated"] and sol.options.code_sigma_zenith_m == 0.5
    out = (t >= t[60]) & (t <= t[69])
    # during the outage (3 satellites) there is no fix; elsewhere every epoch is positioned
    assert not sol.ok[out].any() and sol.ok[~out].all()
    assert np.all(sol.n_sat[out] <= 3)
    ok = sol.ok
    err = sol.p_ecef[ok] - p[ok]
    sig = np.sqrt(np.diagonal(sol.cov_p[ok], axis1=1, axis2=2))
    n = ok.sum()
    assert np.all(np.abs(err.mean(axis=0)) < 4.0 * sig.mean(axis=0) / np.sqrt(n) + 0.05)
    nrms = np.sqrt(np.mean((err / sig) ** 2, axis=0))
    assert np.all((nrms > 0.7) & (nrms < 1.4)), nrms
    assert np.sqrt(np.mean(np.sum(err ** 2, axis=1))) < 2.0
    ev = sol.v_ecef[ok] - v[ok]
    sv = np.sqrt(np.diagonal(sol.cov_v[ok], axis1=1, axis2=2))
    vn = np.sqrt(np.mean((ev / sv) ** 2, axis=0))
    assert np.all((vn > 0.7) & (vn < 1.4)), vn
    # the Galileo inter-system bias of the simulated receiver (2.5 m) is recovered
    isb = sol.clk_m["E"][ok] - sol.clk_m["G"][ok]
    assert isb.mean() == pytest.approx(2.5, abs=0.3)
    dclk = sol.clk_m["G"][ok] - obs.truth["clk_m"]["G"][ok]
    assert abs(dclk.mean()) < 0.3


def test_synthetic_constellation_with_beidou():
    t = 2300 * SECONDS_PER_WEEK + 3600.0 + np.arange(0.0, 20.0)
    p, v = circle_trajectory(t, 47.0, 8.0, 500.0, 0.0, 0.0)
    nav = synthetic_nav(t[0], t[-1], systems=("G", "E", "C"), seed=1)
    obs = simulate_gnss(t, p, v, nav, seed=3, sigma_pr=0.3, systems=("G", "E", "C"))
    assert set(obs.systems) == {"G", "E", "C"}
    assert min(e.n for e in obs.epochs) >= 12
    sol = spp(obs, nav, SppOptions(code_sigma_zenith_m=0.3, model_errors=False))
    assert sol.ok.all()
    err = sol.p_ecef - p
    assert np.sqrt(np.mean(np.sum(err ** 2, axis=1))) < 1.5
    assert set(sol.clk_m) == {"G", "E", "C"}
    assert (sol.clk_m["C"] - sol.clk_m["G"]).mean() == pytest.approx(-4.0, abs=0.4)


def test_cli_simulate_then_pos_end_to_end(tmp_path):
    from dgcal.cli import main
    from dgcal.fields.io.csv_tables import read_table
    sim_dir, out = tmp_path / "sim", tmp_path / "pos"
    rc = main(["simulate", "gnss", "--out", str(sim_dir), "--seed", "4", "--duration", "30",
               "--radius", "80", "--speed", "8", "--systems", "GE"])
    assert rc == 0
    truth = json.loads((sim_dir / "truth.json").read_text())
    rc = main(["pos", "--rinex-obs", str(sim_dir / "sim.obs"), "--rinex-nav", str(sim_dir / "nav.rnx"),
               "--mode", "spp", "--out", str(out), "--no-progress", "--code-sigma", "0.5"])
    assert rc == 0
    tab = read_table(out / "gnss.csv", ["gps_week", "gps_sow", "x", "y", "z", "vx", "vy", "vz"])
    assert len(tab) == 31
    t = tab["gps_week"] * SECONDS_PER_WEEK + tab["gps_sow"]
    np.testing.assert_allclose(t, truth["t_gps"], atol=1e-6)
    p = np.column_stack([tab["x"], tab["y"], tab["z"]])
    err = p - np.array(truth["p_ecef"])
    assert np.sqrt(np.mean(np.sum(err ** 2, axis=1))) < 2.5
    vel = np.column_stack([tab["vx"], tab["vy"], tab["vz"]])
    assert np.sqrt(np.mean(np.sum((vel - np.array(truth["v_ecef"])) ** 2, axis=1))) < 0.3


def test_rtklib_reads_simulated_rinex_without_bias(nav, tmp_path):
    """An independent implementation (RTKLIB pntpos) positions our simulated RINEX near the truth."""
    from dgcal.pos.gnss.rinex import write_rinex_obs
    from dgcal.sim.gnss import DEFAULT_NAV
    from dgcal.pos.gnss.rtklib import rtklib_pntpos
    t = DEFAULT_T0_GPS + 1200.0 + np.arange(0.0, 40.0)
    p, v = circle_trajectory(t, 35.3, 139.5, 100.0, 0.0, 0.0)
    # GPS only: there RTKLIB's single-frequency models (TGD, Klobuchar, Saastamoinen) are ours;
    # for Galileo it picks its own ephemeris type/BGD, which shifts positions by decimetres
    obs = simulate_gnss(t, p, v, nav, seed=13, sigma_pr=0.5, systems=("G",), prepare=False)
    write_rinex_obs(tmp_path / "s.obs", obs)
    tr, pr = rtklib_pntpos(str(tmp_path / "s.obs"), str(DEFAULT_NAV), systems="G")
    assert len(tr) == 40
    np.testing.assert_allclose(tr, t, atol=1e-6)
    err = pr - p
    assert np.all(np.abs(err.mean(axis=0)) < 0.5)
    assert np.sqrt(np.mean(np.sum(err ** 2, axis=1))) < 2.5
