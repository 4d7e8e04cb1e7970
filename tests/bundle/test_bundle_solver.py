"""The least-squares engine against dense linear algebra and scipy on a small bundle with every block type."""
import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from dgcal.bundle.solver.blocks import (CentrePriors, GlobalPriors, ImageObservations, PointPriors, State)
from dgcal.bundle.solver.covariance import Covariance, normal_rhs
from dgcal.bundle.solver.lm import LMOptions, minimise, normals_at
from dgcal.bundle.solver.normals import Problem, linearise
from dgcal.calib.camera.models import Fraser7
from dgcal.fields.pose import Poses

INTR = ("f", "cx", "K1")


def _problem(seed=0, noise=0.3):
    rng = np.random.default_rng(seed)
    cam = Fraser7((1000, 800), np.array([900.0, 500, 400, -0.05, 0.01, 0, 0, 0, 0, 0]))
    n_img, n_pt = 5, 40
    X = np.column_stack([rng.uniform(-20, 20, n_pt), rng.uniform(-20, 20, n_pt), rng.uniform(-3, 3, n_pt)])
    C = np.column_stack([np.linspace(-10, 10, n_img), rng.uniform(-3, 3, n_img), np.full(n_img, 40.0)])
    R_c2w = Rotation.from_euler("xyz", np.column_stack([np.full(n_img, 180.0), rng.normal(0, 3, (n_img, 2))]),
                                degrees=True).as_matrix()
    truth = Poses.from_cam_to_world(R_c2w, C)
    ii, jj = np.meshgrid(np.arange(n_img), np.arange(n_pt), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    uv = cam.project(truth.to_cam(X[jj], ii)) + rng.normal(0, noise, (len(ii), 2))
    sig = np.full((len(ii), 2), noise)
    blocks = [ImageObservations(cam, ii, jj, uv, sig, INTR, 0),
              PointPriors.from_arrays(X[:6] + rng.normal(0, 0.01, (6, 3)), 0.01),
              CentrePriors.from_arrays(np.vstack([C[[0, 3]] + rng.normal(0, 0.05, (2, 3)), np.full((3, 3), np.nan)]),
                                       0.05),
              GlobalPriors(np.array([2]), np.array([-0.05]), np.array([0.01]))]
    prob = Problem(blocks, n_img, n_pt, len(INTR))
    start = State(truth.retract(rng.normal(0, 1e-2, (n_img, 6))), X + rng.normal(0, 0.2, X.shape),
                  np.array([cam["f"], cam["cx"], cam["K1"]]) + [5.0, 3.0, 0.01])
    return prob, start


def _residual_vector(prob, state):
    return np.concatenate([b.evaluate(state, False).r.ravel() for b in prob.blocks])


def _dense_jacobian(prob, state, h=1e-6):
    """d r / d [poses (6N, right perturbation), points (3M), globals (G)] by central differences."""
    N, M, G = prob.n_poses, prob.n_points, prob.n_globals
    n = 6 * N + 3 * M + G
    J = np.empty((len(_residual_vector(prob, state)), n))
    for k in range(n):
        d = np.zeros(n)
        d[k] = h
        moved = []
        for s in (1, -1):
            dd = s * d
            st = State(state.poses.retract(dd[:6 * N].reshape(N, 6)),
                       state.points + dd[6 * N:6 * N + 3 * M].reshape(M, 3),
                       state.globals + dd[6 * N + 3 * M:])
            moved.append(_residual_vector(prob, st))
        J[:, k] = (moved[0] - moved[1]) / (2 * h)
    return J


def test_analytic_jacobians_match_finite_differences():
    prob, start = _problem()
    nrm = linearise(prob, start)
    Jd = _dense_jacobian(prob, start)
    N, M = prob.n_poses, prob.n_points
    # engine normals from analytic Jacobians vs the dense finite-difference normal matrix
    Nd = Jd.T @ Jd
    cam = np.r_[0:6 * N, 6 * N + 3 * M:Jd.shape[1]]
    tol = 1e-7 * np.abs(Nd).max()      # finite-difference noise
    np.testing.assert_allclose(nrm.U, Nd[np.ix_(cam, cam)], rtol=2e-4, atol=tol)
    Vd = np.array([Nd[6 * N + 3 * j:6 * N + 3 * j + 3, 6 * N + 3 * j:6 * N + 3 * j + 3] for j in range(M)])
    np.testing.assert_allclose(nrm.V, Vd, rtol=2e-4, atol=tol)
    np.testing.assert_allclose(nrm.W.toarray(), Nd[np.ix_(cam, np.r_[6 * N:6 * N + 3 * M])], rtol=2e-4, atol=tol)


def test_minimum_and_covariances_equal_dense_least_squares():
    prob, start = _problem()
    sol = minimise(prob, start, LMOptions(tol_chi2=1e-9, tol_rel=1e-15))
    assert sol.converged
    N, M, G = prob.n_poses, prob.n_points, prob.n_globals

    def fun(z):
        st = State(start.poses.retract(z[:6 * N].reshape(N, 6)), start.points + z[6 * N:6 * N + 3 * M].reshape(M, 3),
                   start.globals + z[6 * N + 3 * M:])
        return _residual_vector(prob, st)

    ref = least_squares(fun, np.zeros(6 * N + 3 * M + G), method="lm", xtol=1e-14, ftol=1e-14)
    assert sol.cost == pytest.approx(2 * ref.cost, rel=1e-7)
    # covariances: the engine's Schur cofactors vs the dense inverse of J^T J at the minimum
    nrm = normals_at(prob, sol)
    cov = Covariance.at(prob, nrm)
    Jd = _dense_jacobian(prob, sol.state)
    Qd = np.linalg.inv(Jd.T @ Jd)
    cam = np.r_[0:6 * N, 6 * N + 3 * M:Jd.shape[1]]
    np.testing.assert_allclose(cov.Q_cc, Qd[np.ix_(cam, cam)], rtol=1e-3, atol=1e-12)
    Qp = np.array([Qd[6 * N + 3 * j:6 * N + 3 * j + 3, 6 * N + 3 * j:6 * N + 3 * j + 3] for j in range(M)])
    np.testing.assert_allclose(cov.point_cofactors(), Qp, rtol=1e-3, atol=1e-12)
    np.testing.assert_allclose(cov.global_cofactors(), Qd[-G:, -G:], rtol=1e-3)
    # redundancy numbers of the image observations: 1 - diag(J Q J^T)
    H = Jd @ Qd @ Jd.T
    k = len(prob.blocks[0])
    np.testing.assert_allclose(cov.redundancy_numbers(0), (1 - np.diag(H)[:2 * k]).reshape(k, 2), atol=1e-4)
    total = sum(cov.redundancy_numbers(b).sum() for b in range(len(prob.blocks)))
    assert total == pytest.approx(nrm.redundancy, rel=1e-3)
    # response to a disturbance of the centre priors: N^-1 J^T B, against the dense solve
    B = np.random.default_rng(3).normal(size=(6, 1, 2))
    b_c, b_x = normal_rhs(prob, nrm, 2, B)
    x_c, x_x = cov.response(b_c, b_x)
    Bfull = np.zeros((Jd.shape[0], 2))
    off = nrm.row_offsets[2]
    Bfull[off:off + 6] = B.reshape(6, 2)
    ref_resp = Qd @ Jd.T @ Bfull
    # atol: the finite-difference reference's noise on the response's smallest elements (1e-7 of its largest)
    np.testing.assert_allclose(x_c, ref_resp[cam], rtol=1e-3, atol=1e-6 * np.abs(ref_resp).max())


def test_held_parameters_stay_and_are_not_counted():
    prob, start = _problem()
    prob.pose_free[1] = False
    prob.point_free[7] = [False, False, True]
    prob.global_free[2] = False
    sol = minimise(prob, start)
    np.testing.assert_allclose(sol.state.poses.C_world[1], start.poses.C_world[1])
    np.testing.assert_allclose(sol.state.points[7, :2], start.points[7, :2])
    assert sol.state.globals[2] == start.globals[2]
    nrm = normals_at(prob, sol)
    assert nrm.n_unknowns == 6 * 4 + 3 * 40 - 2 + 2
    cov = Covariance.at(prob, nrm)
    assert np.isnan(cov.pose_cofactors()[1]).all() and np.isfinite(cov.pose_cofactors()[0]).all()
    Qp = cov.point_cofactors(np.array([7]))[0]
    assert np.isnan(Qp[0, 0]) and np.isfinite(Qp[2, 2])


def test_iteration_limit_is_reported_as_not_converged():
    prob, start = _problem()
    sol = minimise(prob, start, LMOptions(max_iterations=1))
    assert not sol.converged and "iteration limit" in sol.stop_reason


def test_compiled_schur_sum_equals_the_dense_product(monkeypatch):
    from dgcal.bundle.solver import normals
    prob, start = _problem()
    nrm = linearise(prob, start)
    monkeypatch.setattr(normals, "GEMM_SPEEDUP", np.inf)    # the small-block path: a dense GEMM
    dense = normals.reduce(nrm, 1e-3).S
    monkeypatch.setattr(normals, "GEMM_SPEEDUP", 0.0)       # the compiled track sum, S dense
    tracks = normals.reduce(nrm, 1e-3).S
    monkeypatch.setattr(normals, "DENSE_SCHUR_MAX", 0)      # the large-block path: the compiled track sum
    sparse = normals.reduce(nrm, 1e-3).S
    np.testing.assert_allclose(sparse, dense, rtol=1e-10, atol=1e-9 * np.abs(dense).max())
    np.testing.assert_allclose(tracks, dense, rtol=1e-10, atol=1e-9 * np.abs(dense).max())


def test_the_track_sum_is_picked_for_short_tracks_and_the_gemm_for_full_visibility():
    """bench/schur.py: the compiled sum over the tracks is 2-30x faster than the dense GEMM when tracks cover a third
    of the block or less, 2-5x slower when every image sees every point."""
    from dgcal.bundle.solver.normals import track_sum_pays
    assert not track_sum_pays(np.full(300, 36), 36) and not track_sum_pays(np.full(200, 300), 300)
    assert track_sum_pays(np.full(300, 12), 36) and track_sum_pays(np.full(1474, 18), 122)


def test_compiled_schur_sum_with_an_image_measuring_a_point_twice(monkeypatch):
    from dgcal.bundle.solver import normals
    prob, start = _problem()
    img = prob.blocks[0]
    # the first observation repeated (a point measured twice in one image) enters both the dense and the
    # compiled sums as two items
    for name in ("pose", "point"):
        setattr(img, name, np.r_[getattr(img, name), getattr(img, name)[:1]])
    img.uv = np.vstack([img.uv, img.uv[:1] + 0.5])
    img.sigma = np.vstack([img.sigma, img.sigma[:1]])
    nrm = linearise(prob, start)
    monkeypatch.setattr(normals, "GEMM_SPEEDUP", np.inf)
    dense = normals.reduce(nrm, 1e-3).S
    monkeypatch.setattr(normals, "DENSE_SCHUR_MAX", 0)
    np.testing.assert_allclose(normals.reduce(nrm, 1e-3).S, dense, rtol=1e-10, atol=1e-9 * np.abs(dense).max())


def test_sparse_reduced_system_equals_the_dense_one(monkeypatch):
    from dgcal.bundle.solver import normals
    prob, start = _problem()
    img = prob.blocks[0]
    for name in ("pose", "point"):      # a point measured twice in one image too
        setattr(img, name, np.r_[getattr(img, name), getattr(img, name)[:1]])
    img.uv = np.vstack([img.uv, img.uv[:1] + 0.5])
    img.sigma = np.vstack([img.sigma, img.sigma[:1]])
    nrm = linearise(prob, start)
    monkeypatch.setattr(normals, "GEMM_SPEEDUP", np.inf)
    dense = normals.reduce(nrm, 1e-3)
    dc_ref, dx_ref = normals.step(nrm, 1e-3)
    for name, value in (("DENSE_SCHUR_MAX", 0), ("SPARSE_MIN_POSES", 0), ("SPARSE_DENSITY_MAX", 1.0)):
        monkeypatch.setattr(normals, name, value)      # the large-block path: S sparse, SuperLU
    sparse = normals.reduce(nrm, 1e-3)
    assert sparse.lu is not None and dense.lu is None
    np.testing.assert_allclose(sparse.dense(), dense.S, rtol=1e-10, atol=1e-9 * np.abs(dense.S).max())
    dc, dx = normals.step(nrm, 1e-3)
    np.testing.assert_allclose(dc, dc_ref, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(dx, dx_ref, rtol=1e-8, atol=1e-12)


def _known_points_problem(shuffle=False):
    """The image observations of `_problem` with the points known (no point unknowns: self-calibration on a
    target field), 40 per image, sorted by image unless shuffled."""
    prob, start = _problem()
    img = prob.blocks[0]
    order = np.random.default_rng(5).permutation(len(img)) if shuffle else np.arange(len(img))
    blk = ImageObservations(img.camera, img.pose[order], img.point[order], img.uv[order], img.sigma[order], INTR, 0,
                            points_fixed=True)
    return Problem([blk], prob.n_poses, prob.n_points, len(INTR), point_free=np.zeros((prob.n_points, 3), bool)), start


def _item_sums(prob, state):
    """NumPy reference of the camera-side normals of one block of known points: sums of per-item products."""
    N, G = prob.n_poses, prob.n_globals
    ev = prob.blocks[0].evaluate(state, True)
    U = np.zeros((6 * N + G, 6 * N + G))
    g = np.zeros(6 * N + G)
    for k in range(len(ev.r)):
        cols = np.r_[6 * ev.pose[k] + np.arange(6), 6 * N + ev.glob]
        J = np.hstack([ev.J_pose[k], ev.J_glob[k]])
        U[np.ix_(cols, cols)] += J.T @ J
        g[cols] += J.T @ ev.r[k]
    return U, g


@pytest.mark.parametrize("shuffle", [False, True])
def test_normals_of_known_points_pose_by_pose_equal_the_item_sums(shuffle, monkeypatch):
    from dgcal.bundle.solver import normals
    prob, start = _known_points_problem(shuffle)
    assert len(prob.blocks[0]) >= normals.PER_POSE_PRODUCTS_MIN * prob.n_poses   # the per-pose products
    U_ref, g_ref = _item_sums(prob, start)
    nrm = linearise(prob, start)
    np.testing.assert_allclose(nrm.U, U_ref, rtol=1e-12, atol=1e-12 * np.abs(U_ref).max())
    np.testing.assert_allclose(nrm.g_c, g_ref, rtol=1e-12, atol=1e-12 * np.abs(g_ref).max())
    # the few-items-per-pose route (one sparse indicator product) and the item-by-item camera frames
    monkeypatch.setattr(normals, "PER_POSE_PRODUCTS_MIN", 10 ** 9)
    monkeypatch.setattr(ImageObservations, "RUN_MIN", 10 ** 9)
    prob2, _ = _known_points_problem(shuffle)
    nrm2 = linearise(prob2, start)
    np.testing.assert_allclose(nrm2.U, U_ref, rtol=1e-12, atol=1e-12 * np.abs(U_ref).max())
    np.testing.assert_allclose(nrm2.g_c, g_ref, rtol=1e-12, atol=1e-12 * np.abs(g_ref).max())
    assert nrm2.cost == pytest.approx(nrm.cost, rel=1e-12)


def _redundancy_reference(cov, block):
    """The redundancy numbers by the sparse matrix D = A_c - A_x V^-1 W^T of every row (NumPy/scipy)."""
    import scipy.sparse as sp
    ev = cov.normals.evals[block]
    k, d = ev.r.shape
    N, M, nc = cov.problem.n_poses, cov.problem.n_points, cov.problem.n_camera_side
    A = np.zeros((k * d, nc))
    rows = np.arange(k * d).reshape(k, d)
    if ev.J_pose is not None:
        for a in range(6):
            np.add.at(A, (rows, 6 * ev.pose[:, None] + a), ev.J_pose[:, :, a])
    if ev.J_glob is not None:
        for c, gcol in enumerate(ev.glob):
            A[rows, 6 * N + gcol] += ev.J_glob[:, :, c]
    q = np.zeros(k * d)
    D = A
    if ev.J_point is not None and M:
        Vinv = cov.reduced.Vinv[ev.point]
        q += np.einsum("kai,kij,kaj->ka", ev.J_point, Vinv, ev.J_point).ravel()
        AxV = np.einsum("kai,kij->kaj", ev.J_point, Vinv).reshape(k * d, 3)
        Ax_V = sp.csr_matrix((AxV.ravel(), (np.repeat(np.arange(k * d), 3),
                                            np.repeat(3 * ev.point[:, None] + np.arange(3), d, axis=0).ravel())),
                             shape=(k * d, 3 * M))
        D = A - (Ax_V @ cov.normals.W.T).toarray()
    Q = np.nan_to_num(cov.Q_cc)
    q += np.einsum("ri,ij,rj->r", D, Q, D)
    return (1.0 - q).reshape(k, d)


def test_compiled_redundancy_numbers_equal_the_sparse_product():
    prob, start = _problem()
    img = prob.blocks[0]
    for name in ("pose", "point"):          # a point measured twice in one image too
        setattr(img, name, np.r_[getattr(img, name), getattr(img, name)[:1]])
    img.uv = np.vstack([img.uv, img.uv[:1] + 0.5])
    img.sigma = np.vstack([img.sigma, img.sigma[:1]])
    sol = minimise(prob, start)
    cov = Covariance.at(prob, normals_at(prob, sol))
    for b in range(len(prob.blocks)):
        ref = _redundancy_reference(cov, b)
        np.testing.assert_allclose(cov.redundancy_numbers(b), ref, rtol=1e-9, atol=1e-12)
        items = np.arange(0, len(prob.blocks[b]), 3)            # a subset, in chunks of 7 items
        np.testing.assert_allclose(cov.redundancy_numbers(b, items, chunk=7), ref[items], rtol=1e-9, atol=1e-12)


def test_compiled_pose_global_and_global_point_couplings_equal_the_item_sums():
    prob, start = _problem()
    only = Problem([prob.blocks[0]], prob.n_poses, prob.n_points, prob.n_globals)
    nrm = linearise(only, start)
    ev = nrm.evals[0]
    N, M, G = only.n_poses, only.n_points, only.n_globals
    U_pg = np.zeros((6 * N, G))
    Wg = np.zeros((G, 3 * M))
    for k in range(len(ev.r)):
        U_pg[6 * ev.pose[k] + np.arange(6)[:, None], ev.glob[None, :]] += ev.J_pose[k].T @ ev.J_glob[k]
        Wg[ev.glob[:, None], 3 * ev.point[k] + np.arange(3)[None, :]] += ev.J_glob[k].T @ ev.J_point[k]
    scale = np.abs(U_pg).max()
    np.testing.assert_allclose(nrm.U[:6 * N, 6 * N:], U_pg, rtol=1e-12, atol=1e-13 * scale)
    np.testing.assert_allclose(nrm.Wg, Wg, rtol=1e-12, atol=1e-13 * np.abs(Wg).max())
