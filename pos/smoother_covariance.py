"""Covariances of the smoother's keyframe states from the linearised graph, by block-tridiagonal recursion.

Why not `gtsam.Marginals`: the receiver clock variables are in seconds (gtsam's GNSS factors), so their
Jacobian columns are ~c/sigma = 1e9 larger than the others and the Cholesky of the normal matrix breaks
down (Jacobian condition ~1e10). Here every factor's information block is assembled per keyframe with the
clock columns rescaled to metres, and the marginals follow from the exact block-tridiagonal recursion
(forward Schur complements, backward Rauch-Tung-Striebel pass). The same forward pass restricted to the
factors available at each epoch is a Kalman filter in information form (`forward_pass`).

Covariances are in gtsam's local coordinates: Pose3 = [rotation (body, rad), position (body axes, m)].
"""
from __future__ import annotations

import numpy as np

from pos.nav_frame import C_LIGHT
from pos.smoother_factors import B, CLK, DRIFT, V, X, ZERO


class KeyframeBlocks:
    """Variable layout of one keyframe block: X (6), V (3), B (6), one clock per system (1 each), drift (1)."""

    def __init__(self, K: int, systems: list):
        self.K = K
        self.systems = list(systems)
        self.n = 15 + len(systems) + (1 if systems else 0)
        self.where: dict = {}
        for k in range(K):
            self.where[X(k)] = (k, 0, 6)
            self.where[V(k)] = (k, 6, 3)
            self.where[B(k)] = (k, 9, 6)
            for j, s in enumerate(systems):
                self.where[CLK(s, k)] = (k, 15 + j, 1)
            if systems:
                self.where[DRIFT(k)] = (k, 15 + len(systems), 1)
        self.where[ZERO()] = None  # a pinned constant: conditioned on (its rows/columns dropped)
        # seconds -> metres for the clock variables (x_s = x_m / c)
        self.scale = np.ones(self.n)
        self.scale[15:] = 1.0 / C_LIGHT


_CACHE: dict = {}


def _accumulate(graph, values, blocks: KeyframeBlocks):
    """Cached `_assemble` (the smoothed covariances and the forward pass linearise at the same point)."""
    key = (id(graph), id(values), blocks.K, tuple(blocks.systems))
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is graph and hit[1] is values:
        return hit[2]
    out = _assemble(graph, values, blocks)
    _CACHE.clear()
    _CACHE[key] = (graph, values, out)
    return out


def _assemble(graph, values, blocks: KeyframeBlocks):
    """Information blocks of the linearised graph per keyframe, clock columns in metres.

    Returns D (K,n,n): factors whose latest keyframe is k, on keyframe k; U (K-1,n,n): coupling of k and k+1;
    Dn (K,n,n): factors reaching keyframe k+1, on keyframe k.
    """
    K, n = blocks.K, blocks.n
    D = np.zeros((K, n, n))
    U = np.zeros((max(K - 1, 0), n, n))
    Dn = np.zeros((K, n, n))
    eD = np.zeros((K, n))
    en = np.zeros((K, n))
    lin = graph.linearize(values)
    where = blocks.where
    cache: dict = {}
    for i in range(lin.size()):
        f = lin.at(i)
        locs = [where[key] for key in f.keys()]
        aug = f.augmentedInformation()
        info, eta = aug[:-1, :-1], aug[:-1, -1]
        if None in locs:
            # only ZERO (dim 1) is None; drop its rows/columns
            dims = [1 if l is None else l[2] for l in locs]
            keep = np.concatenate([np.full(d, l is not None) for d, l in zip(dims, locs)])
            info, eta = info[np.ix_(keep, keep)], eta[keep]
            locs = [l for l in locs if l is not None]
            if not locs:
                continue
        k0 = min(l[0] for l in locs)
        k1 = max(l[0] for l in locs)
        if k1 - k0 > 1:
            raise ValueError("factor spans more than two keyframes")
        pattern = tuple((k - k0, off, dim) for (k, off, dim) in locs)
        ix = cache.get(pattern)
        if ix is None:
            ix = cache[pattern] = _pattern_index(pattern)
        (a00, b00), (a11, b11), (a01, b01) = ix
        if k1 == k0:
            D[k0][a00] += info[b00]
            eD[k0][a00[0][:, 0]] += eta[b00[0][:, 0]]
        else:
            Dn[k0][a00] += info[b00]
            D[k1][a11] += info[b11]
            U[k0][a01] += info[b01]
            en[k0][a00[0][:, 0]] += eta[b00[0][:, 0]]
            eD[k1][a11[0][:, 0]] += eta[b11[0][:, 0]]
    ss = np.outer(blocks.scale, blocks.scale)
    return D * ss, U * ss, Dn * ss, eD * blocks.scale, en * blocks.scale


def _pattern_index(pattern):
    i0, i1, j0, j1 = [], [], [], []  # positions inside the keyframe blocks, and inside the factor's info
    c = 0
    for (dk, off, dim) in pattern:
        (i0 if dk == 0 else i1).extend(range(off, off + dim))
        (j0 if dk == 0 else j1).extend(range(c, c + dim))
        c += dim
    return ((np.ix_(i0, i0), np.ix_(j0, j0)), (np.ix_(i1, i1), np.ix_(j1, j1)), (np.ix_(i0, i1), np.ix_(j0, j1)))


def _unscale(P: np.ndarray, blocks: KeyframeBlocks) -> np.ndarray:
    s = blocks.scale
    return P * s[:, None] * s[None, :]


def smoothed_covariances(graph, values, blocks: KeyframeBlocks) -> np.ndarray:
    """Marginal covariance (K,n,n) of every keyframe block given all data (clock entries in s, s/s)."""
    K, n = blocks.K, blocks.n
    D, U, Dn, _, _ = _accumulate(graph, values, blocks)
    D = D + Dn
    Sinv = np.empty((K, n, n))
    S = D[0]
    for k in range(K):
        if k > 0:
            G = Sinv[k - 1] @ U[k - 1]
            S = D[k] - U[k - 1].T @ G
        Sinv[k] = _inv_sym(S)
    P = np.empty((K, n, n))
    P[K - 1] = Sinv[K - 1]
    for k in range(K - 2, -1, -1):
        G = Sinv[k] @ U[k]
        P[k] = Sinv[k] + G @ P[k + 1] @ G.T
    return np.stack([_unscale(p, blocks) for p in P])


def forward_pass(graph, values, blocks: KeyframeBlocks) -> tuple[np.ndarray, np.ndarray]:
    """Kalman filter on the graph linearised at `values`: for each keyframe k the correction (K,n) to its
    linearisation point and the covariance (K,n,n) given only the factors up to keyframe k (clock entries
    in s, s/s)."""
    K, n = blocks.K, blocks.n
    D, U, Dn, eD, en = _accumulate(graph, values, blocks)
    P = np.empty((K, n, n))
    dx = np.empty((K, n))
    S, y = D[0], eD[0]
    P[0] = _inv_sym(S)
    dx[0] = P[0] @ y
    for k in range(1, K):
        Sp = S + Dn[k - 1]  # previous keyframe's information including the factors that reach k
        yp = y + en[k - 1]
        G = np.linalg.solve(Sp, np.column_stack([U[k - 1], yp]))
        S = D[k] - U[k - 1].T @ G[:, :n]
        y = eD[k] - U[k - 1].T @ G[:, n]
        P[k] = _inv_sym(S)
        dx[k] = P[k] @ y
    return dx * blocks.scale, np.stack([_unscale(p, blocks) for p in P])


def _inv_sym(S: np.ndarray) -> np.ndarray:
    Si = np.linalg.inv(0.5 * (S + S.T))
    return 0.5 * (Si + Si.T)
