"""The smoother's graph linearised at one point, arranged by keyframe: the block layout of the states, the whitened
Jacobian on it, and every row under the latest keyframe it reaches as a dense row over that keyframe's block and
the one before.

Every factor of the smoother touches one keyframe or two consecutive ones (the pinned ZERO aside), so these
per-keyframe rows hold the whole linearised problem: the information of a keyframe pair is one batched matrix
product, and the covariances (RTS recursion), the forward pass with its innovations, the post-fit residuals and
the outlier tests all read the same rows (`dgcal.pos.smoother.covariance`, `dgcal.pos.smoother.integrity`). One
linearisation at the solution serves them all.

The receiver clock variables are in seconds in gtsam (`dgcal.pos.smoother.factors`); here their columns are
rescaled to metres (x_s = x_m / c), which keeps the information matrices well conditioned.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgcal.fields.constants import C_LIGHT
from dgcal.pos.smoother.factors import B, CLK, DRIFT, FE, V, X, ZERO

_KEY_BITS = 56           # gtsam symbols: the character in the top byte, the index below
_DIM = {ord("x"): 6, ord("v"): 3, ord("b"): 6, ord("f"): 3}   # every other key of the smoother is a scalar


class KeyframeBlocks:
    """Variable layout of one keyframe block: X (6), V (3), B (6), one clock per system (1 each), drift (1), the
    slots of the satellites' code biases (1 each, `dgcal.pos.smoother.code_bias`; a slot without an arc at a
    keyframe has no variable there and is carried with unit information, coupled to nothing) and the LC fixes'
    error states (3, `dgcal.pos.smoother.fix_errors`, likewise outside their span)."""

    def __init__(self, K: int, systems: list, first: int = 0, arcs=None, fix_span: tuple | None = None):
        """Blocks for keyframes first .. first+K-1 (numbered 0 .. K-1 here); `fix_span`: the first and last keyframe
        of the LC fixes' error states (`dgcal.pos.smoother.fix_errors`, 3 each, after the code-bias slots)."""
        self.K = K
        self.systems = list(systems)
        self.n_slots = arcs.n_slots if arcs is not None else 0
        self.base = 15 + len(systems) + (1 if systems else 0)
        self.fix = self.base + self.n_slots if fix_span is not None else None   # offset of the fix error states
        self.n = self.base + self.n_slots + (3 if fix_span is not None else 0)
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
            self.active[:, self.base:self.base + self.n_slots] = arcs.active(first + K)[first:first + K]
            for key, (k, slot) in arcs.where().items():
                if first <= k < first + K:
                    self.where[key] = (k - first, self.base + slot, 1)
        if fix_span is not None:
            k0, k1 = fix_span
            ks = np.arange(first, first + K)
            self.active[:, self.fix:self.fix + 3] = ((ks >= k0) & (ks <= k1))[:, None]
            for k in range(max(k0, first), min(k1, first + K - 1) + 1):
                self.where[FE(k)] = (k - first, self.fix, 3)
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

    def columns(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For gtsam keys (sorted, as the columns of a linearised graph): the keyframe (-1: not in the blocks, e.g.
        ZERO) and block offset of each of their scalar columns, in order."""
        keys = np.asarray(keys, np.uint64)
        dims = np.array([_DIM.get(int(c), 1) for c in (keys >> np.uint64(_KEY_BITS))], int)
        loc = [self.where.get(int(key)) for key in keys]
        kf = np.array([-1 if w is None else w[0] for w in loc], int)
        off = np.array([0 if w is None else w[1] for w in loc], int)
        kf_col = np.repeat(kf, dims)
        first = np.repeat(np.cumsum(dims) - dims, dims)
        off_col = np.repeat(off, dims) + np.arange(int(dims.sum())) - first
        return kf_col, off_col


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
    kf_col, off_col = blocks.columns(np.sort(np.array(values.keys(), np.uint64)))
    n_cols = len(kf_col)
    n_rows = int(rows.max()) + 1 if len(rows) else 0
    is_b = cols == n_cols
    b = np.zeros(n_rows)
    b[rows[is_b]] = vals[is_b]
    keep = ~is_b
    cb = kf_col[cols[keep]]
    inside = cb >= 0
    r, c, v, cb = rows[keep][inside], cols[keep][inside], vals[keep][inside], cb[inside]
    off = off_col[c]
    return r, off + n * cb, v * blocks.scale[off], cb, b, n_rows


@dataclass
class KeyframeRows:
    """Whitened rows of a linearised graph by the latest keyframe they reach.

    A (K,M,2n): keyframe k's rows (zero rows pad to M) over the block of keyframe k-1 (columns 0..n-1) and of
    keyframe k (n..2n-1), clock columns in metres; b (K,M): their right-hand sides (the error is A x - b); row
    (K,M): gtsam's index of each row (-1 for padding); b_all (n_rows,): every row's right-hand side, kmax (n_rows,)
    the latest keyframe of every row (-1: a row on no block variable, e.g. ZERO's prior)."""

    A: np.ndarray
    b: np.ndarray
    row: np.ndarray
    b_all: np.ndarray
    kmax: np.ndarray
    n: int

    def normal(self, use: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Information (K,2n,2n) and information vector (K,2n) of each keyframe's rows (those of `use` (K,M) bool,
        else all, computed once): A'A and A'b. Only the slots up to the last one used enter the products."""
        if use is None and getattr(self, "_all", None) is not None:
            return self._all
        m = self.A.shape[1] if use is None or not use.any() else int(np.flatnonzero(use.any(axis=0)).max()) + 1
        A, b = self.A[:, :m], self.b[:, :m]
        Au = A if use is None else A * use[:, :m, None]
        out = np.swapaxes(Au, 1, 2) @ A, np.einsum("kmi,km->ki", Au, b)
        if use is None:
            self._all = out
        return out


def keyframe_rows(graph, values, blocks: KeyframeBlocks) -> KeyframeRows:
    """The graph linearised at `values`, its rows grouped by their latest keyframe (`KeyframeRows`)."""
    n, K = blocks.n, blocks.K
    r, c, v, kb, b, n_rows = whitened_jacobian(graph, values, blocks)
    kmax = np.full(n_rows, -1, np.int64)
    np.maximum.at(kmax, r, kb)
    has = kmax >= 0
    rows = np.flatnonzero(has)
    order = rows[np.argsort(kmax[rows], kind="stable")]
    count = np.bincount(kmax[order], minlength=K)
    M = int(count.max()) if len(count) else 0
    slot = np.empty(n_rows, np.int64)
    slot[order] = np.arange(len(order)) - np.repeat(np.cumsum(count) - count, count)
    A = np.zeros((K, M, 2 * n))
    col = c - n * kmax[r] + n
    if np.any(col < 0):
        raise ValueError("a factor reaches more than two consecutive keyframes")
    A[kmax[r], slot[r], col] = v
    bp = np.zeros((K, M))
    bp[kmax[order], slot[order]] = b[order]
    row = np.full((K, M), -1, np.int64)
    row[kmax[order], slot[order]] = order
    return KeyframeRows(A, bp, row, b, kmax, n)
