"""The one pose type for body poses: POS samples hold a body `Poses` whose covariance follows the pose rule
(right perturbation of R_body_to_world, body axes), and a camera on the body is that pose `mounted`."""
import numpy as np
import pytest
from pyproj import Geod
from scipy.spatial.transform import Rotation

from dgcal.calib.mounting.common import PosSamples, pos_at_rows, pos_at_times
from dgcal.fields.crs import LocalENU, MapGrid
from dgcal.fields.io.formats import Trajectory
from dgcal.fields.pose import Poses, so3_exp
from dgcal.fields.world import World

WORLD = World(MapGrid("EPSG:32651"), LocalENU(23.0, 120.3, 30.0))


def _trajectory(n=6, sigma=True):
    rng = np.random.default_rng(7)
    t = 1000.0 + np.arange(n) * 0.1
    lat = 23.004 + 1e-5 * np.arange(n)
    lon = np.full(n, 120.297)
    h = np.full(n, 330.0)
    v_ned = np.tile([1.1, 0.0, 0.0], (n, 1))
    rph = np.column_stack([rng.normal(0, 5, n), rng.normal(0, 5, n), 75.0 + rng.normal(0, 5, n)])
    s = np.tile([0.05, 0.08, 0.12, 0.01, 0.02, 0.05], (n, 1)) if sigma else None
    return Trajectory(t, lat, lon, h, v_ned, rph, s)


def test_body_poses_round_trip_R_body_to_world_and_position():
    rng = np.random.default_rng(0)
    R = Rotation.random(8, random_state=1).as_matrix()
    r = rng.normal(0, 100, (8, 3))
    body = Poses.from_body_to_world(R, r)
    assert body.frame == "body"
    np.testing.assert_allclose(body.R_body_to_world, R)
    np.testing.assert_allclose(body.R_world_to_body, np.swapaxes(R, 1, 2))
    np.testing.assert_allclose(body.R_frame_to_world, R)
    np.testing.assert_allclose(body.C_world, r)
    X = rng.normal(0, 50, (8, 3))
    np.testing.assert_allclose(body.to_frame(X), np.einsum("nji,nj->ni", R, X - r), atol=1e-12)
    back = Poses.from_body_to_world(body.R_body_to_world, body.C_world)
    np.testing.assert_allclose(back.R_world_to_frame, body.R_world_to_frame)
    assert body[2:5].frame == "body" and len(body[2:5]) == 3
    # the camera-only and body-only accessors refuse the other frame
    with pytest.raises(ValueError):
        _ = body.R_cam_to_world
    with pytest.raises(ValueError):
        _ = Poses.from_cam_to_world(R, r).R_body_to_world
    with pytest.raises(ValueError):
        body.difference(Poses.from_cam_to_world(R, r))
    with pytest.raises(ValueError):
        Poses(R, r, frame="imu")


def test_body_retract_is_a_right_perturbation_of_R_body_to_world():
    R = Rotation.random(5, random_state=3).as_matrix()
    body = Poses.from_body_to_world(R, np.zeros((5, 3)))
    d = np.random.default_rng(4).normal(0, 0.1, (5, 6))
    moved = body.retract(d)
    assert moved.frame == "body"
    np.testing.assert_allclose(moved.R_body_to_world, R @ so3_exp(d[:, 3:]), atol=1e-12)
    np.testing.assert_allclose(moved.C_world, d[:, :3], atol=1e-12)
    np.testing.assert_allclose(moved.difference(body), d, atol=1e-12)


def test_pos_samples_hold_the_world_body_pose_and_round_trip_to_geodetic():
    traj = _trajectory()
    pos = pos_at_rows(WORLD, traj, np.arange(len(traj.t)))
    assert isinstance(pos, PosSamples) and pos.body.frame == "body" and len(pos) == len(traj.t)
    r, v, R = WORLD.pos_to_world(traj.lat, traj.lon, traj.h, traj.v_ned, traj.rph)
    np.testing.assert_allclose(pos.r_imu_world, r)
    np.testing.assert_allclose(pos.R_body_to_world, R)
    np.testing.assert_allclose(pos.v_world, v)
    np.testing.assert_allclose(pos.cov, WORLD.pos_covariance_to_world(traj.lat, traj.lon, traj.rph, traj.sigma))
    lat, lon, h, v_ned, rph = WORLD.world_to_pos(pos.body.C_world, pos.v_world, pos.body.R_body_to_world)
    np.testing.assert_allclose(np.column_stack([lat, lon, h]), pos.geo, atol=1e-9)
    np.testing.assert_allclose(v_ned, traj.v_ned, atol=1e-9)
    np.testing.assert_allclose(rph, traj.rph, atol=1e-9)
    sub = pos.subset(np.array([1, 3]))
    np.testing.assert_allclose(sub.R_body_to_world, R[[1, 3]])
    np.testing.assert_allclose(sub.cov, pos.cov[[1, 3]])
    moved = pos.moved_to(pos.t + 0.5)
    np.testing.assert_allclose(moved.r_imu_world, r + 0.5 * v)
    np.testing.assert_allclose(moved.R_body_to_world, R)
    assert moved.geo is None and moved.rph is None
    # interpolated at the samples' own times: the same body poses (to the interpolation's rounding)
    at = pos_at_times(WORLD, traj, traj.t[1:-1])
    np.testing.assert_allclose(at.body.difference(pos.body[1:-1]), 0.0, atol=1e-6)
    with pytest.raises(ValueError):
        PosSamples(pos.t, Poses.from_cam_to_world(R, r), v, pos.omega_b)


def test_pos_covariance_is_the_body_pose_rule():
    """Geodetic POS errors drawn from the sigmas give body-pose differences (`Poses.difference`: position, right
    perturbation of R_body_to_world) whose covariance is the body pose's covariance."""
    traj = _trajectory(1)
    pos = pos_at_rows(WORLD, traj, np.array([0]))
    rng = np.random.default_rng(11)
    n = 4000
    e = rng.normal(size=(n, 6)) * traj.sigma[0]
    geod = Geod(ellps="WGS84")
    lat0, lon0 = traj.lat[0], traj.lon[0]
    m_per_deg_lat = geod.inv(lon0, lat0 - 5e-4, lon0, lat0 + 5e-4)[2] / 1e-3
    m_per_deg_lon = geod.inv(lon0 - 5e-4, lat0, lon0 + 5e-4, lat0)[2] / 1e-3
    r, _, R = WORLD.pos_to_world(lat0 + e[:, 0] / m_per_deg_lat, lon0 + e[:, 1] / m_per_deg_lon,
                                 traj.h[0] + e[:, 2], np.zeros((n, 3)), traj.rph[0] + e[:, 3:])
    nominal = Poses.from_body_to_world(np.repeat(pos.R_body_to_world, n, 0), np.repeat(pos.r_imu_world, n, 0))
    d = Poses.from_body_to_world(R, r).difference(nominal)
    emp = np.cov(d.T)
    C = pos.cov[0]
    sd = np.sqrt(np.diag(C))
    np.testing.assert_allclose(np.sqrt(np.diag(emp)), sd, rtol=0.06)
    np.testing.assert_allclose(emp / np.outer(sd, sd), C / np.outer(sd, sd), atol=0.06)


def test_a_camera_mounted_on_the_body_carries_the_pose_and_its_covariance():
    rng = np.random.default_rng(5)
    R = Rotation.random(4, random_state=6).as_matrix()
    A = rng.normal(size=(4, 6, 6)) * [0.02, 0.02, 0.03, 1e-3, 1e-3, 2e-3]
    body = Poses.from_body_to_world(R, rng.normal(0, 100, (4, 3)), A @ np.swapaxes(A, 1, 2))
    lever = np.array([0.3, -0.1, 0.25])
    R_cam_to_body = Rotation.from_rotvec([0.01, -0.02, 1.57]).as_matrix()
    cam = body.mounted(lever, R_cam_to_body)
    assert cam.frame == "cam"
    np.testing.assert_allclose(cam.C_world, body.C_world + np.einsum("nij,j->ni", R, lever), atol=1e-12)
    np.testing.assert_allclose(cam.R_cam_to_world, R @ R_cam_to_body, atol=1e-12)
    # a small body error moves the camera pose by the Jacobian the covariance was carried with
    G = np.zeros((6, 6))
    for k in range(6):
        d = np.zeros((4, 6))
        d[:, k] = 1e-6
        plus, minus = body.retract(d).mounted(lever, R_cam_to_body), body.retract(-d).mounted(lever, R_cam_to_body)
        Gk = (plus.difference(cam) - minus.difference(cam)) / 2e-6
        G[:, k] = Gk[0]
    np.testing.assert_allclose(G @ body.cov[0] @ G.T, cam.cov[0], rtol=1e-6, atol=1e-14)
