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
    """Variable layout of one keyframe block: X (6), V (3), B (6), one clock per system (1 each), drift (1) and
    the slots of the satellites' code biases (1 each, `dgcal.pos.smoother.code_bias`; a slot without an arc at a
    keyframe has no variable there and is carried with unit information, coupled to nothing)."""

    def __init__(self, K: int, systems: list, first: int = 0, arcs=None):
        """Blocks for keyframes first .. first+K-1 (numbered 0 .. K-1 here)."""
        self.K = K
        self.systems = list(systems)
        self.n_slots = arcs.n_slots if arcs is not None else 0
        self.base = 15 + len(systems) + (1 if systems else 0)
        self.n = self.base + self.n_slots
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
        self.active = np.ones((K, self.n), bool)
        if self.n_slots:
            self.active[:, self.base:] = arcs.active(first + K)[first:first + K]
            for key, (k, slot) in arcs.where().items():
                if first <= k < first + K:
                    self.where[key] = (k - first, self.base + slot, 1)
        self.where[ZERO()] = None  # a pinned constant: conditioned on (its rows/columns dropped)
        # seconds -> metres for the clock variables (x_s = x_m / c); the code biases are in metres already
        self.scale = np.ones(self.n)
        self.scale[15:self.base] = 1.0 / C_LIGHT

    def pad_inactive(self, D: np.ndarray) -> np.ndarray:
        """D (K,n,n) with unit information on the diagonal of every slot without a variable (in place)."""
        if self.n_slots:
            i = np.arange(self.n)
            D[:, i, i] += ~self.active
        return D


_CACHE: dict = {}


def _accumulate(graph, values, blocks: KeyframeBlocks):
    """Cached `_assemble_sparse` (the smoothed covariances and the forward pass linearise at the same point)."""
    key = (id(graph), id(values), blocks.K, tuple(blocks.systems), blocks.n_slots)
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is graph and hit[1] is values:
        return hit[2]
    out = _assemble_sparse(graph, values, blocks)
    _CACHE.clear()
    _CACHE[key] = (graph, values, out)
    return out


def whitened_jacobian(graph, values, blocks: KeyframeBlocks):
    """The whitened Jacobian of the graph linearised at `values` as triplets on the keyframe blocks: row, global
    column (keyframe * n + offset, clock columns in metres), value and keyframe of every entry, the right-hand
    side b per row (the error is A x - b) and the number of rows (gtsam's rows: the graph's factors in order,
    `factor.dim()` each). Columns of keys outside the blocks (ZERO) are dropped: conditioned on."""
    n = blocks.n
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
    n_rows = int(sum(graph.at(i).dim() for i in range(graph.size())))
    cb = col_block[cols]
    is_b = cb == -2
    b = np.zeros(n_rows)
    np.add.at(b, rows[is_b], vals[is_b])
    keep = cb >= 0
    off = col_off[cols[keep]]
    return rows[keep], off + n * cb[keep], vals[keep] * blocks.scale[off], cb[keep], b, n_rows


def _assemble_sparse(graph, values, blocks: KeyframeBlocks):
    """Information blocks per keyframe from the whitened sparse Jacobian of the linearised graph (one gtsam
    call, scipy products), clock columns in metres.

    Returns D (K,n,n): rows whose latest keyframe is k, on keyframe k; U (K-1,n,n): coupling of k and k+1;
    Dn (K,n,n): rows reaching keyframe k+1, on keyframe k; and the matching information vectors eD, en.

    Rows touching two keyframes are split into the part on the earlier keyframe (A_lo) and on the later
    one (A_hi): Dn = A_lo'A_lo, U = A_lo'A_hi, and A_hi'A_hi goes to D with the single-keyframe rows.
    """
    K, n = blocks.K, blocks.n
    r, c, v, kb, b, n_rows = whitened_jacobian(graph, values, blocks)
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
    return D, U, Dn, e_D.reshape(K, n), e_n.reshape(K, n)


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
    D = blocks.pad_inactive(D + Dn)
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
    D = blocks.pad_inactive(D.copy())
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


def forward_innovations(graph, values, blocks: KeyframeBlocks, row_kind: np.ndarray, kinds: list):
    """Kalman filter on the graph linearised at `values`, with innovations: for each keyframe k the correction
    (K,n) to its linearisation point and the covariance (K,n,n) given only the data up to k (clock entries in s,
    s/s), the normalised innovation squared of each measurement kind at k, kind -> [(k, NIS, rows)], and every
    measurement row's whitened innovation (NaN for process rows).

    `row_kind` (rows of `whitened_jacobian`): -1 for process rows (priors, IMU, clock and bias processes), else the
    index in `kinds` of the measurement the row belongs to. At keyframe k the filtered k-1 and the process rows
    ending at k give the predicted joint of (k-1, k); each kind's rows A, b (error A x - b) at the predicted mean
    x give NIS = r' (A P A' + I)^-1 r, r = A x - b; then all measurement rows update and k-1 is marginalised."""
    K, n = blocks.K, blocks.n
    r, c, v, kb, b, n_rows = whitened_jacobian(graph, values, blocks)
    kmax = np.full(n_rows, -1, np.int64)
    np.maximum.at(kmax, r, kb)
    innov = np.full(n_rows, np.nan)
    # dense rows per keyframe: columns 0..n-1 keyframe k-1, n..2n-1 keyframe k
    col2 = c - n * kmax[r] + n
    order = np.argsort(kmax[r], kind="stable")
    bounds = np.searchsorted(kmax[r][order], np.arange(K + 1))
    pad = np.zeros((K, n))
    if blocks.n_slots:
        pad[~blocks.active] = 1.0
    P = np.empty((K, n, n))
    dx = np.empty((K, n))
    nis: dict = {}
    S = np.zeros((n, n))
    y = np.zeros(n)
    for k in range(K):
        e = order[bounds[k]:bounds[k + 1]]
        rows_k = np.unique(r[e])
        loc = np.searchsorted(rows_k, r[e])
        A = np.zeros((len(rows_k), 2 * n))
        np.add.at(A, (loc, col2[e]), v[e])
        bk = b[rows_k]
        kind = row_kind[rows_k]
        proc = kind < 0
        J = A[proc].T @ A[proc]
        g = A[proc].T @ bk[proc]
        J[:n, :n] += S
        g[:n] += y
        J[n:, n:] += np.diag(pad[k])
        if k == 0:
            J[:n, :n] += np.eye(n)         # no keyframe before the first: a decoupled placeholder
        Pj = _inv_sym(J)
        x = Pj @ g
        for kd in np.unique(kind[~proc]):
            m = kind == kd
            Am = A[m]
            res = Am @ x - bk[m]
            innov[rows_k[m]] = res
            Sm = Am @ Pj @ Am.T + np.eye(int(m.sum()))
            try:
                val = float(res @ np.linalg.solve(Sm, res))
            except np.linalg.LinAlgError:
                continue
            nis.setdefault(kinds[kd], []).append((k, val, int(m.sum())))
        meas = ~proc
        J += A[meas].T @ A[meas]
        g += A[meas].T @ bk[meas]
        Jll = 0.5 * (J[:n, :n] + J[:n, :n].T)
        G = np.linalg.solve(Jll, np.column_stack([J[:n, n:], g[:n]]))
        S = J[n:, n:] - J[n:, :n] @ G[:, :n]
        y = g[n:] - J[n:, :n] @ G[:, n]
        S = 0.5 * (S + S.T)
        P[k] = _inv_sym(S)
        dx[k] = P[k] @ y
    return dx * blocks.scale, np.stack([_unscale(p, blocks) for p in P]), nis, innov
