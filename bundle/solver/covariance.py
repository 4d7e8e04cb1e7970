"""Covariance recovery from the undamped normal equations at the solution (cofactors, units of sigma0^2).

With N = [[U, W], [W^T, V]] and the reduced camera system S = U - W V^-1 W^T:
    Q_cc = S^-1,   Q_xc = -V^-1 W^T Q_cc,   Q_xx = V^-1 + V^-1 W^T Q_cc W V^-1   (per point block).
Redundancy numbers r = 1 - diag(A N^-1 A^T) of whitened observation rows A (Baarda), and the response
N^-1 J^T B of the estimate to a disturbance of the observations (e.g. a POS error common to all epochs),
use the same factors. Parameters that are held or that nothing observes get NaN covariances.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.linalg.lapack import dpotri

from dgcal.bundle.solver.kernels import redundancy_quadratic
from dgcal.bundle.solver.normals import Normals, Problem, Reduced, reduce, solve_normals, solve_reduced


@dataclass
class CameraSideCofactors:
    """Q_cc = S^-1 of the camera side (poses, then globals), times `factor`: a dense matrix, or, for a camera side
    solved by blocks (`dgcal.bundle.solver.normals.Arrow`), its parts, Q_gg = S_g^-1, Q_pg = -E Q_gg,
    Q_pp = D^-1 + E Q_gg E^T, which hold O(N) numbers where the dense Q holds (6N+G)^2. NaN (dense) or `bad`
    mark held and unobserved parameters."""

    n_poses: int
    n_globals: int
    bad: np.ndarray                        # (6N+G,) bool
    Q: np.ndarray | None = None            # dense (6N+G, 6N+G)
    Dinv: np.ndarray | None = None         # (N,6,6)
    E: np.ndarray | None = None            # (N,6,G)
    Q_gg: np.ndarray | None = None         # (G,G)
    factor: float = 1.0

    def scaled(self, f: float) -> "CameraSideCofactors":
        """The same cofactors times f (e.g. sigma0^2: covariances)."""
        return CameraSideCofactors(self.n_poses, self.n_globals, self.bad, self.Q, self.Dinv, self.E, self.Q_gg,
                                   self.factor * f)

    def dense(self) -> np.ndarray:
        """The whole (6N+G, 6N+G) matrix, NaN where `bad` (of a large block this is large)."""
        if self.Q is not None:
            return self.factor * self.Q
        N, G = self.n_poses, self.n_globals
        Q = np.zeros((6 * N + G, 6 * N + G))
        idx = 6 * np.arange(N)[:, None] + np.arange(6)
        Q[idx[:, :, None], idx[:, None, :]] = self.Dinv
        E2 = self.E.reshape(6 * N, G)
        Q[:6 * N, :6 * N] += E2 @ self.Q_gg @ E2.T
        Q[:6 * N, 6 * N:] = -E2 @ self.Q_gg
        Q[6 * N:, :6 * N] = Q[:6 * N, 6 * N:].T
        Q[6 * N:, 6 * N:] = self.Q_gg
        Q[self.bad, :] = np.nan
        Q[:, self.bad] = np.nan
        return self.factor * Q

    def pose_blocks(self) -> np.ndarray:
        """(N,6,6) the poses' diagonal blocks."""
        N = self.n_poses
        if self.Q is not None:
            idx = 6 * np.arange(N)[:, None] + np.arange(6)
            return self.factor * self.Q[idx[:, :, None], idx[:, None, :]]
        P = self.Dinv + np.matmul(np.matmul(self.E, self.Q_gg), self.E.transpose(0, 2, 1))
        bad = self.bad[:6 * N].reshape(N, 6)
        P[bad[:, :, None] | bad[:, None, :]] = np.nan
        return self.factor * P

    def global_block(self, glob: np.ndarray | None = None) -> np.ndarray:
        """(g,g) the block of globals `glob` (all by default)."""
        N, G = self.n_poses, self.n_globals
        g = np.arange(G) if glob is None else np.asarray(glob, int)
        if self.Q is not None:
            return self.factor * self.Q[np.ix_(6 * N + g, 6 * N + g)]
        out = self.Q_gg[np.ix_(g, g)].copy()
        bad = self.bad[6 * N + g]
        out[bad, :] = np.nan
        out[:, bad] = np.nan
        return self.factor * out

    def sandwich(self, L: np.ndarray) -> np.ndarray:
        """L Q L^T for L (r, 6N+G), NaN entries of Q taken as 0 (held and unobserved parameters do not vary)."""
        if self.Q is not None:
            return self.factor * (L @ np.nan_to_num(self.Q) @ L.T)
        N = self.n_poses
        Lm = L * ~self.bad            # Q with its bad rows and columns 0 = L without those columns
        Lp, Lg = Lm[:, :6 * N].reshape(len(L), N, 6), Lm[:, 6 * N:]
        # L Q L^T = Lp D^-1 Lp^T + (Lp E - Lg) Q_gg (Lp E - Lg)^T
        F = np.einsum("rna,nag->rg", Lp, self.E) - Lg
        return self.factor * (np.einsum("rna,nab,snb->rs", Lp, self.Dinv, Lp) + F @ self.Q_gg @ F.T)


@dataclass
class Covariance:
    """Cofactor blocks of a solved problem (multiply by the chosen variance factor for covariances)."""

    problem: Problem
    normals: Normals
    reduced: Reduced
    camera_side: CameraSideCofactors
    _Qc: np.ndarray | None = field(default=None, repr=False)
    _WT: sp.csr_matrix | None = field(default=None, repr=False)

    @classmethod
    def at(cls, problem: Problem, normals: Normals) -> "Covariance":
        """Cofactors from undamped normals (see `dgcal.bundle.solver.lm.normals_at`)."""
        # dense: the whole inverse is wanted, which a sparse factor gives no cheaper than LAPACK; a camera side
        # without pose-point coupling and with many poses by blocks (`Reduced.arrow`)
        red = reduce(normals, 0.0, dense=True)
        nc = problem.n_camera_side
        bad = ~normals.observed_c
        N, G = problem.n_poses, problem.n_globals
        if red.arrow is not None:
            a = red.arrow
            Q_gg = a.solve_globals(np.eye(G)) if G else np.zeros((0, 0))
            side = CameraSideCofactors(N, G, bad, Dinv=a.Dinv, E=a.E, Q_gg=0.5 * (Q_gg + Q_gg.T))
            return cls(problem, normals, red, side)
        Q = _inverse(red) if nc else np.zeros((0, 0))
        Q[bad, :] = np.nan
        Q[:, bad] = np.nan
        return cls(problem, normals, red, CameraSideCofactors(N, G, bad, Q=Q))

    @property
    def Q_cc(self) -> np.ndarray:
        """The camera side's cofactors as one dense matrix (NaN for held/unobserved parameters)."""
        if self.camera_side.Q is None:
            self.camera_side.Q = self.camera_side.dense()
        return self.camera_side.Q

    # --- camera side --------------------------------------------------------------------
    def pose_cofactors(self) -> np.ndarray:
        """(N,6,6) per-pose cofactors [C (m), dtheta (rad)]."""
        return self.camera_side.pose_blocks()

    def global_cofactors(self, glob: np.ndarray | None = None) -> np.ndarray:
        """(g,g) cofactor of globals `glob` (all by default)."""
        return self.camera_side.global_block(glob)

    # --- points -------------------------------------------------------------------------
    def point_cofactors(self, idx: np.ndarray | None = None, chunk: int = 2000) -> np.ndarray:
        """(k,3,3) cofactors of points `idx` (all by default)."""
        M = self.problem.n_points
        idx = np.arange(M) if idx is None else np.atleast_1d(np.asarray(idx, int))
        out = self.reduced.Vinv[idx].copy()
        if self.normals.W is not None and len(idx):
            Qc = np.nan_to_num(self.Q_cc)
            for s0 in range(0, len(idx), chunk):
                sub = idx[s0:s0 + chunk]
                Vinv = self.reduced.Vinv[sub]
                Wj = [self.normals.W[:, 3 * sub + b].tocsc() for b in range(3)]   # (nc,k) per coordinate
                T = [np.asarray(Wj[a].T @ Qc) for a in range(3)]                  # (k,nc)
                Bk = np.empty((len(sub), 3, 3))
                for a in range(3):
                    for b in range(3):
                        Bk[:, a, b] = np.asarray(Wj[b].T.multiply(T[a]).sum(axis=1)).ravel()
                out[s0:s0 + len(sub)] += np.einsum("kab,kbc,kcd->kad", Vinv, Bk, Vinv)
        bad = ~self.normals.observed_x.reshape(-1, 3)[idx]     # held or unobserved coordinates
        out[bad[:, :, None] | bad[:, None, :]] = np.nan
        return out

    # --- observations -------------------------------------------------------------------
    def redundancy_numbers(self, block: int, items: np.ndarray | None = None, chunk: int = 100_000) -> np.ndarray:
        """(k,dim) redundancy numbers of the whitened residuals of items of block number `block`.

        r = 1 - diag(D Q_cc D^T) - diag(A_x V^-1 A_x^T) with D = A_c - A_x V^-1 W^T (a row's camera-side part
        and its point's elimination), summed point by point in a compiled kernel (`redundancy_quadratic`)."""
        ev = self.normals.evals[block]
        k_all, d = ev.r.shape
        items = np.arange(k_all) if items is None else np.atleast_1d(np.asarray(items, int))
        N = self.problem.n_poses
        M = self.problem.n_points
        out = np.empty((len(items), d))
        Qc = self._Q_finite()
        with_point = ev.J_point is not None and M > 0
        WT = self._W_transposed() if with_point else None
        for s0 in range(0, len(items), chunk):
            it = items[s0:s0 + chunk]
            k = len(it)
            cols, vals = [], []
            if ev.J_pose is not None:
                cols.append(np.broadcast_to((6 * ev.pose[it][:, None] + np.arange(6))[:, None, :], (k, d, 6)))
                vals.append(ev.J_pose[it])
            if ev.J_glob is not None:
                g = len(ev.glob)
                cols.append(np.broadcast_to((6 * N + ev.glob)[None, None, :], (k, d, g)))
                vals.append(ev.J_glob[it])
            n_a = sum(c.shape[2] for c in cols)
            a_idx = np.concatenate(cols, axis=2).reshape(-1).astype(np.int64) if cols else np.zeros(0, np.int64)
            a_val = np.concatenate(vals, axis=2).reshape(-1).astype(float) if vals else np.zeros(0)
            a_ptr = np.arange(k * d + 1, dtype=np.int64) * n_a
            q = np.zeros(k * d)
            if with_point:
                Jx = ev.J_point[it]                                   # (k,d,3)
                Vinv = self.reduced.Vinv[ev.point[it]]                # (k,3,3)
                q += np.einsum("kai,kij,kaj->ka", Jx, Vinv, Jx).ravel()
            if with_point and WT is not None:
                U = np.einsum("kai,kij->kaj", Jx, Vinv).reshape(k * d, 3)   # A_x V^-1 per row
                row_point = np.repeat(ev.point[it].astype(np.int64), d)
                wt_ptr, wt_idx, wt_val = WT.indptr, WT.indices, WT.data
            else:
                U = np.zeros((k * d, 3))
                row_point = np.full(k * d, -1, np.int64)
                wt_ptr, wt_idx, wt_val = np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0)
            order = np.argsort(row_point, kind="stable").astype(np.int64)
            redundancy_quadratic(Qc, a_ptr, a_idx, a_val, np.ascontiguousarray(U), row_point, order,
                                 np.asarray(wt_ptr, np.int64), np.asarray(wt_idx, np.int64),
                                 np.asarray(wt_val, float), q)
            out[s0:s0 + k] = (1.0 - q).reshape(k, d)
        return out

    def _Q_finite(self) -> np.ndarray:
        """Q_cc with the NaN of held/unobserved parameters as 0 (C order), computed once."""
        if self._Qc is None:
            self._Qc = np.ascontiguousarray(np.nan_to_num(self.Q_cc))
        return self._Qc

    def _W_transposed(self) -> sp.csr_matrix | None:
        """W^T (3M, nc) in CSR, computed once."""
        if self._WT is None and self.normals.W is not None:
            self._WT = self.normals.W.T.tocsr()
            self._WT.sum_duplicates()
        return self._WT

    def response(self, b_c: np.ndarray, b_x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """N^-1 [b_c; b_x]: e.g. the estimate's response to a disturbance with J^T B = [b_c; b_x]."""
        return solve_normals(self.normals, self.reduced, np.nan_to_num(b_c), np.nan_to_num(b_x))


def _inverse(red: Reduced) -> np.ndarray:
    """S^-1 (symmetric) from the scaled Cholesky factor by LAPACK's potri (a third of a solve with the identity),
    or through `solve_reduced` when S is singular."""
    if red.factor is None:
        Q = solve_reduced(red, np.eye(len(red.scale)))
        return 0.5 * (Q + Q.T)
    c, lower = red.factor
    inv, info = dpotri(c, lower=lower)
    if info != 0:
        Q = solve_reduced(red, np.eye(len(red.scale)))
        return 0.5 * (Q + Q.T)
    tri = np.tril(inv) if lower else np.triu(inv)
    Q = tri + tri.T
    Q[np.diag_indices_from(Q)] *= 0.5
    return Q / np.outer(red.scale, red.scale)


def normal_rhs(problem: Problem, normals: Normals, block: int, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J^T B restricted to one block's whitened rows: B (k,dim,q) per item -> (b_c (nc,q), b_x (3M,q))."""
    ev = normals.evals[block]
    q = B.shape[2]
    N = problem.n_poses
    b_c = np.zeros((problem.n_camera_side, q))
    b_x = np.zeros((3 * problem.n_points, q))
    if ev.J_pose is not None:
        np.add.at(b_c, (6 * ev.pose[:, None] + np.arange(6)), np.einsum("kda,kdq->kaq", ev.J_pose, B))
    if ev.J_glob is not None:
        b_c[6 * N + ev.glob] += np.einsum("kdg,kdq->gq", ev.J_glob, B)
    if ev.J_point is not None:
        np.add.at(b_x, (3 * ev.point[:, None] + np.arange(3)), np.einsum("kda,kdq->kaq", ev.J_point, B))
    return b_c, b_x
