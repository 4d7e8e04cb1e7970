"""Broadcast orbits against cssrlib, geometry and atmosphere models, Sagnac rotation."""
import numpy as np
import pytest

from dgcal.fields.constants import C_LIGHT, OMEGA_EARTH, SECONDS_PER_DAY, SECONDS_PER_WEEK
from dgcal.pos.gnss.ephemeris import satellite_states, select_ephemeris, states_at_transmission
from dgcal.pos.gnss.corrections import (code_sigma_m, elevation_azimuth, klobuchar_delay_m, sagnac_rotate,
                                  saastamoinen_delay_m)
from dgcal.pos.gnss.rinex import gtime_from_gps_seconds, read_rinex_nav

T0 = 2149 * SECONDS_PER_WEEK + 5 * SECONDS_PER_DAY + 12 * 3600.0   # 2021-03-19 12:00 GPS
REF = np.array([-3962108.673, 3381309.574, 3668678.638])


@pytest.fixture(scope="module")
def nav(shared_data):
    return read_rinex_nav(shared_data / "rinex-sept/SEPT078M.21P")


def test_orbits_match_cssrlib_and_velocity_is_derivative(nav):
    from cssrlib.ephemeris import eph2pos
    sats = sorted(nav.by_sat)
    t = T0 + 17.25
    p, v, clk, drift, ura, ok = satellite_states(nav, sats, t)
    assert ok.sum() >= 25
    for i in np.nonzero(ok)[0]:
        eph = select_ephemeris(nav, sats[i], t)
        rs, dts = eph2pos(gtime_from_gps_seconds(t), eph)
        np.testing.assert_allclose(p[i], rs, atol=1e-3)
        assert clk[i] == pytest.approx(dts - eph.tgd, abs=1e-15)
        ra, ca = eph2pos(gtime_from_gps_seconds(t - 0.5), eph)
        rb, cb = eph2pos(gtime_from_gps_seconds(t + 0.5), eph)
        np.testing.assert_allclose(v[i], rb - ra, atol=1e-3)
        assert drift[i] == pytest.approx(cb - ca, abs=1e-14)
        assert 2.5e7 < np.linalg.norm(p[i]) < 4.6e7   # MEO .. QZSS QZO apogee
    # a satellite without ephemeris is flagged, not invented
    p2, *_, ok2 = satellite_states(nav, ["G31"], t)
    assert not ok2[0] and np.all(np.isnan(p2))


def test_transmission_time_is_consistent(nav):
    sats = ["G01", "E08", "J03"]
    p0, *_ = satellite_states(nav, sats, T0)
    pr = np.linalg.norm(p0 - REF, axis=1) + 1.0e5        # + 333 us receiver clock
    p, v, clk, drift, _, ok = states_at_transmission(nav, sats, T0, pr)
    t_tx = T0 - pr / C_LIGHT - clk
    p_direct, *_ = satellite_states(nav, sats, t_tx)
    np.testing.assert_allclose(p, p_direct, atol=2e-3)


def test_elevation_azimuth_directions():
    from dgcal.fields.crs import LocalENU
    enu = LocalENU(35.0, 139.0, 50.0)
    sats = enu.to_ecef(np.array([[0, 0, 2e7], [0, 2e7, 0.0], [2e7, 0, 0.0], [1e7, 0, 1e7]]))
    el, az = elevation_azimuth(enu.origin_ecef, sats)
    np.testing.assert_allclose(np.degrees(el), [90, 0, 0, 45], atol=1e-6)
    np.testing.assert_allclose(np.degrees(az[1:]), [0, 90, 90], atol=1e-6)


def test_klobuchar_textbook_values():
    ion = np.array([[1.0e-8, 0.0, 0.0, 0.0], [72000.0, 0.0, 0.0, 0.0]])
    # zenith at the equator, local time 14:00 (peak): 5 ns + amplitude, slant factor ~1
    lat, lon = 0.0, 0.0
    t = 14 * 3600.0
    d = klobuchar_delay_m(t, lat, lon, np.array([np.pi / 2]), np.array([0.0]), ion)
    F = 1.0 + 16.0 * (0.53 - 0.5) ** 3
    # the pierce point latitude shifts the geomagnetic latitude, but alpha1..3 = 0 makes AMP = alpha0
    assert d[0] == pytest.approx(C_LIGHT * F * (5e-9 + 1e-8), rel=1e-3)
    # at night only the 5 ns floor remains; lower elevation increases the delay
    night = klobuchar_delay_m(2 * 3600.0, lat, lon, np.array([np.pi / 2, 0.3]), np.zeros(2), ion)
    assert night[0] == pytest.approx(C_LIGHT * F * 5e-9, rel=1e-3)
    assert night[1] > 2.0 * night[0]
    # frequency scaling (f_L1/f)^2
    b1 = klobuchar_delay_m(t, lat, lon, np.array([np.pi / 2]), np.array([0.0]), ion, 1561.098e6)
    assert b1[0] / d[0] == pytest.approx((1575.42 / 1561.098) ** 2)
    assert klobuchar_delay_m(t, lat, lon, np.array([1.0]), np.array([0.0]), None)[0] == 0.0


def test_saastamoinen_zenith_and_mapping():
    z = saastamoinen_delay_m(45.0, 0.0, np.array([np.pi / 2]))[0]
    assert 2.3 < z < 2.6                      # zenith total delay at sea level
    z2 = saastamoinen_delay_m(45.0, 2000.0, np.array([np.pi / 2]))[0]
    assert z2 < 0.85 * z                      # less atmosphere above a mountain
    low = saastamoinen_delay_m(45.0, 0.0, np.array([np.radians(30.0)]))[0]
    assert low == pytest.approx(2.0 * z, rel=1e-6)   # 1/sin(el) mapping


def test_sagnac_rotation_and_its_rate():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(5, 3)) * 1.5e7
    v = rng.normal(size=(5, 3)) * 3e3
    tau = np.full(5, 0.07)
    pr, vr = sagnac_rotate(p, v, tau)
    # rotation about z by w*tau: z unchanged, norm unchanged, displacement ~ w*tau*r_xy
    np.testing.assert_allclose(pr[:, 2], p[:, 2])
    np.testing.assert_allclose(np.linalg.norm(pr, axis=1), np.linalg.norm(p, axis=1), rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(pr - p, axis=1),
                               OMEGA_EARTH * 0.07 * np.linalg.norm(p[:, :2], axis=1), rtol=1e-6)
    # velocity is d/dt_rx of the rotated position when tau changes at rate tau_dot
    tau_dot = np.full(5, 2e-6)
    _, vr = sagnac_rotate(p, v, tau, tau_dot)
    h = 1e-3
    pa, _ = sagnac_rotate(p - v * h * (1 - tau_dot[:, None]), v, tau - tau_dot * h)
    pb, _ = sagnac_rotate(p + v * h * (1 - tau_dot[:, None]), v, tau + tau_dot * h)
    np.testing.assert_allclose(vr, (pb - pa) / (2 * h), atol=1e-5)


def test_code_sigma_grows_towards_horizon():
    s = code_sigma_m(np.radians([90.0, 30.0, 10.0]), 0.3)
    assert s[0] == pytest.approx(0.3)
    assert s[0] < s[1] < s[2]


def test_beidou_geo_state_uses_cssrlib_geo_frame():
    from cssrlib.gnss import Eph, char2sys, gpst2time, prn2sat
    from dgcal.pos.gnss.rinex import BroadcastNav
    week, toes = 2149, 475200.0
    eph = Eph(prn2sat(char2sys("C"), 1))
    eph.week, eph.toes = week, toes
    eph.toe = eph.toc = gpst2time(week, toes)
    eph.A, eph.e, eph.i0, eph.omg, eph.M0 = 42164.0e3, 0.0005, np.radians(5.0), 0.3, 1.0  # i0 in the -5 deg GEO frame
    eph.OMG0, eph.OMGd = 2.0, 0.0
    eph.cuc = eph.cus = eph.crc = eph.crs = eph.cic = eph.cis = eph.idot = eph.deln = 0.0
    eph.af0, eph.af1 = 1e-4, 1e-12
    nav = BroadcastNav(eph=[eph], by_sat={"C01": [eph]}, ion_gps=None, ion_bds=None, leap_seconds=18)
    t = week * SECONDS_PER_WEEK + toes + 100.0
    p, v, clk, drift, ura, ok = satellite_states(nav, ["C01"], t)
    assert ok[0]
    assert abs(np.linalg.norm(p[0]) - 42164.0e3) < 50e3
    assert np.linalg.norm(v[0]) < 400.0              # geosynchronous: slow in ECEF (MEO: ~3 km/s)
    # in ECEF a geosynchronous orbit repeats after one sidereal day
    from dgcal.pos.gnss.ephemeris import _geo_state
    p1, *_ = _geo_state(eph, t + 86164.09)
    assert np.linalg.norm(p1 - p[0]) < 2e3
    assert clk[0] == pytest.approx(1e-4 + 1e-12 * 100.0, abs=3e-9)   # + relativistic term


def test_compiled_receiver_model_equals_the_numpy_models(nav):
    """The compiled zero-difference terms of PPK (`carrier_model`) against `corrections`' NumPy functions, pyproj's
    geodetic coordinates and the light-time loop they replace: same values to rounding, NaN where a satellite is
    not usable."""
    from dgcal.fields.crs import ecef_to_geodetic
    from dgcal.pos.gnss.carrier_model import at_reception, geodetic, receiver_terms
    assert nav.ion_gps is not None and np.any(nav.ion_gps)
    sats = sorted(nav.by_sat)
    rng = np.random.default_rng(3)
    for _ in range(5):
        p_rx = REF + rng.normal(size=3) * 5e3
        t = T0 + rng.uniform(0, 3600.0)
        p0, *_ = satellite_states(nav, sats, t)
        pr = np.linalg.norm(p0 - p_rx, axis=1) + 3e4
        p, v, clk, _d, _u, ok = states_at_transmission(nav, sats, t, pr)
        # the NumPy light-time loop of carrier.satellite_geometry before it was compiled
        tau = np.linalg.norm(p - p_rx, axis=1) / C_LIGHT
        for _ in range(2):
            tau = np.linalg.norm(sagnac_rotate(p, v, tau)[0] - p_rx, axis=1) / C_LIGHT
        los0 = (p - p_rx) / np.linalg.norm(p - p_rx, axis=1, keepdims=True)
        p_ref, v_ref = sagnac_rotate(p, v, tau, np.sum(los0 * v, axis=1) / C_LIGHT)
        pos, vel = at_reception(p, v, p_rx)
        np.testing.assert_allclose(pos[ok], p_ref[ok], rtol=0, atol=1e-7)
        np.testing.assert_allclose(vel[ok], v_ref[ok], rtol=0, atol=1e-10)
        assert np.all(np.isnan(pos[~ok]))
        lat, lon, h = ecef_to_geodetic(p_rx)
        g = geodetic(p_rx)
        np.testing.assert_allclose(g[:2], (lat, lon), rtol=0, atol=1e-10)           # deg
        assert g[2] == pytest.approx(h, abs=1e-5)                                   # m
        ok[0] = False                                       # a satellite without a model
        rho, los, el, az, tropo, iono = receiver_terms(pos, ok, p_rx, np.full(len(sats), t),
                                                       np.asarray(nav.ion_gps, float), True, 0.7)
        el_ref, az_ref = elevation_azimuth(p_rx, pos[ok], (lat, lon))
        np.testing.assert_allclose(rho[ok], np.linalg.norm(pos[ok] - p_rx, axis=1), rtol=1e-15)
        np.testing.assert_allclose(los[ok], (pos[ok] - p_rx) / rho[ok, None], rtol=0, atol=1e-15)
        np.testing.assert_allclose(el[ok], el_ref, rtol=0, atol=1e-12)         # 1e-11 deg of geodetic latitude
        np.testing.assert_allclose(az[ok], az_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(tropo[ok], saastamoinen_delay_m(lat, h, el_ref, 0.7), rtol=1e-11)
        np.testing.assert_allclose(iono[ok], klobuchar_delay_m(t, lat, lon, el_ref, az_ref, nav.ion_gps), rtol=1e-11)
        assert np.all(np.isnan(np.r_[el[~ok], az[~ok], tropo[~ok], iono[~ok]]))
        assert (el[ok] < 0).any() and (tropo[ok][el[ok] < 0] == 0).all()      # below the horizon: no delay
        no_ion = receiver_terms(pos, ok, p_rx, np.full(len(sats), t), np.zeros((2, 4)), False, 0.7)
        assert np.all(no_ion[5][ok] == 0.0)
