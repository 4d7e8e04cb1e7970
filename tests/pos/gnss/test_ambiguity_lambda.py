"""LAMBDA on float-ambiguity covariances like GNSS ones (a few position unknowns make them nearly singular and
strongly correlated): the decorrelation is an exact integer unimodular change of variables (Z'QZ = L'DL, L
size-reduced), also with 60 ambiguities, and decorrelation + search find the integer least-squares solution
that brute force finds."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from dgcal.pos.gnss.ambiguity import decorrelate, search


def _gnss_like_q(rng, n: int) -> np.ndarray:
    """Covariance of n float ambiguities dominated by 3 geometry unknowns (condition number ~1e6-1e9)."""
    G = rng.standard_normal((n, 3)) * rng.uniform(1, 50)
    return G @ G.T * 1e2 + np.diag(rng.uniform(1e-4, 1e-2, n))


@pytest.mark.parametrize("n", [2, 8, 23, 56, 60])
def test_decorrelation_is_an_exact_unimodular_transformation(n):
    rng = np.random.default_rng(n)
    for _ in range(5):
        Q = _gnss_like_q(rng, n)
        L, D, Z = decorrelate(Q)
        assert np.array_equal(Z, np.round(Z)) and abs(np.linalg.slogdet(Z)[1]) < 1e-6   # integer, |det| 1
        lhs, rhs = Z.T @ Q @ Z, L.T @ np.diag(D) @ L
        assert np.abs(lhs - rhs).max() <= 1e-6 * np.abs(lhs).max()
        assert np.abs(np.tril(L, -1)).max(initial=0.0) <= 0.5 + 1e-9                     # size-reduced
        assert np.abs(Z).max() < 1e6                                                       # no runaway growth


def test_decorrelation_and_search_find_the_integer_least_squares_solution():
    rng = np.random.default_rng(5)
    for _ in range(20):
        n = 4
        Q = _gnss_like_q(rng, n) * 1e-4 + np.diag(rng.uniform(0.01, 0.05, n))
        a = rng.normal(0, 20, n)
        Qi = np.linalg.inv(Q)
        box = [np.arange(np.floor(v) - 6, np.ceil(v) + 7) for v in a]
        best = min((float((a - np.array(c)) @ Qi @ (a - np.array(c))), c) for c in itertools.product(*box))
        L, D, Z = decorrelate(Q)
        zn, s = search(L, D, Z.T @ a, 2)
        a_fix = np.linalg.solve(Z.T, zn[:, 0])
        assert np.allclose(a_fix, best[1]) and s[0] == pytest.approx(best[0], rel=1e-6)
