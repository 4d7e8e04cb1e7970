"""dgcal.fields.world: covariance round trips (EOP <-> poses), POS covariances, constructors."""
import numpy as np
import pytest
from pyproj import Geod
from scipy.spatial.transform import Rotation

from dgcal.fields.crs import LocalENU, MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.pose import Poses, so3_log
from dgcal.fields.world import World

rng = np.random.default_rng(3)
CENTRE = np.array([327000.0, 2655000.0, 120.0])     # UTM 51N


def _poses(world, n=15, cov=True):
    P = world.to_map(rng.uniform(-1500, 1500, (n, 3)) * [1, 1, 0.2])
    R = Rotation.from_rotvec(rng.normal(0, 0.3, (n, 3))).as_matrix()
    C = world.to_world(P)
    A = rng.normal(size=(n, 6, 6)) * [0.02, 0.02, 0.03, 1e-3, 1e-3, 2e-3]
    return Poses(R, C, A @ np.swapaxes(A, 1, 2) if cov else None)


WORLDS = {
    "utm": lambda: World.from_crs("EPSG:32651", CENTRE),
    "utm-geoid": lambda: World.from_crs("EPSG:32651", CENTRE, geoid=21.5),
    "geographic": lambda: World(MapGrid("EPSG:4326"), LocalENU(23.0, 120.3, 30.0)),
    "engineering": lambda: World.from_crs("local", CENTRE),
}


@pytest.mark.parametrize("name", list(WORLDS))
def test_eop_and_covariance_round_trip(name):
    w = WORLDS[name]()
    p = _poses(w)
    xyz, opk, cov_map = w.poses_to_eop(p)
    back = w.eop_to_poses(xyz, opk, cov_map)
    np.testing.assert_allclose(back.C_world, p.C_world, atol=1e-6)
    np.testing.assert_allclose(back.R_world_to_cam, p.R_world_to_cam, atol=1e-9)
    np.testing.assert_allclose(back.cov, p.cov, rtol=1e-5, atol=1e-12)
    # and map -> world -> map
    xyz2, opk2, cov_map2 = w.poses_to_eop(back)
    np.testing.assert_allclose(xyz2, xyz, atol=1e-6)
    np.testing.assert_allclose(cov_map2, cov_map, rtol=1e-5, atol=1e-12)


def test_eop_position_covariance_is_metres_along_grid_axes():
    """For a geographic CRS too: the position block of the EOP covariance is metres along grid E, N, Up."""
    w = WORLDS["geographic"]()
    p = _poses(w, 3)
    J = w.eop_jacobian(p)
    np.testing.assert_allclose(J[:, :3, :3], w.R_world_to_grid_at(p.C_world), atol=1e-15)
    np.testing.assert_allclose(J[:, :3, 3:], 0.0, atol=0)
    # the angle rows: a small rotation about the camera axes changes omega/phi/kappa by ~57 deg/rad
    assert np.all(np.abs(np.linalg.det(J[:, 3:, 3:])) > 0.5 * np.degrees(1) ** 3)


def test_pos_covariance_matches_monte_carlo():
    w = World(MapGrid("EPSG:32651"), LocalENU(23.0, 120.3, 30.0))
    lat, lon, h = np.array([23.004]), np.array([120.297]), np.array([330.0])
    rph = np.array([[2.0, -3.0, 75.0]])
    sigma = np.array([[0.05, 0.08, 0.12, 0.01, 0.02, 0.05]])   # N, E, U (m), roll, pitch, heading (deg)
    C = w.pos_covariance_to_world(lat, lon, rph, sigma)[0]
    n = 4000
    e = rng.normal(size=(n, 6)) * sigma
    geod = Geod(ellps="WGS84")
    m_per_deg_lat = geod.inv(lon[0], lat[0] - 5e-4, lon[0], lat[0] + 5e-4)[2] / 1e-3
    m_per_deg_lon = geod.inv(lon[0] - 5e-4, lat[0], lon[0] + 5e-4, lat[0])[2] / 1e-3
    r0, _, R0 = w.pos_to_world(lat, lon, h, np.zeros((1, 3)), rph)
    r, _, R = w.pos_to_world(lat + e[:, 0] / m_per_deg_lat, lon + e[:, 1] / m_per_deg_lon, h + e[:, 2],
                             np.zeros((n, 3)), rph + e[:, 3:])
    d = np.column_stack([r - r0, so3_log(np.swapaxes(R0, -1, -2) @ R)])   # right perturbation, body axes
    emp = np.cov(d.T)
    np.testing.assert_allclose(np.sqrt(np.diag(emp)), np.sqrt(np.diag(C)), rtol=0.06)
    sd = np.sqrt(np.diag(C))
    np.testing.assert_allclose(emp / np.outer(sd, sd), C / np.outer(sd, sd), atol=0.06)


def test_constructors_agree_and_engineering_has_no_geodetic_link():
    grid = MapGrid("EPSG:32651")
    pts = CENTRE + rng.uniform(-500, 500, (8, 3))
    a, b = World.at_map_points(grid, pts), World.from_crs("EPSG:32651", pts.mean(axis=0))
    assert (a.enu.lat0, a.enu.lon0, a.enu.h0) == (b.enu.lat0, b.enu.lon0, b.enu.h0)
    assert b.crs_text == "EPSG:32651" and not b.local_only
    e = World.engineering(CENTRE)
    assert e.local_only and e.crs_text is None
    np.testing.assert_allclose(e.R_world_to_grid_at(np.zeros((2, 3))), np.tile(np.eye(3), (2, 1, 1)))
    with pytest.raises(InputError, match="map CRS"):
        e.pos_to_world([23.0], [120.0], [0.0], np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(InputError, match="geoid"):
        World.from_crs("EPSG:32651", CENTRE, geoid="/no/such/geoid.tif")
