"""Multi-ray intersection: accuracy, honest covariance, pose sensitivities against finite differences."""
import numpy as np

from dgcal.bundle.intersection import intersect, propagate_pose_covariance
from dgcal.fields.pose import so3_exp
from dgcal.sim.mounting import mounting_flight_camera


def _scene(seed=0, n_pts=30):
    rng = np.random.default_rng(seed)
    cam = mounting_flight_camera()
    C = np.array([[x, y, 300.0 + rng.normal(0, 5)] for x in (-80.0, 0.0, 80.0) for y in (-60.0, 60.0)])
    R_down = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
    R = so3_exp(rng.normal(0, 0.02, (len(C), 3))) @ R_down
    X = np.column_stack([rng.uniform(-100, 100, n_pts), rng.uniform(-80, 80, n_pts), rng.uniform(-10, 10, n_pts)])
    img, pt, uv = [], [], []
    for m in range(len(C)):
        Xc = (X - C[m]) @ R[m]
        p = cam.project(Xc)
        ok = (p[:, 0] > 0) & (p[:, 0] < cam.image_size[0]) & (p[:, 1] > 0) & (p[:, 1] < cam.image_size[1])
        for k in np.nonzero(ok)[0]:
            img.append(m)
            pt.append(k)
            uv.append(p[k])
    return cam, C, R, X, np.array(img), np.array(pt), np.array(uv)


def test_intersection_exact_and_honest():
    cam, C, R, X, img, pt, uv = _scene()
    res = intersect(cam, C, R, img, pt, uv, n_points=len(X))
    assert res.ok.all()
    assert np.max(np.abs(res.xyz - X)) < 1e-6
    rng = np.random.default_rng(5)
    z = []
    for _ in range(20):
        noisy = uv + rng.normal(0, 0.5, uv.shape)
        r = intersect(cam, C, R, img, pt, noisy, np.full(uv.shape, 0.5), len(X))
        e = r.xyz - X
        z.append(np.einsum("ki,kij,kj->k", e, np.linalg.inv(r.cov), e))
    # chi-square with 3 dof: mean 3
    assert 2.4 < np.mean(z) < 3.6


def test_pose_sensitivities_match_finite_differences():
    cam, C, R, X, img, pt, uv = _scene(1)
    res = intersect(cam, C, R, img, pt, uv, n_points=len(X))
    h = 1e-4
    for m in (0, 3):
        for j in range(6):
            C2, R2 = C.copy(), R.copy()
            if j < 3:
                C2[m, j] += h
            else:
                d = np.zeros(3)
                d[j - 3] = h
                R2[m] = R[m] @ so3_exp(d)
            r2 = intersect(cam, C2, R2, img, pt, uv, n_points=len(X))
            # the measured pixels stay, so moving the pose moves the intersected point
            num = (r2.xyz - res.xyz) / h
            assert np.allclose(num, res.dX_dpose[:, m, :, j], atol=2e-3 * max(1, np.abs(num).max()))


def test_common_error_propagation():
    cam, C, R, X, img, pt, uv = _scene(2)
    res = intersect(cam, C, R, img, pt, uv, n_points=len(X))
    # a common shift of all centres moves every point by the same shift
    G = np.zeros((len(C), 6, 3))
    G[:, :3, :] = np.eye(3)
    cov = propagate_pose_covariance(res, None, G, np.diag([0.01, 0.04, 0.09]))
    assert np.allclose(np.diagonal(cov, axis1=1, axis2=2), [0.01, 0.04, 0.09], rtol=1e-3)


def test_single_ray_points_are_not_ok():
    cam, C, R, X, img, pt, uv = _scene(3)
    keep = ~((pt == 0) & (img != img[pt == 0][0]))
    res = intersect(cam, C, R, img[keep], pt[keep], uv[keep], n_points=len(X))
    assert not res.ok[0] and np.isnan(res.xyz[0]).all() and res.ok[1:].all()


def test_correlated_pose_errors():
    cam, C, R, X, img, pt, uv = _scene(4)
    res = intersect(cam, C, R, img, pt, uv, n_points=len(X))
    M = len(C)
    rng = np.random.default_rng(0)
    cov = np.array([np.diag(rng.uniform(0.5, 2.0, 6)) * [1e-4, 1e-4, 1e-4, 1e-8, 1e-8, 1e-8] for _ in range(M)])
    # identity correlation: the independent propagation
    assert np.allclose(propagate_pose_covariance(res, cov, pose_corr=np.eye(M)), propagate_pose_covariance(res, cov))
    # full correlation of equal covariances: one error common to all poses
    same = np.repeat(cov[:1], M, axis=0)
    G = np.repeat(np.eye(6)[None], M, axis=0)
    assert np.allclose(propagate_pose_covariance(res, same, pose_corr=np.ones((M, M))),
                       propagate_pose_covariance(res, None, G, same[0]), rtol=1e-6, atol=1e-14)
    # and against a Monte Carlo of correlated errors
    rho = np.exp(-np.abs(np.subtract.outer(np.arange(M), np.arange(M))) / 2.0)
    Lr = np.linalg.cholesky(rho)
    S = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    e = np.einsum("mn,snj->smj", Lr, rng.standard_normal((4000, M, 6))) * S  # (samples, M, 6)
    dX = np.einsum("kmij,smj->ski", res.dX_dpose, e)
    mc = np.einsum("ski,skj->kij", dX, dX) / len(e)
    pred = propagate_pose_covariance(res, cov, pose_corr=rho)
    ok = res.ok
    assert np.allclose(np.diagonal(mc[ok], axis1=1, axis2=2), np.diagonal(pred[ok], axis1=1, axis2=2), rtol=0.1)
