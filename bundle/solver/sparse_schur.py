"""The reduced camera system of a large block as a sparse matrix, and its sparse factor.

Images couple only through the points they share, so S = U - W V^-1 W^T has 6x6 blocks only at pairs of poses
with a common point (a 600-image strip block: 7 % of the dense matrix), plus the dense rows and columns of the
globals. Its upper blocks are summed over the tracks in a compiled kernel (`kernels.pose_pose_schur_blocks`) and
the matrix is factored by SuperLU with a fill-reducing symmetric ordering and diagonal pivots (scipy's, so no
new dependency): LDL^T-like work on the sparse pattern instead of a dense Cholesky of the whole 6N x 6N.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from dgcal.bundle.solver.kernels import pose_pair_pattern, pose_pose_schur_blocks

SPARSE_MIN_POSES = 100        # below this the dense Cholesky of S costs less than SuperLU's ordering
SPARSE_DENSITY_MAX = 0.25     # share of the 6x6 blocks of S that are non-zero up to which S is kept sparse


class PairPattern:
    """Where the entries of the sparse S (poses and G globals) sit in CSC order, computed once per track layout."""

    def __init__(self, pose: np.ndarray, order: np.ndarray, starts: np.ndarray, N: int, G: int):
        self.N, self.G = N, G
        self.lut, rows, cols = pose_pair_pattern(pose, order, starts, N)
        self.n_blocks = len(rows)
        self.density = (2 * len(rows) - N) / max(N * N, 1)
        self.diag_blocks = self.lut[np.arange(N), np.arange(N)].astype(np.int64)
        self.off = np.flatnonzero(rows != cols)
        x = np.arange(6)
        r_up = (6 * rows[:, None, None] + x[None, :, None] + 0 * x[None, None, :]).ravel()
        c_up = (6 * cols[:, None, None] + 0 * x[None, :, None] + x[None, None, :]).ravel()
        ro, co = rows[self.off], cols[self.off]
        # mirrored blocks, their entries in the order of B[off].transpose(0, 2, 1)
        r_lo = (6 * co[:, None, None] + x[None, :, None] + 0 * x[None, None, :]).ravel()
        c_lo = (6 * ro[:, None, None] + 0 * x[None, :, None] + x[None, None, :]).ravel()
        n6 = 6 * N
        g = n6 + np.arange(G)
        pr, pg = np.meshgrid(np.arange(n6), g, indexing="ij")            # border (n6,G) and its transpose
        gr, gc = np.meshgrid(g, g, indexing="ij")
        r = np.concatenate([r_up, r_lo, pr.ravel(), pg.T.ravel(), gr.ravel()])
        c = np.concatenate([c_up, c_lo, pg.ravel(), pr.T.ravel(), gc.ravel()])
        self.shape = (n6 + G, n6 + G)
        A = sp.csc_matrix((np.arange(1, len(r) + 1, dtype=float), (r, c)), shape=self.shape)
        self.perm = A.data.astype(np.int64) - 1        # CSC position -> entry of the concatenated data
        self.indices, self.indptr = A.indices, A.indptr
        self.col_of = np.repeat(np.arange(self.shape[0]), np.diff(self.indptr))

    def schur_blocks(self, Y: np.ndarray, W: np.ndarray, pose: np.ndarray, order: np.ndarray, starts: np.ndarray,
                     n_threads: int) -> np.ndarray:
        """(n_blocks,6,6) upper blocks of sum_j W_j V_j^-1 W_j^T (Y = per-item W V^-1, W per-item blocks)."""
        return pose_pose_schur_blocks(Y, W, pose, order, starts, self.lut, self.n_blocks, n_threads)

    def matrix(self, B: np.ndarray, border: np.ndarray, corner: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
        """S in CSC from its upper pose blocks B (n_blocks,6,6), the pose-global border (6N,G) and the globals'
        square (G,G), scaled to a unit diagonal; returns it with the scale s (S = diag(s) S_scaled diag(s))."""
        d = np.concatenate([np.einsum("kii->ki", B[self.diag_blocks]).ravel(), np.diag(corner)])
        s = np.sqrt(np.maximum(d, 1e-300))
        data = np.concatenate([B.ravel(), B[self.off].transpose(0, 2, 1).ravel(), border.ravel(), border.T.ravel(),
                               corner.ravel()])[self.perm]
        data /= s[self.indices] * s[self.col_of]
        return sp.csc_matrix((data, self.indices, self.indptr), shape=self.shape), s


def sparse_factor(S_scaled: sp.csc_matrix):
    """SuperLU factor of a scaled symmetric S (minimum-degree ordering on S, diagonal pivots); None unless S is
    positive definite (every pivot > 0), like a failed Cholesky."""
    try:
        lu = splu(S_scaled, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
    except RuntimeError:          # exactly singular
        return None
    piv = lu.U.diagonal()
    return lu if np.all(np.isfinite(piv)) and piv.min() > 0 else None
