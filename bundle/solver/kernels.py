"""Compiled kernels (numba) of the engine's two hot loops: the per-item normal-equation products and the
pose-pose Schur complement sum over the points. Both walk the observations once, in C speed, without the
(k,6,6) temporaries of the vectorised NumPy form; `normals.py` calls them, the NumPy form is the reference
in tests/test_bundle_solver.py.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True)
def accumulate_items(r, J_pose, pose, J_point, point, U_pp, g_p, V, g_x, W_blocks):  # pragma: no cover - compiled
    """Add one block's items to the pose blocks U_pp (N,6,6), g_p (N,6), the point blocks V (M,3,3), g_x (M,3)
    and write each item's pose-point coupling J_pose^T J_point into W_blocks (k,6,3).
    r (k,d); J_pose (k,d,6); J_point (k,d,3); pose, point (k,) (the same length)."""
    k, d = r.shape
    for n in range(k):
        i = pose[n]
        j = point[n]
        for a in range(6):
            ga = 0.0
            for e in range(d):
                ga += J_pose[n, e, a] * r[n, e]
            g_p[i, a] += ga
            for b in range(a, 6):
                s = 0.0
                for e in range(d):
                    s += J_pose[n, e, a] * J_pose[n, e, b]
                U_pp[i, a, b] += s
                if b != a:
                    U_pp[i, b, a] += s
            for b in range(3):
                s = 0.0
                for e in range(d):
                    s += J_pose[n, e, a] * J_point[n, e, b]
                W_blocks[n, a, b] = s
        for a in range(3):
            ga = 0.0
            for e in range(d):
                ga += J_point[n, e, a] * r[n, e]
            g_x[j, a] += ga
            for b in range(a, 3):
                s = 0.0
                for e in range(d):
                    s += J_point[n, e, a] * J_point[n, e, b]
                V[j, a, b] += s
                if b != a:
                    V[j, b, a] += s


@njit(cache=True, parallel=True)
def pose_pose_schur(Y, W, pose, order, starts, N, n_threads):  # pragma: no cover - compiled
    """sum_j W_j V_j^-1 W_j^T over the points as a dense (6N,6N): for every pair of items a, b of a point's
    track, the block Y_a W_b^T at (pose_a, pose_b). Y, W (k,6,3); `order` sorts the items by point, then pose,
    and `starts` (M+1,) bounds each point's run in it. Only pose_a <= pose_b is summed, then mirrored; the
    points are split between `n_threads` threads, each with its own sum."""
    M = len(starts) - 1
    parts = np.zeros((n_threads, 6 * N, 6 * N))
    for t in prange(n_threads):
        S = parts[t]
        for j in range(t * M // n_threads, (t + 1) * M // n_threads):
            for u in range(starts[j], starts[j + 1]):
                a = order[u]
                pa = 6 * pose[a]
                for v in range(u, starts[j + 1]):
                    b = order[v]
                    pb = 6 * pose[b]
                    for x in range(6):
                        y0, y1, y2 = Y[a, x, 0], Y[a, x, 1], Y[a, x, 2]
                        for y in range(6):
                            S[pa + x, pb + y] += y0 * W[b, y, 0] + y1 * W[b, y, 1] + y2 * W[b, y, 2]
                    if v != u and pa == pb:   # the same image twice in a track: both orders of the pair
                        for x in range(6):
                            for y in range(6):
                                S[pa + x, pb + y] += (Y[b, x, 0] * W[a, y, 0] + Y[b, x, 1] * W[a, y, 1]
                                                      + Y[b, x, 2] * W[a, y, 2])
    S = parts[0]
    for t in range(1, n_threads):
        S += parts[t]
    # mirror the strictly upper blocks (the diagonal blocks are complete)
    for p in prange(N):
        for q in range(p + 1, N):
            for x in range(6):
                for y in range(6):
                    S[6 * q + y, 6 * p + x] = S[6 * p + x, 6 * q + y]
    return S
