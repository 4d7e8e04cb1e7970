"""The engine's assembly in parts (`Problem.chunk_items`: a chunkable block evaluated and summed a few items at a
time) and the camera side solved pose by pose (`normals.Arrow`): the same normal equations, steps, minimum and
covariances as the whole-block, dense engine (issue 16: `dgcal camera` on 5 M observations)."""
import numpy as np
import pytest

from dgcal.bundle.solver import normals
from dgcal.bundle.solver.blocks import ImageObservations
from dgcal.bundle.solver.covariance import Covariance
from dgcal.bundle.solver.lm import minimise, normals_at
from dgcal.bundle.solver.normals import Problem, linearise, reduce, solve_normals
from test_bundle_solver import INTR, _known_points_problem, _problem


def _with_chunks(prob: Problem, size: int | None) -> Problem:
    return Problem(prob.blocks, prob.n_poses, prob.n_points, prob.n_globals, prob.pose_free, prob.point_free,
                   prob.global_free, chunk_items=size)


def _close(a, b, rtol=1e-12):
    np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * max(np.abs(b).max(initial=0.0), 1e-300))


def _assert_same_normals(a, b):
    for name in ("U_pp", "U_pg", "U_gg", "g_c", "V", "g_x"):
        _close(getattr(a, name), getattr(b, name))
    assert a.cost == pytest.approx(b.cost, rel=1e-13)
    assert a.n_residuals == b.n_residuals and a.row_offsets == b.row_offsets
    assert np.array_equal(a.observed_c, b.observed_c) and np.array_equal(a.observed_x, b.observed_x)
    assert (a.wp_blocks is None) == (b.wp_blocks is None) and (a.Wg is None) == (b.Wg is None)
    if a.wp_blocks is not None:
        assert np.array_equal(a.wp_blocks, b.wp_blocks)      # per item, compiled in item order: bit for bit
    if a.Wg is not None:
        _close(a.Wg, b.Wg)


def test_chunked_normals_with_point_unknowns_equal_the_whole_block():
    prob, start = _problem()
    whole = linearise(prob, start)
    small = _with_chunks(prob, 7)
    assert len(small.parts(prob.blocks[0])) == -(-len(prob.blocks[0]) // 7)
    assert small.parts(prob.blocks[1]) == [None]                 # priors are not chunkable
    nrm = linearise(small, start)
    _assert_same_normals(nrm, whole)
    # the compiled per-item sums run in item order: the pose and point blocks are those of the whole block exactly
    assert np.array_equal(nrm.U_pp, whole.U_pp) and np.array_equal(nrm.V, whole.V)
    # the linearisation of a block summed in parts is evaluated again, whole, when asked for
    assert nrm._evals[0] is None
    for b in range(len(prob.blocks)):
        assert np.array_equal(nrm.evals[b].r, whole.evals[b].r)
        assert np.array_equal(nrm.evals[b].J_pose if nrm.evals[b].J_pose is not None else 0,
                              whole.evals[b].J_pose if whole.evals[b].J_pose is not None else 0)
        assert np.array_equal(nrm.weights[b], whole.weights[b])
    assert small.cost(start) == pytest.approx(prob.cost(start), rel=1e-13)
    for a, b in zip(small.block_costs(start), prob.block_costs(start)):
        assert np.array_equal(a, b)
    # the same minimum and covariances
    sol_a, sol_b = minimise(small, start), minimise(prob, start)
    assert sol_a.iterations == sol_b.iterations
    _close(sol_a.state.globals, sol_b.state.globals, 1e-10)
    _close(sol_a.state.points, sol_b.state.points, 1e-10)
    cov_a = Covariance.at(small, normals_at(small, sol_a))
    cov_b = Covariance.at(prob, normals_at(prob, sol_b))
    _close(np.nan_to_num(cov_a.Q_cc), np.nan_to_num(cov_b.Q_cc), 1e-8)
    _close(cov_a.redundancy_numbers(0), cov_b.redundancy_numbers(0), 1e-8)


@pytest.mark.parametrize("shuffle", [False, True])
def test_chunked_normals_of_known_points_equal_the_whole_block(shuffle):
    prob, start = _known_points_problem(shuffle)
    blk = prob.blocks[0]
    whole = linearise(prob, start)
    small = _with_chunks(prob, 50)
    parts = small.parts(blk)
    assert len(parts) > 1
    if not shuffle:       # sorted by image: a part ends where an image's items end (40 an image here)
        assert all(p.stop % 40 == 0 for p in parts[:-1])
    nrm = linearise(small, start)
    _assert_same_normals(nrm, whole)
    if not shuffle:       # each pose's products over the same rows as the whole block's
        assert np.array_equal(nrm.U_pp, whole.U_pp) and np.array_equal(nrm.U_pg, whole.U_pg)
    # the views of a part are reused (the per-part caches key on them) and follow a change of the items
    assert blk._part(parts[0], prob.n_poses)[0] is blk._part(parts[0], prob.n_poses)[0]
    blk.uv = blk.uv + 0.0
    assert blk._part(parts[0], prob.n_poses)[2].base is blk.uv


def _arrow_problem():
    """Known points, one image left without observations and one intrinsic held: unobserved and held
    parameters on the camera side."""
    prob, start = _known_points_problem()
    b = prob.blocks[0]
    keep = b.pose != 4
    blk = ImageObservations(b.camera, b.pose[keep], b.point[keep], b.uv[keep], b.sigma[keep], INTR, 0,
                            points_fixed=True)
    return Problem([blk], prob.n_poses, prob.n_points, prob.n_globals, point_free=prob.point_free,
                   global_free=np.array([True, False, True])), start


def test_camera_side_by_poses_equals_the_dense_solve(monkeypatch):
    prob, start = _arrow_problem()
    nrm = linearise(prob, start)
    monkeypatch.setattr(normals, "ARROW_MIN_POSES", 10 ** 9)
    dense = reduce(nrm, 1e-3)
    monkeypatch.setattr(normals, "ARROW_MIN_POSES", 1)
    arrow = reduce(nrm, 1e-3)
    assert dense.arrow is None and arrow.arrow is not None and arrow.S is None
    _close(arrow.scale, dense.scale, 1e-14)
    for b_c, b_x in ((-nrm.g_c, -nrm.g_x), (np.random.default_rng(1).normal(size=(len(nrm.g_c), 3)),
                                           np.zeros((len(nrm.g_x), 3)))):
        _close(solve_normals(nrm, arrow, b_c, b_x)[0], solve_normals(nrm, dense, b_c, b_x)[0], 1e-9)
    sol_a = minimise(prob, start)
    monkeypatch.setattr(normals, "ARROW_MIN_POSES", 10 ** 9)
    sol_d = minimise(prob, start)
    assert sol_a.iterations == sol_d.iterations
    _close(sol_a.state.globals, sol_d.state.globals, 1e-10)
    _close(sol_a.state.poses.C_world, sol_d.state.poses.C_world, 1e-10)
    cov_d = Covariance.at(prob, normals_at(prob, sol_d))
    monkeypatch.setattr(normals, "ARROW_MIN_POSES", 1)
    cov_a = Covariance.at(prob, normals_at(prob, sol_d))
    assert cov_a.camera_side.Q is None and cov_d.camera_side.Q is not None
    bad = ~cov_d.normals.observed_c
    assert bad[6 * 4:6 * 5].all() and bad[6 * 5 + 1]           # the unobserved image, the held intrinsic
    _close(np.nan_to_num(cov_a.pose_cofactors()), np.nan_to_num(cov_d.pose_cofactors()), 1e-9)
    _close(np.nan_to_num(cov_a.global_cofactors()), np.nan_to_num(cov_d.global_cofactors()), 1e-9)
    assert np.array_equal(np.isnan(cov_a.pose_cofactors()), np.isnan(cov_d.pose_cofactors()))
    assert np.array_equal(np.isnan(cov_a.global_cofactors()), np.isnan(cov_d.global_cofactors()))
    L = np.random.default_rng(2).normal(size=(4, prob.n_camera_side))
    _close(cov_a.camera_side.scaled(2.0).sandwich(L), cov_d.camera_side.scaled(2.0).sandwich(L), 1e-9)
    _close(cov_a.camera_side.sandwich(L), L @ np.nan_to_num(cov_d.Q_cc) @ L.T, 1e-9)
    Qa = cov_a.Q_cc                                             # the dense matrix, built when asked for
    assert np.array_equal(np.isnan(Qa), np.isnan(cov_d.Q_cc))
    _close(np.nan_to_num(Qa), np.nan_to_num(cov_d.Q_cc), 1e-9)
