"""Map CRS <-> world frame (dgcal.fields.world): points and EOP angles (convergence, curvature, geoid); resection."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dgcal.bundle.resection import pnp, similarity_umeyama
from dgcal.fields.crs import MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.frames import R_cam_to_map_from_opk
from dgcal.fields.pose import Poses
from dgcal.fields.world import World
from dgcal.sim.flight import block_flight_camera

rng = np.random.default_rng(11)
CENTRE = np.array([327000.0, 2655000.0, 120.0])     # UTM 51N, ~1.7 deg west of the central meridian


def _random_R(n):
    return Rotation.from_rotvec(rng.normal(0, 0.3, (n, 3))).as_matrix()


def test_points_and_eops_round_trip():
    g = World.from_crs("EPSG:32651", CENTRE)
    P = CENTRE + rng.uniform(-2000, 2000, (20, 3)) * [1, 1, 0.05]
    np.testing.assert_allclose(g.to_map(g.to_world(P)), P, atol=1e-6)
    R, C = _random_R(20), g.to_world(P)
    xyz, opk, _ = g.poses_to_eop(Poses(R, C))
    back = g.eop_to_poses(xyz, opk)
    R2, C2 = back.R_world_to_cam, back.C_world
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(C2, C, atol=1e-4)


def test_eop_angles_follow_grid_axes_at_the_centre():
    """A ray's direction in grid-level axes at the projection centre, from the map EOP, points to where the
    ground point really is in map coordinates (checked independently of the local frame, 300 m away)."""
    g = World.from_crs("EPSG:32651", CENTRE)
    grid = MapGrid("EPSG:32651")
    C_map = CENTRE + [1500.0, -800.0, 400.0]       # far from the frame origin: curvature and convergence differ
    P_map = C_map + [120.0, 250.0, -380.0]
    R_w2c, C_loc = np.eye(3)[None] @ Rotation.from_euler("x", [180.0], degrees=True).as_matrix(), g.to_world(C_map)
    xyz, opk, _ = g.poses_to_eop(Poses(R_w2c, C_loc))
    R_cam_to_grid = R_cam_to_map_from_opk(*opk[0])
    # ray to P in the camera frame, computed in the adjustment frame
    ray_cam = R_w2c[0] @ (g.to_world(P_map)[0] - C_loc[0])
    d_grid = R_cam_to_grid @ ray_cam
    # the same direction from map coordinates: grid E/N differences scaled back to metres on the ground
    lat, lon, _ = grid.to_geodetic(C_map)
    k = _scale_factor(grid, C_map)
    d_map = (P_map - C_map) / [k, k, 1.0]
    cosang = d_grid @ d_map / np.linalg.norm(d_grid) / np.linalg.norm(d_map)
    assert np.degrees(np.arccos(min(1, cosang))) < 0.003   # vs ~0.7 deg convergence and 0.01 deg curvature
    # and a nadir camera looking straight down at its own centre with top to grid north has opk ~ 0
    R_nadir_cam_to_grid = np.diag([1.0, -1.0, -1.0])
    R_w2c_n = (np.swapaxes(g.R_world_to_grid_at(C_loc), -1, -2)[0] @ R_nadir_cam_to_grid).T
    np.testing.assert_allclose(g.poses_to_eop(Poses(R_w2c_n[None], C_loc))[1], [[0, 0, 0]], atol=1e-9)
    # while in the local frame it is rotated by the convergence (~-0.7 deg) plus the curvature
    kappa_local = np.degrees(np.arctan2(R_w2c_n[0, 1], R_w2c_n[0, 0]))
    assert 0.3 < abs(kappa_local) < 1.5


def _scale_factor(grid, xyz):
    lat, lon, h = grid.to_geodetic(xyz)
    a = grid.from_geodetic(lat, lon, 0.0)
    b = grid.from_geodetic(lat + 1e-4, lon, 0.0)
    from pyproj import Geod
    dist = Geod(ellps="WGS84").inv(lon, lat, lon, lat + 1e-4)[2]
    return np.hypot(*(b - a)[:2]) / dist


def test_covariance_to_map_matches_monte_carlo():
    g = World.from_crs("EPSG:32651", CENTRE)
    R, C = _random_R(1), np.array([[300.0, -200.0, 150.0]])
    A = rng.normal(size=(6, 6)) * [0.02, 0.02, 0.02, 1e-3, 1e-3, 1e-3]
    cov = A @ A.T
    xyz0, opk0, J = g.poses_to_eop(Poses(R, C, cov[None]))
    J = J[0]
    s = rng.multivariate_normal(np.zeros(6), cov, 4000)
    # the pose rule of dgcal.fields.pose: R_cam_to_world <- R_cam_to_world Exp(dtheta)
    Rs = Rotation.from_rotvec(-s[:, 3:]).as_matrix() @ R
    xyz, opk, _ = g.poses_to_eop(Poses(Rs, C + s[:, :3]))
    d_opk = (opk - opk0 + 180.0) % 360.0 - 180.0     # a pose with omega or kappa near +-180 deg wraps
    emp = np.cov(np.column_stack([xyz - xyz0, d_opk]).T)
    np.testing.assert_allclose(np.sqrt(np.diag(emp)), np.sqrt(np.diag(J)), rtol=0.08)
    # the position-angle cross terms too (they change sign with the perturbation side)
    sd = np.sqrt(np.diag(J))
    np.testing.assert_allclose(emp / np.outer(sd, sd), J / np.outer(sd, sd), atol=0.1)


def test_geoid_constant_undulation():
    g = World.from_crs("EPSG:32651", CENTRE, geoid=20.0)
    e = World.from_crs("EPSG:32651", CENTRE + [0, 0, 20.0])
    P = CENTRE + [[10.0, 20.0, 5.0]]
    np.testing.assert_allclose(g.to_world(P), e.to_world(P + [0, 0, 20.0]), atol=1e-6)
    np.testing.assert_allclose(g.to_map(g.to_world(P)), P, atol=1e-6)


def test_bad_crs_and_local_frame():
    with pytest.raises(InputError, match="'crs'"):
        World.from_crs("EPSG:4326", CENTRE)
    loc = World.from_crs("local", np.array([10.0, 20.0, 3.0]))
    P = np.array([[11.0, 22.0, 4.0]])
    np.testing.assert_allclose(loc.to_world(P), [[1.0, 2.0, 1.0]])
    R = _random_R(1)
    xyz, opk, _ = loc.poses_to_eop(Poses(R, loc.to_world(P)))
    R2 = loc.eop_to_poses(xyz, opk).R_world_to_cam
    np.testing.assert_allclose(R2, R, atol=1e-12)


def test_pnp_and_umeyama():
    cam = block_flight_camera()
    X = rng.uniform([-40, -30, -3], [40, 30, 3], (12, 3))
    R = Rotation.from_euler("xyz", [182.0, -3.0, 30.0], degrees=True).as_matrix()
    C = np.array([2.0, -1.0, 80.0])
    uv = cam.project((X - C) @ R.T)
    R2, C2, inl = pnp(cam, uv, X)
    np.testing.assert_allclose(R2, R, atol=1e-6)
    np.testing.assert_allclose(C2, C, atol=1e-4)
    Rs = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    s, R3, t = similarity_umeyama(X, 2.5 * X @ Rs.T + [1, 2, 3])
    assert s == pytest.approx(2.5) and np.allclose(R3, Rs) and np.allclose(t, [1, 2, 3])


def test_resection_of_degenerate_geometry_returns_no_pose_not_an_opencv_error():
    from dgcal.bundle.resection import pnp
    from dgcal.sim.block import full_frame_20mm_camera
    cam = full_frame_20mm_camera()
    X = np.column_stack([np.linspace(0, 10, 5), np.zeros(5), np.zeros(5)])        # collinear control
    uv = np.column_stack([np.linspace(2000, 4000, 5), np.full(5, 2000.0)])
    assert pnp(cam, uv, X) is None
    assert pnp(cam, uv[:3], X[:3]) is None
    # nearly degenerate points that OpenCV's SQPnP asserts on: no pose either
    X2 = X + np.array([[0, 0, 0], [0, 0.02, 0], [0, 0, 0], [0, 0, 0.02], [0, 0, 0]])
    assert pnp(cam, uv, X2) is None
