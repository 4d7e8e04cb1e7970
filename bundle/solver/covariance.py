"""Covariance recovery from the undamped normal equations at the solution (cofactors, units of sigma0^2).

With N = [[U, W], [W^T, V]] and the reduced camera system S = U - W V^-1 W^T:
    Q_cc = S^-1,   Q_xc = -V^-1 W^T Q_cc,   Q_xx = V^-1 + V^-1 W^T Q_cc W V^-1   (per point block).
Redundancy numbers r = 1 - diag(A N^-1 A^T) of whitened observation rows A (Baarda), and the response
N^-1 J^T B of the estimate to a disturbance of the observations (e.g. a POS error common to all epochs),
use the same factors. Parameters that are held or that nothing observes get NaN covariances.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from dgcal.bundle.solver.normals import Normals, Problem, Reduced, reduce, solve_normals, solve_reduced


@dataclass
class Covariance:
    """Cofactor blocks of a solved problem (multiply by the chosen variance factor for covariances)."""

    problem: Problem
    normals: Normals
    reduced: Reduced
    Q_cc: np.ndarray

    @classmethod
    def at(cls, problem: Problem, normals: Normals) -> "Covariance":
        """Cofactors from undamped normals (see `dgcal.bundle.solver.lm.normals_at`)."""
        red = reduce(normals, 0.0)
        nc = problem.n_camera_side
        Q = solve_reduced(red, np.eye(nc)) if nc else np.zeros((0, 0))
        Q = 0.5 * (Q + Q.T)
        bad = ~normals.observed_c
        Q[bad, :] = np.nan
        Q[:, bad] = np.nan
        return cls(problem, normals, red, Q)

    # --- camera side --------------------------------------------------------------------
    def pose_cofactors(self) -> np.ndarray:
        """(N,6,6) per-pose cofactors [C (m), dtheta (rad)]."""
        N = self.problem.n_poses
        idx = 6 * np.arange(N)[:, None] + np.arange(6)
        return self.Q_cc[idx[:, :, None], idx[:, None, :]]

    def global_cofactors(self, glob: np.ndarray | None = None) -> np.ndarray:
        """(g,g) cofactor of globals `glob` (all by default)."""
        N, G = self.problem.n_poses, self.problem.n_globals
        g = np.arange(G) if glob is None else np.asarray(glob, int)
        return self.Q_cc[np.ix_(6 * N + g, 6 * N + g)]

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
    def redundancy_numbers(self, block: int, items: np.ndarray | None = None, chunk: int = 4000) -> np.ndarray:
        """(k,dim) redundancy numbers of the whitened residuals of items of block number `block`."""
        ev = self.normals.evals[block]
        k_all, d = ev.r.shape
        items = np.arange(k_all) if items is None else np.atleast_1d(np.asarray(items, int))
        N = self.problem.n_poses
        nc = self.problem.n_camera_side
        M = self.problem.n_points
        out = np.empty((len(items), d))
        Qc = np.nan_to_num(self.Q_cc)
        for s0 in range(0, len(items), chunk):
            it = items[s0:s0 + chunk]
            k = len(it)
            rows = np.arange(k * d).reshape(k, d)
            r_, c_, v_ = [], [], []
            if ev.J_pose is not None:
                cols = 6 * ev.pose[it][:, None] + np.arange(6)
                r_.append(np.broadcast_to(rows[:, :, None], (k, d, 6)).ravel())
                c_.append(np.broadcast_to(cols[:, None, :], (k, d, 6)).ravel())
                v_.append(ev.J_pose[it].ravel())
            if ev.J_glob is not None:
                g = len(ev.glob)
                r_.append(np.broadcast_to(rows[:, :, None], (k, d, g)).ravel())
                c_.append(np.broadcast_to((6 * N + ev.glob)[None, None, :], (k, d, g)).ravel())
                v_.append(ev.J_glob[it].ravel())
            def cat(a):
                return np.concatenate(a) if a else np.zeros(0)
            A_c = sp.csr_matrix((cat(v_), (cat(r_).astype(int), cat(c_).astype(int))), shape=(k * d, nc))
            q = np.zeros(k * d)
            if ev.J_point is not None and M:
                Jx = ev.J_point[it]                                   # (k,d,3)
                Vinv = self.reduced.Vinv[ev.point[it]]                # (k,3,3)
                q += np.einsum("kai,kij,kaj->ka", Jx, Vinv, Jx).ravel()
                # B = A_x V^-1 W^T: the point part pushed onto the camera side through the coupling
                AxV = np.einsum("kai,kij->kaj", Jx, Vinv)              # (k,d,3)
                pcols = 3 * ev.point[it][:, None] + np.arange(3)
                Ax_V = sp.csr_matrix((AxV.ravel(), (np.repeat(np.arange(k * d), 3),
                                                    np.repeat(pcols, d, axis=0).ravel())), shape=(k * d, 3 * M))
                D = (A_c - Ax_V @ self.normals.W.T).tocsr()
            else:
                D = A_c
            DQ = D @ Qc
            q += np.asarray(D.multiply(DQ).sum(axis=1)).ravel()
            out[s0:s0 + k] = (1.0 - q).reshape(k, d)
        return out

    def response(self, b_c: np.ndarray, b_x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """N^-1 [b_c; b_x]: e.g. the estimate's response to a disturbance with J^T B = [b_c; b_x]."""
        return solve_normals(self.normals, self.reduced, np.nan_to_num(b_c), np.nan_to_num(b_x))


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
