"""The one pose type: conversions round-trip and the perturbation rule is the documented one."""
import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.fields.pose import Poses, so3_exp, so3_log, so3_right_jacobian, so3_right_jacobian_inv


def _random_poses(n=5, seed=0):
    rng = np.random.default_rng(seed)
    R = Rotation.random(n, random_state=seed).as_matrix()
    return Poses(R, rng.normal(0, 100, (n, 3)))


def test_R_t_round_trip_and_projection():
    p = _random_poses()
    q = Poses.from_R_t(p.R_world_to_cam, p.t_cam)
    np.testing.assert_allclose(q.C_world, p.C_world, atol=1e-9)
    X = np.random.default_rng(1).normal(0, 50, (5, 3))
    np.testing.assert_allclose(p.to_cam(X), np.einsum("nij,nj->ni", p.R_world_to_cam, X) + p.t_cam, atol=1e-9)
    r = Poses.from_cam_to_world(p.R_cam_to_world, p.C_world)
    np.testing.assert_allclose(r.R_world_to_cam, p.R_world_to_cam)


def test_retract_is_a_right_perturbation_of_cam_to_world_and_difference_inverts_it():
    p = _random_poses()
    d = np.random.default_rng(2).normal(0, 0.1, (5, 6))
    q = p.retract(d)
    np.testing.assert_allclose(q.R_cam_to_world, p.R_cam_to_world @ so3_exp(d[:, 3:]), atol=1e-12)
    np.testing.assert_allclose(q.R_world_to_cam, so3_exp(-d[:, 3:]) @ p.R_world_to_cam, atol=1e-12)
    np.testing.assert_allclose(q.C_world, p.C_world + d[:, :3])
    np.testing.assert_allclose(q.difference(p), d, atol=1e-12)
    np.testing.assert_allclose(so3_log(so3_exp(d[:, 3:])), d[:, 3:], atol=1e-12)


def test_a_small_rotation_error_moves_camera_points_as_documented():
    # X_cam = R_world_to_cam (X - C): with R_cam_to_world <- R Exp(dtheta), X_cam <- X_cam - dtheta x X_cam
    p = _random_poses(1)
    X = np.array([[10.0, -5.0, 30.0]])
    dth = np.array([1e-6, -2e-6, 0.5e-6])
    Xc = p.to_cam(X)[0]
    Xc2 = p.retract(np.r_[0, 0, 0, dth][None]).to_cam(X)[0]
    np.testing.assert_allclose(Xc2 - Xc, -np.cross(dth, Xc), atol=1e-9)


def test_inverse_right_jacobian_linearises_the_log():
    rng = np.random.default_rng(4)
    for phi in (rng.normal(0, 0.5, 3), np.array([1e-8, 0, 0]), np.array([0.0, 2.5, 0.3])):
        d = rng.normal(0, 1e-6, 3)
        lhs = so3_log(so3_exp(phi) @ so3_exp(d)) - phi
        np.testing.assert_allclose(lhs, so3_right_jacobian_inv(phi) @ d, atol=1e-11)


def test_right_jacobian_linearises_the_exponential_and_inverts_its_inverse():
    rng = np.random.default_rng(5)
    for phi in (rng.normal(0, 0.5, 3), np.array([1e-8, 0, 0]), np.array([0.0, 2.5, 0.3]), np.zeros(3)):
        d = rng.normal(0, 1e-6, 3)
        lhs = so3_log(so3_exp(phi).T @ so3_exp(phi + d))
        np.testing.assert_allclose(lhs, so3_right_jacobian(phi) @ d, atol=1e-11)
        if np.linalg.norm(phi) > 0:
            np.testing.assert_allclose(so3_right_jacobian(phi) @ so3_right_jacobian_inv(phi), np.eye(3), atol=1e-9)
    stack = rng.normal(0, 0.4, (4, 2, 3))
    assert so3_right_jacobian(stack).shape == (4, 2, 3, 3)
