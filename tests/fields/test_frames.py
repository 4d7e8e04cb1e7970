import numpy as np
import pytest

from dgcal.fields import frames
from dgcal.fields.crs import (LocalENU, MapGrid, R_ecef_to_enu_at, R_ecef_to_ned_at, ecef_to_geodetic,
                              geodetic_to_ecef)

rng = np.random.default_rng(1)


def test_rph_round_trip_and_meaning():
    rph = np.column_stack([rng.uniform(-60, 60, 50), rng.uniform(-80, 80, 50), rng.uniform(0, 360, 50)])
    R = frames.R_body_to_ned_from_rph(*rph.T)
    np.testing.assert_allclose(frames.rph_from_R_body_to_ned(R), rph, atol=1e-9)
    # heading 90 deg: body x (forward) points east in NED
    np.testing.assert_allclose(frames.R_body_to_ned_from_rph(0, 0, 90) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # positive pitch lifts the nose: body x gets a negative down component
    assert (frames.R_body_to_ned_from_rph(0, 10, 0) @ [1, 0, 0])[2] < 0
    # positive roll dips the right wing: body y gets a positive down component
    assert (frames.R_body_to_ned_from_rph(10, 0, 0) @ [0, 1, 0])[2] > 0


def test_opk_round_trip_and_nadir_identity():
    opk = np.column_stack([rng.uniform(-30, 30, 50), rng.uniform(-30, 30, 50), rng.uniform(-179, 179, 50)])
    M = frames.R_photo_to_map_from_opk(*opk.T)
    np.testing.assert_allclose(frames.opk_from_R_photo_to_map(M), opk, atol=1e-9)
    Rcv = frames.R_cam_to_map_from_opk(*opk.T)
    np.testing.assert_allclose(frames.opk_from_R_cam_to_map(Rcv), opk, atol=1e-9)
    # nadir image, top to north: CV z (view) points down, CV -y (image top) points north
    R0 = frames.R_cam_to_map_from_opk(0, 0, 0)
    np.testing.assert_allclose(R0 @ [0, 0, 1], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(R0 @ [0, -1, 0], [0, 1, 0], atol=1e-12)
    # M = Rx Ry Rz with the usual right-handed matrices
    w, p, k = np.radians([5.0, -7.0, 30.0])
    Rx = np.array([[1, 0, 0], [0, np.cos(w), -np.sin(w)], [0, np.sin(w), np.cos(w)]])
    Ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    Rz = np.array([[np.cos(k), -np.sin(k), 0], [np.sin(k), np.cos(k), 0], [0, 0, 1]])
    np.testing.assert_allclose(frames.R_photo_to_map_from_opk(5, -7, 30), Rx @ Ry @ Rz, atol=1e-12)


def test_ecef_geodetic_enu_round_trip():
    lat, lon, h = 24.1 + rng.uniform(-1, 1, 20), 120.6 + rng.uniform(-1, 1, 20), rng.uniform(0, 3000, 20)
    p = geodetic_to_ecef(lat, lon, h)
    np.testing.assert_allclose(ecef_to_geodetic(p), np.column_stack([lat, lon, h]), atol=1e-7)
    loc = LocalENU(24.1, 120.6, 100.0)
    enu = loc.from_ecef(p)
    np.testing.assert_allclose(loc.to_ecef(enu), p, atol=1e-6)
    # one metre up at the origin is +U
    up = loc.from_geodetic(24.1, 120.6, 101.0)
    np.testing.assert_allclose(up, [0, 0, 1], atol=1e-6)
    R = frames.R_ecef_to_enu(lat, lon)
    assert R.shape == (20, 3, 3)
    np.testing.assert_allclose(R[3], frames.R_ecef_to_enu(lat[3], lon[3]))
    # the same rotations from the ECEF points: one point (3,3), several (N,3,3); NED is ENU with N/E swapped, -U
    np.testing.assert_allclose(R_ecef_to_enu_at(p), R, atol=1e-12)
    np.testing.assert_allclose(R_ecef_to_enu_at(p[3]), R[3], atol=1e-12)
    np.testing.assert_allclose(R_ecef_to_ned_at(p), frames.R_ecef_to_ned(lat, lon), atol=1e-12)
    assert R_ecef_to_ned_at(p[:1]).shape == (1, 3, 3)
    # one metre up at a point is -D there
    up = geodetic_to_ecef(lat[3], lon[3], h[3] + 1.0) - p[3]
    np.testing.assert_allclose(R_ecef_to_ned_at(p[3]) @ up, [0, 0, -1], atol=1e-6)


def test_convergence_sign_and_grid_rotation():
    grid = MapGrid("EPSG:32651")  # UTM 51N, central meridian 123 E
    # east of the central meridian (northern hemisphere) meridians lean toward the pole on the central
    # meridian, so grid north lies east of true north: positive true azimuth; west of it, negative
    gamma_e = grid.convergence_deg(24.0, 124.0)
    gamma_w = grid.convergence_deg(24.0, 121.0)
    assert gamma_e > 0 > gamma_w
    # textbook: gamma ~ atan(tan(lon - lon0) sin(lat)); pyproj's own factor agrees
    assert np.isclose(gamma_e, np.degrees(np.arctan(np.tan(np.radians(1.0)) * np.sin(np.radians(24.0)))), atol=1e-3)
    import pyproj
    assert np.isclose(gamma_e, pyproj.Proj("EPSG:32651").get_factors(124.0, 24.0).meridian_convergence, atol=1e-5)
    # a true-north vector expressed in grid axes has grid azimuth -gamma
    R = grid.R_enu_to_grid_at(grid.from_geodetic(24.0, 124.0, 0.0))
    v = R @ [0, 1, 0]
    assert np.isclose(np.degrees(np.arctan2(v[0], v[1])), -gamma_e, atol=1e-9)
    # vectorised over points
    pts = grid.from_geodetic(np.array([24.0, 24.5]), np.array([124.0, 121.0]), np.zeros(2))
    Rs = grid.R_enu_to_grid_at(pts)
    assert Rs.shape == (2, 3, 3)
    np.testing.assert_allclose(Rs[0], R, atol=1e-12)
    # and the grid really shows it: a point 1 km true north has that grid azimuth
    p0 = grid.from_geodetic(24.0, 124.0, 0.0)
    loc = LocalENU(24.0, 124.0, 0.0)
    p1 = grid.from_geodetic(*loc.to_geodetic([0, 1000.0, 0]))
    d = p1 - p0
    assert np.isclose(np.degrees(np.arctan2(d[0], d[1])), -gamma_e, atol=2e-3)


def test_map_grid_round_trips():
    grid = MapGrid("EPSG:3826")
    xyz = np.column_stack([rng.uniform(2e5, 2.5e5, 10), rng.uniform(2.6e6, 2.7e6, 10), rng.uniform(0, 500, 10)])
    # TWD97 to WGS84 goes through a datum shift whose inverse is good to ~2e-5 m
    np.testing.assert_allclose(grid.from_ecef(grid.to_ecef(xyz)), xyz, atol=1e-4)
    g = grid.to_geodetic(xyz)
    np.testing.assert_allclose(grid.from_geodetic(*g.T), xyz, atol=1e-6)


def test_bad_crs_is_input_error():
    from dgcal.fields.errors import InputError
    with pytest.raises(InputError, match="not a CRS"):
        MapGrid("EPSG:999999")


def test_skew_matches_cross():
    a, b = rng.normal(size=3), rng.normal(size=3)
    np.testing.assert_allclose(frames.skew(a) @ b, np.cross(a, b))


def test_wgs84_ecef_geodetic_match_pyproj_without_importing_it():
    """dgcal's ECEF <-> geodetic (PROJ's cart formulas, so SPP need not import pyproj) agree with pyproj to
    1e-9 deg / 1e-6 m over the globe, heights from -1 km to 40 000 km, the poles and the date line."""
    import pyproj
    from dgcal.fields.crs import ecef_to_geodetic, geodetic_to_ecef
    rng = np.random.default_rng(4)
    n = 20000
    lat = np.r_[np.degrees(np.arcsin(rng.uniform(-1, 1, n))), 90.0, -90.0, 0.0, 45.0]
    lon = np.r_[rng.uniform(-180, 180, n), 0.0, 180.0, -180.0, 179.999999]
    h = np.r_[rng.uniform(-1e3, 4e7, n), 0.0, 10.0, -500.0, 1e5]
    ref = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x, y, z = ref.transform(lon, lat, h)
    p = geodetic_to_ecef(lat, lon, h)
    np.testing.assert_allclose(p, np.stack([x, y, z], axis=-1), rtol=0, atol=1e-6)
    back = ecef_to_geodetic(p)
    lon2, lat2, h2 = ref.transform(x, y, z, direction="INVERSE")
    np.testing.assert_allclose(back[:, 0], lat2, rtol=0, atol=1e-9)
    d_lon = (back[:, 1] - lon2 + 180.0) % 360.0 - 180.0
    np.testing.assert_allclose(np.where(np.abs(lat2) < 89.9999, d_lon, 0.0), 0.0, atol=1e-9)
    np.testing.assert_allclose(back[:, 2], h2, rtol=0, atol=1e-6)
    low = h < 1e4                  # Bowring's one-step inverse (PROJ's too) is exact near the Earth, not in orbit
    np.testing.assert_allclose(back[low, 2], h[low], rtol=0, atol=1e-5)
