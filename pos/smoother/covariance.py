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

import gtsam
import numpy as np
import scipy.sparse as sp

from dgcal.fields.constants import C_LIGHT
from dgcal.pos.smoother.factors import B, CLK, DRIFT, V, X, ZERO


class KeyframeBlocks:
    """Variable layout of one keyframe block: X (6), V (3), B (6), one clock per system (1 each), drift (1)."""

    def __init__(self, K: int, systems: list, first: int = 0):
        """Blocks for keyframes first .. first+K-1 (numbered 0 .. K-1 here)."""
        self.K = K
        self.systems = list(systems)
        self.n = 15 + len(systems) + (1 if systems else 0)
        self.where: dict = {}
        for i in range(K):
            k = first + i
            self.where[X(k)] = (i, 0, 6)
            self.where[V(k)] = (i, 6, 3)
            self.where[B(k)] = (i, 9, 6)
            for j, s in enumerate(systems):
                self.where[CLK(s, k)] = (i, 15 + j, 1)
            if systems:
                self.where[DRIFT(k)] = (i, 15 + len(systems), 1)
        self.where[ZERO()] = None  # a pinned constant: conditioned on (its rows/columns dropped)
        # seconds -> metres for the clock variables (x_s = x_m / c)
        self.scale = np.ones(self.n)
        self.scale[15:] = 1.0 / C_LIGHT


_CACHE: dict = {}


def _accumulate(graph, values, blocks: KeyframeBlocks):
    """Cached `_assemble_sparse` (the smoothed covariances and the forward pass linearise at the same point)."""
    key = (id(graph), id(values), blocks.K, tuple(blocks.systems))
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is graph and hit[1] is values:
        return hit[2]
    out = _assemble_sparse(graph, values, blocks)
    _CACHE.clear()
    _CACHE[key] = (graph, values, out)
    return out


def _assemble_sparse(graph, values, blocks: KeyframeBlocks):
    """Information blocks per keyframe from the whitened sparse Jacobian of the linearised graph (one gtsam
    call, scipy products), clock columns in metres.

    Returns D (K,n,n): rows whose latest keyframe is k, on keyframe k; U (K-1,n,n): coupling of k and k+1;
    Dn (K,n,n): rows reaching keyframe k+1, on keyframe k; and the matching information vectors eD, en.

    Rows touching two keyframes are split into the part on the earlier keyframe (A_lo) and on the later
    one (A_hi): Dn = A_lo'A_lo, U = A_lo'A_hi, and A_hi'A_hi goes to D with the single-keyframe rows.
    """
    K, n = blocks.K, blocks.n
    lin = graph.linearize(values)
    ijs = lin.sparseJacobian_()
    rows = ijs[0].astype(np.int64) - 1
    cols = ijs[1].astype(np.int64) - 1
    vals = ijs[2]
    # gtsam orders the columns by sorted key; the last column is the right-hand side b
    keys = sorted(int(k) for k in values.keys())
    col_block = []
    col_off = []
    for key in keys:
        loc = blocks.where.get(key, "absent")
        dim = _key_dim(values, key)
        if loc is None or loc == "absent":
            col_block.extend([-1] * dim)  # ZERO: conditioned on
            col_off.extend([0] * dim)
        else:
            k, off, d = loc
            col_block.extend([k] * d)
            col_off.extend(range(off, off + d))
    col_block = np.array(col_block + [-2])  # -2: the b column
    col_off = np.array(col_off + [0])
    n_rows = int(rows.max()) + 1 if len(rows) else 0
    cb = col_block[cols]
    is_b = cb == -2
    b = np.zeros(n_rows)
    np.add.at(b, rows[is_b], vals[is_b])
    keep = cb >= 0
    r, c, v, kb = rows[keep], col_off[cols[keep]] + n * cb[keep], vals[keep], cb[keep]
    kmin = np.full(n_rows, K, np.int64)
    kmax = np.full(n_rows, -1, np.int64)
    np.minimum.at(kmin, r, kb)
    np.maximum.at(kmax, r, kb)
    pair = (kmax > kmin)[r]
    lo = pair & (kb == kmin[r])
    N = K * n
    shape = (n_rows, N)
    A_single_hi = sp.csr_matrix((v[~lo], (r[~lo], c[~lo])), shape=shape)
    A_lo = sp.csr_matrix((v[lo], (r[lo], c[lo])), shape=shape)
    A_hi_pair = sp.csr_matrix((v[pair & ~lo], (r[pair & ~lo], c[pair & ~lo])), shape=shape)
    H_D = (A_single_hi.T @ A_single_hi).tocsr()
    H_Dn = (A_lo.T @ A_lo).tocsr()
    H_U = (A_lo.T @ A_hi_pair).tocsr()
    e_D = A_single_hi.T @ b
    e_n = A_lo.T @ b
    D = np.empty((K, n, n))
    Dn = np.empty((K, n, n))
    U = np.zeros((max(K - 1, 0), n, n))
    for k in range(K):
        sl = slice(k * n, (k + 1) * n)
        D[k] = H_D[sl, sl].toarray()
        Dn[k] = H_Dn[sl, sl].toarray()
        if k < K - 1:
            U[k] = H_U[sl, slice((k + 1) * n, (k + 2) * n)].toarray()
    eD = e_D.reshape(K, n)
    en = e_n.reshape(K, n)
    ss = np.outer(blocks.scale, blocks.scale)
    return D * ss, U * ss, Dn * ss, eD * blocks.scale, en * blocks.scale


def _key_dim(values, key) -> int:
    sym = gtsam.Symbol(key).chr()
    return {ord("x"): 6, ord("v"): 3, ord("b"): 6}.get(sym, 1)


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
