"""RINEX 3 reading (real SEPT data), errors naming file and line, and the observation writer round trip."""
import numpy as np
import pytest

from dgcal.fields.constants import C_LIGHT, SECONDS_PER_DAY, SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.pos.gnss.rinex import (calendar_from_gps_seconds, gps_seconds_from_calendar, gps_seconds_from_gtime,
                       gtime_from_gps_seconds, read_rinex_nav, read_rinex_obs, write_rinex_obs)

OBS = "rinex-sept/SEPT078M1.21O"
NAV = "rinex-sept/SEPT078M.21P"


def test_time_conversions_round_trip():
    t = gps_seconds_from_calendar(2021, 3, 19, 12, 0, 0.5)
    assert t == pytest.approx(2149 * SECONDS_PER_WEEK + 5 * SECONDS_PER_DAY + 12 * 3600 + 0.5)
    y, mo, d, h, mi, s = calendar_from_gps_seconds(t)
    assert (y, mo, d, h, mi) == (2021, 3, 19, 12, 0) and s == pytest.approx(0.5)
    assert gps_seconds_from_gtime(gtime_from_gps_seconds(t + 0.123)) == pytest.approx(t + 0.123, abs=1e-9)


def test_read_real_observations(shared_data):
    obs = read_rinex_obs(shared_data / OBS)
    assert len(obs) == 60
    assert obs.signals == {"G": "C1C", "E": "C1C", "J": "C1C"}
    assert np.linalg.norm(obs.p_approx_ecef - [-3962108.4557, 3381308.8777, 3668678.1749]) < 1e-3
    t = obs.t_gps
    assert t[0] == pytest.approx(gps_seconds_from_calendar(2021, 3, 19, 12, 0, 0.0))
    np.testing.assert_allclose(np.diff(t), 1.0)
    e0, e1 = obs[10], obs[11]
    assert e0.sat[0] == "E01" and e0.n == 23
    assert e0.pr_m.min() > 1.9e7 and e0.pr_m.max() < 4.0e7
    # the file has no Doppler: it is derived from carrier phase and must match the code rate
    common = [s for s in e0.sat if s in e1.sat]
    i0 = [e0.sat.index(s) for s in common]
    i1 = [e1.sat.index(s) for s in common]
    code_rate = e1.pr_m[i1] - e0.pr_m[i0]
    rr = 0.5 * (e0.range_rate_mps[i0] + e1.range_rate_mps[i1])
    assert np.all(np.isfinite(rr))
    # code rate includes the common receiver clock drift and code noise (< a few m/s)
    d = code_rate - rr
    assert np.std(d) < 2.0
    np.testing.assert_allclose(e0.wavelength_m, C_LIGHT / 1575.42e6)


def test_read_real_navigation(shared_data):
    nav = read_rinex_nav(shared_data / NAV)
    assert {"G01", "E01", "J01"} <= set(nav.by_sat)
    np.testing.assert_allclose(nav.ion_gps[0], [0.1118e-07, 0.7451e-08, -0.5960e-07, -0.5960e-07])
    np.testing.assert_allclose(nav.ion_gps[1], [0.9011e05, 0.0, -0.1966e06, -0.6554e05])
    assert nav.leap_seconds == 18


def test_errors_name_file_and_line(shared_data, tmp_path):
    lines = (shared_data / OBS).read_text().splitlines(keepends=True)
    k = next(i for i, s in enumerate(lines) if s.startswith(">")) + 3   # a satellite record
    bad = lines[:k] + [lines[k][:10] + "12x45.678" + lines[k][19:]] + lines[k + 1:]
    p = tmp_path / "bad.21O"
    p.write_text("".join(bad))
    with pytest.raises(InputError) as ei:
        read_rinex_obs(p)
    assert f"bad.21O:{k + 1}" in str(ei.value)

    nl = (shared_data / NAV).read_text().splitlines(keepends=True)
    j = next(i for i, s in enumerate(nl) if "END OF HEADER" in s) + 3
    nl[j] = nl[j][:5] + "   .1x3D+01" + nl[j][16:]
    q = tmp_path / "bad.21P"
    q.write_text("".join(nl))
    with pytest.raises(InputError) as ei:
        read_rinex_nav(q)
    assert f"bad.21P:{j + 1}" in str(ei.value)

    with pytest.raises(InputError, match="not an observation file"):
        read_rinex_obs(shared_data / NAV)
    with pytest.raises(InputError, match="not a RINEX file"):
        r = tmp_path / "x.txt"
        r.write_text("hello\n")
        read_rinex_nav(r)
    with pytest.raises(InputError, match="not found"):
        read_rinex_obs(tmp_path / "missing.obs")


def test_writer_round_trip(shared_data, tmp_path):
    from dgcal.sim.gnss import DEFAULT_T0_GPS, circle_trajectory, simulate_gnss
    nav = read_rinex_nav(shared_data / NAV)
    t = DEFAULT_T0_GPS + np.arange(0.0, 5.0)
    p, v = circle_trajectory(t, 35.3, 139.5, 80.0, 100.0, 10.0)
    sim = simulate_gnss(t, p, v, nav, seed=2, systems=("G", "E", "J"), prepare=False)
    path = tmp_path / "sim.obs"
    write_rinex_obs(path, sim)
    back = read_rinex_obs(path)
    assert len(back) == len(sim)
    for a, b in zip(sim.epochs, back.epochs):
        assert b.t_gps == pytest.approx(a.t_gps, abs=1e-6)
        ia = np.argsort(a.sat)
        ib = np.argsort(b.sat)
        assert [a.sat[i] for i in ia] == [b.sat[i] for i in ib]
        np.testing.assert_allclose(b.pr_m[ib], a.pr_m[ia], atol=1e-3)
        np.testing.assert_allclose(b.doppler_hz[ib], a.doppler_hz[ia], atol=1e-3)
        np.testing.assert_allclose(b.range_rate_mps[ib], a.range_rate_mps[ia], atol=1e-3)
