"""The compiled keyframe recursions against dense linear algebra on random block-tridiagonal systems."""
import numpy as np

from dgcal.pos.smoother.recursions import information_filter, rts_covariances, rts_step, schur_inverses


def _chain(K: int, n: int, seed: int):
    """Random pair informations J[k] (2n,2n) over (k-1, k) (SPD), vectors g[k], and their dense sum (K n, K n)."""
    rng = np.random.default_rng(seed)
    J = np.empty((K, 2 * n, 2 * n))
    g = rng.normal(size=(K, 2 * n))
    H = np.zeros((K * n + n, K * n + n))   # a placeholder block for "keyframe -1" in front
    b = np.zeros(K * n + n)
    for k in range(K):
        A = rng.normal(size=(3 * n, 2 * n))
        J[k] = A.T @ A
        s = slice(k * n, k * n + 2 * n)
        H[s, s] += J[k]
        b[s] += g[k]
    H[:n, :n] += np.eye(n)
    return J, g, H, b


def test_schur_and_rts_equal_the_dense_inverse_and_solution():
    K, n = 7, 4
    _, _, H, b = _chain(K, n, 0)
    H, b = H[n:, n:] + np.eye(K * n) * 0.0, b[n:]     # the chain without the placeholder
    D = np.stack([H[k * n:(k + 1) * n, k * n:(k + 1) * n] for k in range(K)])
    U = np.stack([H[k * n:(k + 1) * n, (k + 1) * n:(k + 2) * n] for k in range(K - 1)])
    Sinv = schur_inverses(D, U)
    G = Sinv[:-1] @ U
    P = rts_covariances(Sinv, G)
    dx = rts_step(Sinv, G, b.reshape(K, n))
    C = np.linalg.inv(H)
    for k in range(K):
        np.testing.assert_allclose(P[k], C[k * n:(k + 1) * n, k * n:(k + 1) * n], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(dx.ravel(), np.linalg.solve(H, b), rtol=1e-9, atol=1e-12)


def test_information_filter_equals_the_dense_marginal_of_the_rows_so_far():
    K, n = 6, 3
    J, g, _, _ = _chain(K, n, 1)
    Jr = J.copy()
    Jr[0, :n, :n] += np.eye(n)
    Sf, yf = information_filter(Jr, g, n)
    for k in range(K):
        m = (k + 2) * n                    # placeholder + keyframes 0..k
        H = np.zeros((m, m))
        b = np.zeros(m)
        for j in range(k + 1):
            s = slice(j * n, j * n + 2 * n)
            H[s, s] += J[j]
            b[s] += g[j]
        H[:n, :n] += np.eye(n)
        C = np.linalg.inv(H)
        P_k = C[-n:, -n:]
        np.testing.assert_allclose(np.linalg.inv(Sf[k]), P_k, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(np.linalg.solve(Sf[k], yf[k]), np.linalg.solve(H, b)[-n:], rtol=1e-8, atol=1e-12)
