"""Integer ambiguity resolution: LAMBDA (decorrelation + search), partial fixing, ratio test, fixed solution.

LAMBDA (Teunissen 1995; the MLAMBDA search of Chang, Yang & Zhou 2005, as in RTKLIB's ``lambda.c``):
the float ambiguities ``a`` with covariance ``Q = L' diag(D) L`` are decorrelated by integer Gauss
transformations and permutations ``z = Z' a`` (``Z`` unimodular), then the two integer vectors closest
to ``z`` in the metric of ``Q_z`` are found by a shrinking depth-first search. ``resolve`` tries the
full set first; if its ratio test fails it fixes the largest trailing subset of the decorrelated
ambiguities whose bootstrapped success rate is at least ``p0`` (partial ambiguity resolution in the
decorrelated space, which fixes e.g. wide-lane-like combinations before the narrow lanes) and ratio-
tests that subset. A fix is returned as integer constraints ``C a = c`` (rows of ``Z'``), which
``fixed_solution`` applies to any float state that contains ``a`` linearly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.linalg.lapack import dgesv
from scipy.special import erf

LOOP_MAX = 100000


def gesv(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(A, B)`` by LAPACK's dgesv called directly (the same LU factorisation; bits may differ
    between numpy's and scipy's LAPACK builds), without NumPy's per-call overhead (most of the filter's time)."""
    _lu, _piv, X, info = dgesv(A, B)
    if info > 0:
        raise np.linalg.LinAlgError("singular matrix")
    return X


def ldl(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Q = L' diag(D) L`` with L unit lower triangular (the factorisation LAMBDA works on)."""
    L, D, ok = _ldl(np.array(Q, dtype=float, copy=True))
    if not ok:
        raise np.linalg.LinAlgError("ambiguity covariance is not positive definite")
    return L, D


@njit(cache=True)
def _ldl(A):  # pragma: no cover - compiled
    """The factorisation of `ldl` on A (overwritten), from the last row up; ok False at a non-positive pivot."""
    n = A.shape[0]
    L = np.zeros((n, n))
    D = np.zeros(n)
    for i in range(n - 1, -1, -1):
        D[i] = A[i, i]
        if D[i] <= 0.0:
            return L, D, False
        a = math.sqrt(D[i])
        for q in range(i + 1):
            L[i, q] = A[i, q] / a
        for p in range(i):
            for q in range(i):
                A[p, q] -= L[i, p] * L[i, q]
        d = L[i, i]
        for q in range(i + 1):
            L[i, q] /= d
    return L, D, True


def decorrelate(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """LAMBDA reduction: (L, D, Z) with ``Z' Q Z = L' diag(D) L`` decorrelated, Z integer unimodular.

    Chang, Yang & Zhou's MREDUCTION strategy: a column is size-reduced whole before its swap test unless it
    was since the last permutation ("lazy" transformations), and the sweep steps back one position after a swap
    instead of restarting; a final pass size-reduces all of L.
    """
    L, Dv = ldl(Q)
    Lt = np.ascontiguousarray(L.T)               # Lt[j, i] = L[i, j]: column updates on contiguous rows
    Zt = np.eye(len(Dv))                         # Zt[j] = column j of Z
    D = Dv.copy()
    _reduce(Lt, D, Zt)
    return np.ascontiguousarray(Lt.T), D, np.ascontiguousarray(Zt.T)


@njit(cache=True)
def _reduce(Lt, D, Zt):  # pragma: no cover - compiled
    """The permutation sweep (a column size-reduced unless it was since the last permutation) and the final size
    reduction, in place (see decorrelate)."""
    n = len(D)
    k = n - 2
    k1 = n - 2                                   # the last permuted column: the ones below it are reduced
    while k >= 0:
        if k <= k1:
            # all of column k before the swap test (RTKLIB's gauss for every i > k): reducing only L[k+1, k] lets
            # the other entries grow through the swaps (to 1e9 and beyond with 56 ambiguities), and Z'QZ then no
            # longer equals L'DL
            _size_reduce_column(Lt, Zt, k)
        l1 = Lt[k, k + 1]
        delta = D[k] + l1 * l1 * D[k + 1]
        if delta + 1e-6 < D[k + 1]:
            eta = D[k] / delta
            lam = D[k + 1] * l1 / delta
            D[k] = eta * D[k + 1]
            D[k + 1] = delta
            for i in range(k):
                a0 = Lt[i, k]
                a1 = Lt[i, k + 1]
                Lt[i, k] = -l1 * a0 + a1
                Lt[i, k + 1] = eta * a0 + lam * a1
            Lt[k, k + 1] = lam
            for i in range(k + 2, n):
                tmp = Lt[k, i]
                Lt[k, i] = Lt[k + 1, i]
                Lt[k + 1, i] = tmp
            for i in range(n):
                tmp = Zt[k, i]
                Zt[k, i] = Zt[k + 1, i]
                Zt[k + 1, i] = tmp
            k1 = k
            if k < n - 2:
                k += 1
        else:
            k -= 1
    for j in range(n - 2, -1, -1):
        _size_reduce_column(Lt, Zt, j)


@njit(cache=True)
def _size_reduce_column(Lt, Zt, k):  # pragma: no cover - compiled
    """Integer Gauss transformations making |L[i, k]| <= 1/2 for every i > k (Lt = L', Zt = Z'), in place."""
    n = Lt.shape[0]
    for i in range(k + 1, n):
        mu = math.floor(Lt[k, i] + 0.5)
        if mu != 0:
            for q in range(i, n):
                Lt[k, q] -= mu * Lt[i, q]
            for q in range(n):
                Zt[k, q] -= mu * Zt[i, q]


def search(L: np.ndarray, D: np.ndarray, zs: np.ndarray, m: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The ``m`` best integer vectors (columns, best first) and squared distances for decorrelated floats ``zs``."""
    zn, s = _search(np.ascontiguousarray(L, dtype=float), np.ascontiguousarray(D, dtype=float),
                    np.ascontiguousarray(zs, dtype=float), m, LOOP_MAX)
    order = np.argsort(s)
    return zn[:, order], s[order]


@njit(cache=True)
def _search(L, D, zs, m, loop_max):  # pragma: no cover - compiled
    """MLAMBDA's shrinking depth-first search (see `search`); candidates in the order found."""
    n = len(D)
    S = np.zeros((n, n))
    dist = np.zeros(n)
    zb = np.zeros(n)
    z = np.zeros(n)
    step = np.zeros(n)
    zn = np.zeros((n, m))
    s = np.full(m, np.inf)
    nn, imax = 0, 0
    maxdist = np.inf
    k = n - 1
    zb[k] = zs[k]
    z[k] = np.rint(zb[k])
    y = zb[k] - z[k]
    step[k] = 1.0 if y > 0 else -1.0
    for _ in range(loop_max):
        newdist = dist[k] + y * y / D[k]
        if newdist < maxdist:
            if k != 0:
                k -= 1
                dist[k] = newdist
                dz = z[k + 1] - zb[k + 1]
                for q in range(k + 1):
                    S[k, q] = S[k + 1, q] + dz * L[k + 1, q]
                zb[k] = zs[k] + S[k, k]
                z[k] = np.rint(zb[k])
                y = zb[k] - z[k]
                step[k] = 1.0 if y > 0 else -1.0
            else:
                if nn < m:
                    if nn == 0 or newdist > s[imax]:
                        imax = nn
                    for q in range(n):               # element by element: a slice assignment
                        zn[q, nn] = z[q]             # costs numba seconds of compilation
                    s[nn] = newdist
                    nn += 1
                else:
                    if newdist < s[imax]:
                        for q in range(n):
                            zn[q, imax] = z[q]
                        s[imax] = newdist
                        imax = np.argmax(s)
                    maxdist = s[imax]
                z[0] += step[0]
                y = zb[0] - z[0]
                step[0] = -step[0] - (1.0 if step[0] > 0 else -1.0)
        else:
            if k == n - 1:
                break
            k += 1
            z[k] += step[k]
            y = zb[k] - z[k]
            step[k] = -step[k] - (1.0 if step[k] > 0 else -1.0)
    return zn, s


def lambda_ils(a: np.ndarray, Q: np.ndarray, m: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Integer least squares: the ``m`` best integer vectors for float ``a`` (columns) and their squared norms."""
    L, D, Z = decorrelate(Q)
    zs = Z.T @ a
    zn, s = search(L, D, zs, m)
    return np.round(np.linalg.solve(Z.T, zn)), s


def bootstrap_success_rate(D: np.ndarray) -> float:
    """Bootstrapped success rate of the decorrelated ambiguities with conditional variances ``D`` (cycles^2)."""
    return float(np.prod(erf(1.0 / (2.0 * np.sqrt(2.0 * np.asarray(D, float))))))


@dataclass
class AmbiguityFix:
    """Result of ``resolve``: integer constraints ``C a = c`` (k x n, k) when ``fixed``; the ratio of the
    second-best to the best squared norm, the best norm ``s1``, the bootstrapped success rate of the
    fixed set and whether it is the full set or a partial one."""

    fixed: bool
    C: np.ndarray
    c: np.ndarray
    ratio: float
    s1: float
    success_rate: float
    n_fixed: int
    mode: str


def resolve(a: np.ndarray, Q: np.ndarray, ratio_threshold: float = 3.0, p0: float = 0.999,
            min_fix: int = 4, partial: bool = True) -> AmbiguityFix:
    """Fix float ambiguities ``a`` (cycles, covariance ``Q``): full set, else the partial set (see module doc)."""
    n = len(a)
    if n < min_fix:
        return AmbiguityFix(False, np.zeros((0, n)), np.zeros(0), 0.0, np.nan, 0.0, 0, "none")
    # most precise ambiguities last (where the factorisation starts): fewer permutations
    order = np.argsort(-np.diag(Q), kind="stable")
    Qs = Q[order][:, order]
    try:
        L, D, Z = decorrelate(0.5 * (Qs + Qs.T))
    except np.linalg.LinAlgError:
        return AmbiguityFix(False, np.zeros((0, n)), np.zeros(0), 0.0, np.nan, 0.0, 0, "none")
    Z = Z[np.argsort(order)]                   # z = Z' a with the permutation (a_sorted = a[order]) folded in
    zs = Z.T @ a
    zn, s = search(L, D, zs, 2)
    ratio = s[1] / max(s[0], 1e-12)
    ps = bootstrap_success_rate(D)
    best = AmbiguityFix(True, Z.T.copy(), zn[:, 0].copy(), float(ratio), float(s[0]), ps, n, "full")
    if ratio >= ratio_threshold:
        return best
    if not partial:
        best.fixed = False
        return best
    # largest trailing subset of the decorrelated ambiguities with success rate >= p0
    cum = np.cumprod(erf(1.0 / (2.0 * np.sqrt(2.0 * D[::-1]))))[::-1]   # cum[k] = P(z_k..z_{n-1})
    good = np.nonzero(cum >= p0)[0]
    k0 = int(good[0]) if len(good) else n
    for k in (k0, k0 + 1, k0 + 2):
        if k == 0 or n - k < min_fix:
            continue
        zn_k, s_k = search(L[k:, k:], D[k:], zs[k:], 2)
        r_k = s_k[1] / max(s_k[0], 1e-12)
        if r_k >= ratio_threshold:
            return AmbiguityFix(True, Z.T[k:].copy(), zn_k[:, 0].copy(), float(r_k), float(s_k[0]),
                                float(cum[k]), n - k, "partial")
    best.fixed = False
    return best


def fixed_solution(x: np.ndarray, P: np.ndarray, D_amb: np.ndarray, fix: AmbiguityFix,
                   var_extra: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Condition a float state (x, P) on the fix ``C (D_amb x) = c``; returns (x_fixed, P_fixed, chi2 of the fix).

    ``D_amb`` (n_amb x n_state) maps the state to the ambiguities given to ``resolve``. The chi-square is
    ``(C a - c)' (C Q_a C')^-1 (C a - c)`` (the squared norm of the float-to-fixed correction); ``var_extra``
    (n_state,): variances of state errors the float covariance leaves out, added to ``Q_a`` of the chi-square only.
    """
    A = fix.C @ D_amb                          # constraint rows on the state
    r = fix.c - A @ x
    AP = A @ P
    S = AP @ A.T
    K = gesv(S, AP).T                          # P A' S^-1
    xf = x + K @ r
    Pf = P - K @ A @ P
    if var_extra is not None:
        S = S + (A * var_extra) @ A.T
    chi2 = float(r @ gesv(S, r))
    return xf, 0.5 * (Pf + Pf.T), chi2
