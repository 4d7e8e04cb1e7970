"""The pose-pose Schur product W V^-1 W^T two ways, on the same synthetic blocks: a dense GEMM of the (6N x 3M)
couplings (what dgcal.bundle.solver.normals.reduce does for small blocks) beside the compiled sum over the points'
tracks (dgcal.bundle.solver.kernels.pose_pose_schur), from every point in every image (close range, a target
field) to short tracks (aerial blocks). Prints both times, their ratio, the flop ratio N^2 M / sum k^2 and which one
`track_sum_pays` (GEMM_SPEEDUP) picks: the pick should be the faster one but near the break-even.

Run by hand: `OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/schur.py` (one BLAS thread, as campaign steps run).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dgcal.bundle.solver.normals import GEMM_SPEEDUP, pose_pose_schur, track_sum_pays  # noqa: E402

CASES = [(36, 100, 36), (36, 300, 36), (60, 600, 60), (300, 200, 300), (20, 2000, 20), (36, 300, 12),
         (60, 600, 20), (122, 1474, 40), (20, 2000, 5), (122, 1474, 18), (200, 1000, 10)]


def _block(rng, N: int, M: int, k: int):
    """Random couplings W of M points each seen by k of N images and Y = W V^-1: (Y, W, pose, order, starts,
    point)."""
    pose = np.concatenate([np.sort(rng.choice(N, k, replace=False)) for _ in range(M)]).astype(np.int64)
    point = np.repeat(np.arange(M), k)
    A = rng.normal(size=(M, 3, 3))
    Vinv = A @ A.transpose(0, 2, 1) + np.eye(3)                      # a point's inverse normal block: SPD
    W = rng.normal(size=(len(pose), 6, 3))
    Y = W @ Vinv[point]
    order = np.lexsort((pose, point)).astype(np.int64)
    starts = np.searchsorted(point[order], np.arange(M + 1)).astype(np.int64)
    return Y, W, pose, order, starts, point


def _coupling(blocks: np.ndarray, pose: np.ndarray, point: np.ndarray, N: int, M: int) -> sp.csr_matrix:
    rows = np.broadcast_to(6 * pose[:, None, None] + np.arange(6)[None, :, None], blocks.shape)
    cols = np.broadcast_to(3 * point[:, None, None] + np.arange(3)[None, None, :], blocks.shape)
    return sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(6 * N, 3 * M))


def main() -> None:
    rng = np.random.default_rng(0)
    print(f"GEMM_SPEEDUP = {GEMM_SPEEDUP}; best of 3 runs each")
    for N, M, k in CASES:
        Y, W, pose, order, starts, point = _block(rng, N, M, k)
        YM, WM = _coupling(Y, pose, point, N, M), _coupling(W, pose, point, N, M)
        pose_pose_schur(Y, W, pose, order, starts, N, 1)     # compiled (or loaded from the cache) outside the timing
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            dense = YM.toarray() @ WM.T.toarray()
            t1 = time.perf_counter()
            tracks = pose_pose_schur(Y, W, pose, order, starts, N, 1)
            times.append((t1 - t0, time.perf_counter() - t1))
        assert np.allclose(dense, tracks, atol=1e-9 * np.abs(dense).max())
        d, c = np.min(times, axis=0)
        pick = "tracks" if track_sum_pays(np.diff(starts), N) else "dense"
        print(f"N {N:4d} M {M:5d} k {k:3d}: dense GEMM {1e3 * d:7.1f} ms, track sum {1e3 * c:7.1f} ms "
              f"(dense/tracks {d / c:5.2f}; N^2 M / sum k^2 {N * N / k / k:6.1f}) -> picks {pick}")


if __name__ == "__main__":
    main()
