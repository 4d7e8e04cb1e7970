"""The problem's layout, its cost and its normal equations with the points eliminated (Schur complement).

Camera-side columns: 6 per pose ([dC, dtheta], `dgcal.fields.pose`) then the G globals; point-side: 3 per point.
Held parameters (pose_free, point_free, global_free = False) and parameters no residual depends on get a unit
diagonal and a zero gradient, so they stay where they are and keep the system regular.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from dgcal.bundle.solver.blocks import INVALID_COST, Block, BlockEval, State
from dgcal.bundle.solver.kernels import (accumulate_global_points, accumulate_items, accumulate_pose_globals,
                                        coupling_dot, coupling_tdot, pose_pose_schur)
from dgcal.bundle.solver.robust import robust_cost_and_weight
from dgcal.bundle.solver.sparse_schur import SPARSE_DENSITY_MAX, SPARSE_MIN_POSES, PairPattern, sparse_factor

V_REGULARISATION = 1e-10   # added to the point blocks' diagonal (whitened units: a prior of ~1e5 sigma)
# items of a chunkable block (image observations) evaluated, weighted and summed into the normal equations at
# once: the residuals and Jacobians of every item (~1 kB an item) are never held together (5 M observations:
# ~100 MB for a part instead of 5 GB); each part's sums are added, in item order
CHUNK_ITEMS = 100_000


def _evaluate(b: Block, state: State, jacobians: bool, rows: slice | None) -> BlockEval:
    """A block's evaluation: all its items (rows None) or a part."""
    return b.evaluate(state, jacobians) if rows is None else b.evaluate(state, jacobians, rows)


@dataclass
class Problem:
    """Residual blocks over N poses, M points and G globals, with masks of the parameters held fixed."""

    blocks: list[Block]
    n_poses: int
    n_points: int
    n_globals: int
    pose_free: np.ndarray | None = None      # (N,) bool
    point_free: np.ndarray | None = None     # (M,3) bool
    global_free: np.ndarray | None = None    # (G,) bool
    chunk_items: int | None = None           # items of a chunkable block evaluated at once (None: CHUNK_ITEMS)

    def __post_init__(self) -> None:
        N, M, G = self.n_poses, self.n_points, self.n_globals
        self.pose_free = np.ones(N, bool) if self.pose_free is None else np.asarray(self.pose_free, bool)
        self.point_free = np.ones((M, 3), bool) if self.point_free is None else np.asarray(self.point_free, bool)
        self.global_free = np.ones(G, bool) if self.global_free is None else np.asarray(self.global_free, bool)

    @property
    def n_camera_side(self) -> int:
        return 6 * self.n_poses + self.n_globals

    def parts(self, b: Block) -> list[slice | None]:
        """The parts a block is evaluated in: [None] (all its items at once) unless it is chunkable and larger
        than `chunk_items`."""
        if not b.chunkable:
            return [None]
        ch = b.chunks(self.n_poses, CHUNK_ITEMS if self.chunk_items is None else self.chunk_items)
        return [None] if len(ch) == 1 else ch

    def _item_costs(self, b: Block, state: State, rows: slice | None) -> np.ndarray:
        ev = _evaluate(b, state, False, rows)
        e2 = np.sum(ev.r * ev.r, axis=1)
        rho, _ = robust_cost_and_weight(b.loss, b.loss_scale, np.where(ev.valid, e2, 0.0))
        return np.where(ev.valid, rho, INVALID_COST)

    def block_costs(self, state: State) -> list[np.ndarray]:
        """Robust cost of every item of every block (INVALID_COST for items that cannot be evaluated)."""
        return [np.concatenate([self._item_costs(b, state, rows) for rows in self.parts(b)]) for b in self.blocks]

    def cost(self, state: State) -> float:
        """Total robust cost sum(rho(|r|^2)) (= chi^2 without a robust loss), summed part by part."""
        return float(sum(sum(self._item_costs(b, state, rows).sum() for rows in self.parts(b))
                         for b in self.blocks))

    def retract(self, state: State, dc: np.ndarray, dx: np.ndarray | None) -> State:
        """The state moved by camera-side steps dc (6N+G,) and point steps dx (3M,)."""
        N = self.n_poses
        poses = state.poses.retract(dc[:6 * N].reshape(N, 6)) if N else state.poses
        points = state.points + (dx.reshape(-1, 3) if dx is not None and self.n_points else 0.0)
        return State(poses, points, state.globals + dc[6 * N:])


@dataclass
class Normals:
    """J^T J and J^T r in blocks: camera side U (pose blocks U_pp (N,6,6), pose-global U_pg (N,6,G), globals U_gg
    (G,G); `U` is the dense 6N+G matrix), pose-point coupling Wp (per-item 6x3 blocks `wp_blocks` at `coupling`;
    `Wp` is the block-sparse 6N x 3M matrix), global-point coupling Wg (dense G x 3M), point blocks V (M,3,3),
    gradients g_c, g_x."""

    U_pp: np.ndarray
    U_pg: np.ndarray
    U_gg: np.ndarray
    g_c: np.ndarray
    Wg: np.ndarray | None
    V: np.ndarray
    g_x: np.ndarray
    cost: float
    n_residuals: int
    observed_c: np.ndarray          # (6N+G,) bool: a free camera-side parameter some residual depends on
    observed_x: np.ndarray          # (3M,) bool
    _evals: list[BlockEval | None] = field(default_factory=list, repr=False)   # None: evaluated in parts
    _weights: list[np.ndarray | None] = field(default_factory=list, repr=False)
    row_offsets: list[int] = field(default_factory=list)
    wp_blocks: np.ndarray | None = None   # (k,6,3) pose-point coupling of every item with a pose and a point
    coupling: "CouplingPattern | None" = None   # where those blocks sit in Wp
    _U: np.ndarray | None = field(default=None, repr=False)
    _Wp: sp.bsr_matrix | None = field(default=None, repr=False)
    _W: sp.csr_matrix | None = field(default=None, repr=False)
    problem: Problem | None = field(default=None, repr=False)   # what was linearised, and where (for `evals`)
    state: State | None = field(default=None, repr=False)

    def _whole(self, b: int) -> None:
        """Block b's linearisation over all its items, when it was summed in parts (computed on first use)."""
        if self._evals[b] is None:
            blk = self.problem.blocks[b]
            ev, _, w = _weighted(self.problem, blk.evaluate(self.state, True), blk)
            self._evals[b], self._weights[b] = ev, w

    @property
    def evals(self) -> list[BlockEval]:
        """Whitened, robust-weighted linearisation of every block (a block summed in parts is evaluated whole
        again on first use: covariances of observations, redundancy numbers)."""
        for b in range(len(self._evals)):
            self._whole(b)
        return self._evals

    @property
    def weights(self) -> list[np.ndarray]:
        """Robust weight per item and block."""
        for b in range(len(self._weights)):
            self._whole(b)
        return self._weights

    @property
    def n_unknowns(self) -> int:
        return int(self.observed_c.sum() + self.observed_x.sum())

    @property
    def redundancy(self) -> int:
        return self.n_residuals - self.n_unknowns

    @property
    def U(self) -> np.ndarray:
        """The camera side (6N+G, 6N+G) as one dense matrix (built on first use: large blocks never need it)."""
        if self._U is None:
            N, G = len(self.U_pp), len(self.U_gg)
            U = np.zeros((6 * N + G, 6 * N + G))
            idx = 6 * np.arange(N)[:, None] + np.arange(6)
            U[idx[:, :, None], idx[:, None, :]] = self.U_pp
            U[:6 * N, 6 * N:] = self.U_pg.reshape(6 * N, G)
            U[6 * N:, :6 * N] = U[:6 * N, 6 * N:].T
            U[6 * N:, 6 * N:] = self.U_gg
            self._U = U
        return self._U

    @property
    def Wp(self) -> sp.bsr_matrix | None:
        """The pose-point coupling (6N, 3M) as a block-sparse matrix (built on first use)."""
        if self._Wp is None and self.wp_blocks is not None:
            self._Wp = self.coupling.matrix(self.wp_blocks)
        return self._Wp

    @property
    def W(self) -> sp.csr_matrix | None:
        """The whole camera-side x point coupling (6N+G, 3M) as one sparse matrix."""
        if self._W is None and self.Wp is not None:
            parts = [self.Wp.tocsr()] + ([sp.csr_matrix(self.Wg)] if self.Wg is not None and len(self.Wg) else [])
            self._W = sp.vstack(parts).tocsr()
        return self._W

    def W_dot(self, x: np.ndarray) -> np.ndarray:
        """W @ x for x (3M,) or (3M,q)."""
        x2 = np.ascontiguousarray(x.reshape(len(x), -1), dtype=float)
        out = np.zeros((6 * len(self.U_pp), x2.shape[1]))
        pat = self.coupling
        coupling_dot(self.wp_blocks, pat.pose64, pat.point64, x2, out)
        if self.Wg is not None and len(self.Wg):
            out = np.concatenate([out, self.Wg @ x2])
        return out.reshape((len(out),) + x.shape[1:])

    def WT_dot(self, y: np.ndarray) -> np.ndarray:
        """W^T @ y for y (6N+G,) or (6N+G,q)."""
        n6 = 6 * len(self.U_pp)
        y2 = np.ascontiguousarray(y.reshape(len(y), -1), dtype=float)
        out = np.zeros((3 * len(self.V), y2.shape[1]))
        pat = self.coupling
        coupling_tdot(self.wp_blocks, pat.pose64, pat.point64, y2, out)
        if self.Wg is not None and len(self.Wg):
            out += self.Wg.T @ y2[n6:]
        return out.reshape((len(out),) + y.shape[1:])


class Grouper:
    """Sums over the items of equal index (idx (k,) into n groups) by one sparse indicator product."""

    def __init__(self, idx: np.ndarray, n: int):
        self.idx, self.n = idx, n
        k = len(idx)
        self.G = sp.csr_matrix((np.ones(k), (idx, np.arange(k))), shape=(n, k))

    def sum(self, values: np.ndarray) -> np.ndarray:
        """(n,...) sums of values (k,...)."""
        k = len(self.idx)
        return np.asarray(self.G @ values.reshape(k, -1)).reshape((self.n,) + values.shape[1:])


def _grouper(cache: dict, key: str, idx: np.ndarray, n: int) -> Grouper:
    """A Grouper for idx, reused while a block's index array stays the same object."""
    g = cache.get(key)
    if g is None or g.idx is not idx or g.n != n:
        g = cache[key] = Grouper(idx, n)
    return g


class CouplingPattern:
    """Where per-item 6x3 pose-point blocks go in the block-sparse Wp (6N x 3M): sorted once, reused."""

    def __init__(self, pose: np.ndarray, point: np.ndarray, N: int, M: int):
        self.pose, self.point, self.N, self.M = pose, point, N, M
        self.order = np.lexsort((point, pose))
        p, q = pose[self.order], point[self.order]
        self.unique = len(p) < 2 or bool(np.all((p[1:] != p[:-1]) | (q[1:] != q[:-1])))
        self.indptr = np.searchsorted(p, np.arange(N + 1))
        self.indices = q
        self.by_pose = Grouper(pose, N)
        self.pose64 = pose.astype(np.int64)
        self.point64 = point.astype(np.int64)
        self.by_point_order = np.lexsort((pose, point)).astype(np.int64)   # by point, then pose
        self.point_starts = np.searchsorted(point[self.by_point_order], np.arange(M + 1)).astype(np.int64)
        self._pairs: dict[int, PairPattern] = {}

    def pairs(self, G: int) -> PairPattern:
        """The sparse pattern of the reduced camera system with G globals (computed once)."""
        if G not in self._pairs:
            self._pairs[G] = PairPattern(self.pose64, self.by_point_order, self.point_starts, self.N, G)
        return self._pairs[G]

    def matrix(self, blocks: np.ndarray) -> sp.bsr_matrix:
        """Wp-shaped block-sparse matrix of per-item blocks (k,6,3) (an image seeing a point twice: summed)."""
        B = sp.bsr_matrix((blocks[self.order], self.indices, self.indptr), shape=(6 * self.N, 3 * self.M))
        if not self.unique:
            B.sum_duplicates()
        return B


def _group_sum(values: np.ndarray, idx: np.ndarray, n: int) -> np.ndarray:
    """Sums of values (k,...) over equal idx (k,) into (n,...)."""
    return Grouper(idx, n).sum(values)


def _tdot(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A_k^T B_k for stacks (k,d,a), (k,d,b) -> (k,a,b)."""
    return np.matmul(A.transpose(0, 2, 1), B)


PER_POSE_PRODUCTS_MIN = 32   # items per pose from which a block's pose sums are one matrix product per pose


def _pose_products(cache: dict, A: np.ndarray, B: np.ndarray | None, r: np.ndarray, pose: np.ndarray,
                   N: int, k_block: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Per pose, the sums over its items of A^T A (N,6,6), A^T r (N,6) and A^T B (N,6,Gb) (None without B): one
    BLAS product per pose over its rows when the poses have many items (self-calibration: ~1000 per image),
    else one sparse indicator product over the stacked per-item products. `k_block`: the items of the whole
    block when these are a part of it (the choice is the block's)."""
    k, d = r.shape
    if (k if k_block is None else k_block) < PER_POSE_PRODUCTS_MIN * max(N, 1):
        by_pose = _grouper(cache, "pose", pose, N)
        return (by_pose.sum(_tdot(A, A)), by_pose.sum(np.einsum("kda,kd->ka", A, r)),
                None if B is None else by_pose.sum(_tdot(A, B)))
    runs = cache.get("pose_runs")
    if runs is None or runs[0] is not pose or runs[1] != N:
        order = None if np.all(pose[1:] >= pose[:-1]) else np.argsort(pose, kind="stable")
        bounds = np.searchsorted(pose if order is None else pose[order], np.arange(N + 1))
        runs = cache["pose_runs"] = (pose, N, order, d * bounds)
    _, _, order, rows = runs

    def stacked(X):
        X = X if order is None else X[order]
        return X.reshape(k * d, -1)
    A2, r2 = stacked(A), stacked(r)[:, 0]
    B2 = None if B is None else stacked(B)
    AA, Ar = np.zeros((N, 6, 6)), np.zeros((N, 6))
    AB = None if B is None else np.zeros((N, 6, B.shape[2]))
    for i in np.flatnonzero(rows[1:] > rows[:-1]):
        s = slice(rows[i], rows[i + 1])
        a = A2[s]
        AA[i] = a.T @ a
        Ar[i] = a.T @ r2[s]
        if AB is not None:
            AB[i] = a.T @ B2[s]
    return AA, Ar, AB


def _weighted(problem: Problem, ev: BlockEval, b: Block) -> tuple[BlockEval, float, np.ndarray]:
    """The evaluation whitened by the robust weights (IRLS) and masked by the held parameters."""
    e2 = np.sum(ev.r * ev.r, axis=1)
    rho, w = robust_cost_and_weight(b.loss, b.loss_scale, np.where(ev.valid, e2, 0.0))
    cost = float(np.sum(np.where(ev.valid, rho, INVALID_COST)))
    sw = np.where(ev.valid, np.sqrt(w), 0.0)
    ev.r = np.where(ev.valid[:, None], ev.r, 0.0) * sw[:, None]
    if ev.J_pose is not None:
        ev.J_pose = _scaled(ev.J_pose, (sw * problem.pose_free[ev.pose])[:, None, None])
    if ev.J_point is not None:
        ev.J_point = _scaled(ev.J_point, (sw[:, None] * problem.point_free[ev.point])[:, None, :])
    if ev.J_glob is not None:
        ev.J_glob = _scaled(ev.J_glob, sw[:, None, None] * problem.global_free[ev.glob][None, None, :])
    return ev, cost, np.where(ev.valid, w, 0.0)


def _scaled(J: np.ndarray, s: np.ndarray) -> np.ndarray:
    """np.nan_to_num(J) * s, without the copies when J is finite and every factor is 1 (no robust weight, nothing
    held, nothing invalid: the usual case)."""
    if not np.isfinite(J).all():
        J = np.nan_to_num(J)
    return J if np.all(s == 1.0) else J * s


def linearise(problem: Problem, state: State) -> Normals:
    """Normal equations at `state` (robust losses as iteratively reweighted least squares), assembled block
    by block from per-item Jacobian products (each item touches at most one pose and one point); a chunkable
    block larger than `problem.chunk_items` is evaluated and summed part by part (`Problem.parts`)."""
    N, M, G = problem.n_poses, problem.n_points, problem.n_globals
    U_pp = np.zeros((N, 6, 6))
    U_pg = np.zeros((N, 6, G))
    U_gg = np.zeros((G, G))
    g_p, g_g = np.zeros((N, 6)), np.zeros(G)
    V, g_x = np.zeros((M, 3, 3)), np.zeros((M, 3))
    Wg = np.zeros((G, M, 3)) if M else None
    wp_blk, wp_pose, wp_point, patterns = [], [], [], []
    evals, weights, offsets = [], [], []
    cost, row, n_valid = 0.0, 0, 0
    for b in problem.blocks:
        cache = b.__dict__.setdefault("_groupers", {})
        parts = problem.parts(b)
        whole = parts == [None]
        k_block = len(b)
        blk_all = None       # (k,6,3) pose-point coupling of every item (items with a pose and a point)
        offsets.append(row)
        for rows in parts:
            ev, c, w = _weighted(problem, _evaluate(b, state, True, rows), b)
            part_cache = cache if whole else cache.setdefault(("part", rows.start, rows.stop), {})
            cost += c
            r = ev.r
            A, B, C = ev.J_pose, ev.J_glob, ev.J_point
            fused = A is not None and C is not None and M > 0
            if fused:
                # items with a pose and a point (image observations): one compiled pass for the pose and point
                # blocks, the gradients and the couplings
                if blk_all is None:
                    blk_all = np.empty((k_block if not whole else len(r), 6, 3))
                blk = blk_all if whole else blk_all[rows]
                accumulate_items(np.ascontiguousarray(r), np.ascontiguousarray(A), ev.pose.astype(np.int64),
                                 np.ascontiguousarray(C), ev.point.astype(np.int64), U_pp, g_p, V, g_x, blk)
            if A is not None and not fused:
                # items without a point unknown (image observations of known points, priors, POS): NumPy
                AA, Ar, AB = _pose_products(part_cache, A, B, r, ev.pose, N, k_block)
                U_pp += AA
                g_p += Ar
                if B is not None:
                    U_pg[:, :, ev.glob] += AB
            elif A is not None and B is not None:
                U_pg_b = np.zeros((N, 6, B.shape[2]))
                accumulate_pose_globals(np.ascontiguousarray(A), ev.pose.astype(np.int64), np.ascontiguousarray(B),
                                        U_pg_b)
                U_pg[:, :, ev.glob] += U_pg_b
            if B is not None:
                g = ev.glob
                Bf = B.reshape(-1, len(g))
                U_gg[np.ix_(g, g)] += Bf.T @ Bf
                g_g[g] += Bf.T @ r.ravel()
            if C is not None and M:
                if not fused:
                    by_point = _grouper(part_cache, "point", ev.point, M)
                    V += by_point.sum(_tdot(C, C))
                    g_x += by_point.sum(np.einsum("kda,kd->ka", C, r))
                if B is not None:
                    Wg_b = np.zeros((len(ev.glob), M, 3))
                    accumulate_global_points(np.ascontiguousarray(B), np.ascontiguousarray(C),
                                             ev.point.astype(np.int64), Wg_b)
                    Wg[ev.glob] += Wg_b
            row += r.size
            n_valid += int(ev.valid.sum()) * r.shape[1]
            if whole:
                evals.append(ev)
                weights.append(w)
        if not whole:        # evaluated again, whole, if ever asked for (Normals.evals)
            evals.append(None)
            weights.append(None)
        if blk_all is not None:
            pose_b, point_b = (ev.pose, ev.point) if whole else (b.pose, b.point)
            wp_blk.append(blk_all)
            wp_pose.append(pose_b)
            wp_point.append(point_b)
            pat = cache.get("coupling")
            if pat is None or pat.pose is not pose_b or pat.point is not point_b or (pat.N, pat.M) != (N, M):
                pat = cache["coupling"] = CouplingPattern(pose_b, point_b, N, M)
            patterns.append(pat)
    g_c = np.concatenate([g_p.ravel(), g_g])
    blocks = pattern = None
    if M and wp_blk:
        if len(wp_blk) == 1:
            blocks, pattern = wp_blk[0], patterns[0]
        else:   # several observation blocks (cameras): one pattern over all their items
            blocks = np.concatenate(wp_blk)
            pattern = CouplingPattern(np.concatenate(wp_pose), np.concatenate(wp_point), N, M)
    # parameters nothing observes (or held) get a unit diagonal: they stay where they are
    dU = np.concatenate([np.einsum("naa->na", U_pp).ravel(), np.diag(U_gg)])
    observed_c = dU > 0
    np.einsum("naa->na", U_pp)[...] = np.where(observed_c[:6 * N], dU[:6 * N], 1.0).reshape(N, 6)
    U_gg[np.diag_indices(G)] = np.where(observed_c[6 * N:], dU[6 * N:], 1.0)
    dV = np.einsum("naa->na", V)
    observed_x = (dV > 0).ravel()
    dV[dV <= 0] = 1.0
    if blocks is None and Wg is not None and not Wg.any():
        Wg = None                     # no point is an unknown (all held or known): nothing to eliminate
    return Normals(U_pp, U_pg, U_gg, g_c, None if Wg is None else Wg.reshape(G, 3 * M), V, g_x.ravel(), cost,
                   n_valid, observed_c, observed_x, evals, weights, offsets, blocks, pattern, problem=problem,
                   state=state)


def _damp(A: np.ndarray, lam: float) -> np.ndarray:
    """A + lam diag(A) over the last two axes."""
    if lam == 0.0:
        return A
    Ad = A.copy()
    d = np.einsum("...ii->...i", Ad)
    d += lam * np.maximum(d, 1e-12)
    return Ad


def _vinv_dot(Vinv: np.ndarray, b: np.ndarray) -> np.ndarray:
    """blockdiag(V^-1) @ b for b (3M,) or (3M,q)."""
    M = len(Vinv)
    return np.matmul(Vinv, b.reshape(M, 3, -1)).reshape(b.shape)


ARROW_MIN_POSES = 100   # poses from which a camera side without pose-point coupling is solved pose by pose


@dataclass
class Arrow:
    """A camera side without pose-point coupling (a camera calibrated on known targets): its poses meet only
    through the globals, S = [[D, B], [B^T, U_gg]] with D the 6x6 pose blocks and B = U_pg. Solved by eliminating
    the poses, E = D^-1 B (N,6,G), S_g = U_gg - B^T E (G,G): O(N) in time and memory where the dense S is
    (6N+G)^2 (10 000 images: 29 GB)."""

    Dinv: np.ndarray          # (N,6,6)
    E: np.ndarray             # (N,6,G)
    S_g: np.ndarray           # (G,G)
    factor: tuple | None      # Cholesky factor of S_g scaled to a unit diagonal (None: singular)
    scale_g: np.ndarray       # (G,)

    def solve_globals(self, b_g: np.ndarray) -> np.ndarray:
        """S_g^-1 b_g (b_g (G,q))."""
        if self.factor is not None:
            return cho_solve(self.factor, b_g / self.scale_g[:, None], check_finite=False) / self.scale_g[:, None]
        return np.linalg.lstsq(self.S_g, b_g, rcond=None)[0]

    def solve(self, b_c: np.ndarray) -> np.ndarray:
        """S^-1 b_c for b_c (6N+G,) or (6N+G,q)."""
        N, G = self.E.shape[0], self.E.shape[2]
        b2 = b_c.reshape(len(b_c), -1)
        bp = b2[:6 * N].reshape(N, 6, -1)
        x_g = self.solve_globals(b2[6 * N:] - np.einsum("nag,naq->gq", self.E, bp)) if G else np.zeros((0, b2.shape[1]))
        x_p = np.matmul(self.Dinv, bp) - np.matmul(self.E, x_g)
        return np.concatenate([x_p.reshape(6 * N, -1), x_g]).reshape(b_c.shape)


def _arrow(nrm: "Normals", lam: float) -> Arrow | None:
    """The poses eliminated from the damped camera side (None when a pose block is not positive definite: the
    dense path then decides)."""
    D = _damp(nrm.U_pp, lam)
    try:
        np.linalg.cholesky(D)
    except np.linalg.LinAlgError:
        return None
    Dinv = np.linalg.inv(D)
    Dinv = 0.5 * (Dinv + Dinv.transpose(0, 2, 1))
    E = np.matmul(Dinv, nrm.U_pg)
    S_g = _damp(nrm.U_gg, lam) - np.einsum("nag,nah->gh", nrm.U_pg, E)
    S_g = 0.5 * (S_g + S_g.T)
    s = np.sqrt(np.maximum(np.diag(S_g), 1e-300))
    try:
        factor = cho_factor(S_g / s[:, None] / s[None, :], check_finite=False) if len(S_g) else None
    except (LinAlgError, ValueError):
        factor = None
    return Arrow(Dinv, E, S_g, factor, s)


@dataclass
class Reduced:
    """The reduced camera system S = U - W V^-1 W^T, its factor and V^-1 (at one damping). Dense: S itself with
    a Cholesky factor of the scaled S (`factor`); sparse (large blocks): S scaled to a unit diagonal in CSC,
    S = diag(scale) S_csc diag(scale), with SuperLU's factor (`lu`). Both None when S is singular. Without
    pose-point coupling and with many poses (`arrow`): S is not formed, the poses are eliminated by blocks
    (`Arrow`); `scale` is sqrt(diag(S)) in every case."""

    S: np.ndarray | sp.csc_matrix | None
    Vinv: np.ndarray
    scale: np.ndarray
    factor: tuple | None
    lu: object | None = None
    arrow: Arrow | None = None

    def dense(self) -> np.ndarray:
        """S as a dense array."""
        if self.arrow is not None:
            raise ValueError("the camera side is solved by blocks (Reduced.arrow): no dense S")
        return self.S.toarray() * np.outer(self.scale, self.scale) if sp.issparse(self.S) else self.S


SCHUR_THREADS = max(1, min(2, os.cpu_count() or 1))   # threads of the compiled Schur sum
DENSE_SCHUR_MAX = 4_000_000   # entries of a (6N x 3M) coupling below which S may be dense
# The pose-pose Schur product as a dense GEMM costs ~N^2 M flops, the compiled sum over the tracks ~sum of squared
# track lengths, each flop of which runs about this much slower (bench/schur.py, one BLAS thread, 2026-12-03: every
# point in every image, the GEMM 1-5x faster; tracks a third of the block, the sum 2x faster; 122 aerial images with
# 18-image tracks, the sum 8x faster)
GEMM_SPEEDUP = 4.0


def reduce(nrm: Normals, lam: float = 0.0, dense: bool = False) -> Reduced:
    """Eliminate the points (3x3 blocks) from the damped normal equations; large blocks whose images share points
    with few others keep S sparse (`dgcal.bundle.solver.sparse_schur`) unless `dense` is asked for."""
    # a tiny diagonal keeps a point seen along one ray (or nearly parallel rays) invertible
    Vinv = np.linalg.inv(_damp(nrm.V, lam) + V_REGULARISATION * np.eye(3)) if len(nrm.V) else np.zeros((0, 3, 3))
    if nrm.wp_blocks is None and nrm.Wg is not None:
        raise NotImplementedError("points coupled to globals only")   # every point block has a pose here
    if nrm.wp_blocks is None or not len(nrm.V):
        if len(nrm.U_pp) >= ARROW_MIN_POSES:
            arrow = _arrow(nrm, lam)
            if arrow is not None:
                d = np.concatenate([np.einsum("naa->na", _damp(nrm.U_pp, lam)).ravel(), np.diag(_damp(nrm.U_gg, lam))])
                return Reduced(None, Vinv, np.sqrt(np.maximum(d, 1e-300)), None, arrow=arrow)
        return _dense_reduced(_damp(nrm.U, lam), Vinv)
    pat = nrm.coupling
    N, M = len(nrm.U_pp), len(nrm.V)
    n6 = 6 * N
    Y = np.matmul(nrm.wp_blocks, Vinv[pat.point])                   # (k,6,3) W_k V_j^-1 per item
    G = 0 if nrm.Wg is None else len(nrm.Wg)
    S_pg = np.zeros((n6, G))
    S_gg = np.zeros((G, G))
    if G:
        Wg3 = nrm.Wg.reshape(G, -1, 3)
        S_pg = pat.by_pose.sum(np.einsum("kia,gka->kig", Y, Wg3[:, pat.point])).reshape(n6, G)
        S_gg = np.einsum("gmi,mij,hmj->gh", Wg3, Vinv, Wg3)
    large = n6 * 3 * M > DENSE_SCHUR_MAX
    if large and not dense and N >= SPARSE_MIN_POSES and pat.pairs(G).density <= SPARSE_DENSITY_MAX:
        pairs = pat.pairs(G)
        B = pairs.schur_blocks(Y, nrm.wp_blocks, pat.pose64, pat.by_point_order, pat.point_starts, SCHUR_THREADS)
        np.negative(B, out=B)
        B[pairs.diag_blocks] += _damp(nrm.U_pp, lam)
        S, s = pairs.matrix(B, nrm.U_pg.reshape(n6, G) - S_pg, _damp(nrm.U_gg, lam) - S_gg)
        return Reduced(S, Vinv, s, None, sparse_factor(S))
    S = _damp(nrm.U, lam).copy()
    if not large and not track_sum_pays(np.diff(pat.point_starts), N):
        S[:n6, :n6] -= pat.matrix(Y).toarray() @ nrm.Wp.T.toarray()
    else:     # the points couple only the images that see them: a compiled sum over their tracks
        S[:n6, :n6] -= pose_pose_schur(Y, nrm.wp_blocks, pat.pose64, pat.by_point_order, pat.point_starts, N,
                                       SCHUR_THREADS)
    if G:
        S[:n6, n6:] -= S_pg
        S[n6:, :n6] -= S_pg.T
        S[n6:, n6:] -= S_gg
    return _dense_reduced(S, Vinv)


def track_sum_pays(track_lengths: np.ndarray, n_poses: int) -> bool:
    """Whether the compiled sum over the points' tracks (items per point `track_lengths`) forms the pose-pose Schur
    product faster than a dense GEMM over `n_poses` poses (GEMM_SPEEDUP)."""
    k = np.asarray(track_lengths, float)
    return GEMM_SPEEDUP * float(k @ k) < float(n_poses) ** 2 * len(k)


def _dense_reduced(S: np.ndarray, Vinv: np.ndarray) -> Reduced:
    """The dense S with its scaled Cholesky factor (None when S is not positive definite)."""
    s = np.sqrt(np.maximum(np.diag(S), 1e-300))
    try:
        factor = cho_factor(S / s[:, None] / s[None, :], check_finite=False)
    except (LinAlgError, ValueError):
        factor = None
    return Reduced(S, Vinv, s, factor)


def solve_reduced(red: Reduced, b_c: np.ndarray) -> np.ndarray:
    """S^-1 b_c (b_c (nc,) or (nc,q)), by the scaled factor or least squares when S is singular."""
    if red.arrow is not None:
        return red.arrow.solve(b_c)
    s = red.scale if b_c.ndim == 1 else red.scale[:, None]
    if red.lu is not None:
        return red.lu.solve(np.ascontiguousarray(b_c / s)) / s
    if red.factor is not None:
        return cho_solve(red.factor, b_c / s, check_finite=False) / s
    return np.linalg.lstsq(red.dense(), b_c, rcond=None)[0]


def solve_normals(nrm: Normals, red: Reduced, b_c: np.ndarray, b_x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """N^-1 [b_c; b_x] through the Schur complement: camera side (nc,...) and point side (3M,...)."""
    if not len(red.Vinv):
        return solve_reduced(red, b_c), np.zeros_like(b_x)
    if nrm.wp_blocks is None:                # points and camera side uncoupled
        return solve_reduced(red, b_c), _vinv_dot(red.Vinv, b_x)
    y = _vinv_dot(red.Vinv, b_x)
    dc = solve_reduced(red, b_c - nrm.W_dot(y))
    dx = _vinv_dot(red.Vinv, b_x - nrm.WT_dot(dc))
    return dc, dx


def step(nrm: Normals, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """The damped Gauss-Newton step (camera side dc, points dx)."""
    red = reduce(nrm, lam)
    return solve_normals(nrm, red, -nrm.g_c, -nrm.g_x)
