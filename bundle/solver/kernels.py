"""Compiled kernels (numba) of the engine's hot loops over image observations with point unknowns: the per-item
normal-equation products (with the pose, the point and the globals), the pose-pose Schur complement sum over
the points and the redundancy numbers' quadratic forms. Each walks the observations once, in C speed, without
the (k,6,6) temporaries of the vectorised NumPy form; `normals.py` and `covariance.py` call them, the NumPy forms
are the references in tests/bundle/test_bundle_solver.py.

Problems without point unknowns (a camera calibrated on a known target field) stay in NumPy: numba's first call
in a process costs 0.3-0.7 s, more than such an adjustment takes.
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


@njit(cache=True)
def accumulate_pose_globals(J_pose, pose, J_glob, U_pg):  # pragma: no cover - compiled
    """Add one block's pose-global couplings J_pose^T J_glob to U_pg (N,6,Gb). J_pose (k,d,6); J_glob (k,d,Gb);
    pose (k,)."""
    k, d, Gb = J_glob.shape
    for n in range(k):
        i = pose[n]
        for e in range(d):
            for a in range(6):
                ja = J_pose[n, e, a]
                for b in range(Gb):
                    U_pg[i, a, b] += ja * J_glob[n, e, b]


@njit(cache=True)
def accumulate_global_points(J_glob, J_point, point, Wg):  # pragma: no cover - compiled
    """Add one block's global-point couplings J_glob^T J_point to Wg (Gb,M,3). J_glob (k,d,Gb); J_point (k,d,3)."""
    k, d, Gb = J_glob.shape
    for n in range(k):
        j = point[n]
        for g in range(Gb):
            for b in range(3):
                s = 0.0
                for e in range(d):
                    s += J_glob[n, e, g] * J_point[n, e, b]
                Wg[g, j, b] += s


@njit(cache=True)
def redundancy_quadratic(Q, a_ptr, a_idx, a_val, U, row_point, order, wt_ptr, wt_idx, wt_val, q):  # pragma: no cover
    """q[r] += D_r Q D_r^T for whitened observation rows D_r = A_r - U_r^T W_j^T (the camera-side row A_r pushed
    through the elimination of its point j, none when row_point[r] < 0), without forming D.

    Q (nc,nc) symmetric; A in CSR (a_ptr, a_idx, a_val), (R, nc); U (R,3) = the row's A_x V_j^-1; W^T in CSR
    (3M, nc); `order` sorts the rows by point. Per point j, with Z = Q W_j on the columns the point and its rows
    touch: D_r Q D_r^T = A_r Q A_r^T - 2 A_r Z U_r + U_r^T (W_j^T Z) U_r."""
    nc = Q.shape[0]
    pos = np.full(nc, -1, np.int64)
    supp = np.empty(nc, np.int64)
    Z = np.zeros((nc, 3))
    R = len(order)
    u = 0
    while u < R:
        j = row_point[order[u]]
        v = u
        while v < R and row_point[order[v]] == j:
            v += 1
        ns = 0
        if j >= 0:
            for b in range(3):
                for p in range(wt_ptr[3 * j + b], wt_ptr[3 * j + b + 1]):
                    c = wt_idx[p]
                    if pos[c] < 0:
                        pos[c] = ns
                        supp[ns] = c
                        ns += 1
            for t in range(u, v):
                r = order[t]
                for p in range(a_ptr[r], a_ptr[r + 1]):
                    c = a_idx[p]
                    if pos[c] < 0:
                        pos[c] = ns
                        supp[ns] = c
                        ns += 1
            for x in range(ns):
                Z[x, 0] = 0.0
                Z[x, 1] = 0.0
                Z[x, 2] = 0.0
            for b in range(3):
                for p in range(wt_ptr[3 * j + b], wt_ptr[3 * j + b + 1]):
                    s = wt_idx[p]
                    wv = wt_val[p]
                    for x in range(ns):
                        Z[x, b] += Q[s, supp[x]] * wv      # Q symmetric: row access
            H = np.zeros((3, 3))
            for b in range(3):
                for p in range(wt_ptr[3 * j + b], wt_ptr[3 * j + b + 1]):
                    x = pos[wt_idx[p]]
                    for c in range(3):
                        H[b, c] += wt_val[p] * Z[x, c]
        for t in range(u, v):
            r = order[t]
            t1 = 0.0
            for p1 in range(a_ptr[r], a_ptr[r + 1]):
                c1 = a_idx[p1]
                s = 0.0
                for p2 in range(a_ptr[r], a_ptr[r + 1]):
                    s += Q[c1, a_idx[p2]] * a_val[p2]
                t1 += a_val[p1] * s
            if j >= 0:
                u0, u1, u2 = U[r, 0], U[r, 1], U[r, 2]
                t2 = 0.0
                for p in range(a_ptr[r], a_ptr[r + 1]):
                    x = pos[a_idx[p]]
                    t2 += a_val[p] * (Z[x, 0] * u0 + Z[x, 1] * u1 + Z[x, 2] * u2)
                t3 = (u0 * (H[0, 0] * u0 + H[0, 1] * u1 + H[0, 2] * u2)
                      + u1 * (H[1, 0] * u0 + H[1, 1] * u1 + H[1, 2] * u2)
                      + u2 * (H[2, 0] * u0 + H[2, 1] * u1 + H[2, 2] * u2))
                q[r] += t1 - 2.0 * t2 + t3
            else:
                q[r] += t1
        for x in range(ns):
            pos[supp[x]] = -1
        u = v


@njit(cache=True)
def pose_pair_pattern(pose, order, starts, N):  # pragma: no cover - compiled
    """The upper (p <= q) 6x6 blocks of the reduced camera system: every (p, p) and every pair of poses that
    share a point. Returns lut (N,N) int32 (block number of (p, q), -1 for none; p <= q) and the block rows and
    columns (n_blocks,) in row-major order. `order`/`starts` as in `pose_pose_schur` (by point, then pose)."""
    mark = np.zeros((N, N), np.bool_)
    for p in range(N):
        mark[p, p] = True
    for j in range(len(starts) - 1):
        for u in range(starts[j], starts[j + 1]):
            pa = pose[order[u]]
            for v in range(u + 1, starts[j + 1]):
                mark[pa, pose[order[v]]] = True
    lut = np.full((N, N), -1, np.int32)
    n = 0
    for p in range(N):
        for q in range(p, N):
            if mark[p, q]:
                lut[p, q] = n
                n += 1
    rows = np.empty(n, np.int64)
    cols = np.empty(n, np.int64)
    for p in range(N):
        for q in range(p, N):
            k = lut[p, q]
            if k >= 0:
                rows[k] = p
                cols[k] = q
    return lut, rows, cols


@njit(cache=True, parallel=True)
def pose_pose_schur_blocks(Y, W, pose, order, starts, lut, n_blocks, n_threads):  # pragma: no cover - compiled
    """sum_j W_j V_j^-1 W_j^T over the points as its upper 6x6 blocks (n_blocks,6,6) of `pose_pair_pattern`'s
    lut: the block-sparse form of `pose_pose_schur` (no dense 6N x 6N accumulator, nothing to mirror)."""
    M = len(starts) - 1
    parts = np.zeros((n_threads, n_blocks, 6, 6))
    for t in prange(n_threads):
        B = parts[t]
        for j in range(t * M // n_threads, (t + 1) * M // n_threads):
            for u in range(starts[j], starts[j + 1]):
                a = order[u]
                pa = pose[a]
                for v in range(u, starts[j + 1]):
                    b = order[v]
                    pb = pose[b]
                    k = lut[pa, pb]
                    for x in range(6):
                        y0, y1, y2 = Y[a, x, 0], Y[a, x, 1], Y[a, x, 2]
                        for y in range(6):
                            B[k, x, y] += y0 * W[b, y, 0] + y1 * W[b, y, 1] + y2 * W[b, y, 2]
                    if v != u and pa == pb:   # the same image twice in a track: both orders of the pair
                        for x in range(6):
                            for y in range(6):
                                B[k, x, y] += (Y[b, x, 0] * W[a, y, 0] + Y[b, x, 1] * W[a, y, 1]
                                               + Y[b, x, 2] * W[a, y, 2])
    S = parts[0]
    for t in range(1, n_threads):
        S += parts[t]
    return S


@njit(cache=True)
def coupling_dot(blocks, pose, point, x, out):  # pragma: no cover - compiled
    """out (6N,q) += Wp x for x (3M,q), Wp given by its per-item blocks (k,6,3) at (pose, point)."""
    q = x.shape[1]
    for n in range(len(pose)):
        i = 6 * pose[n]
        j = 3 * point[n]
        for c in range(q):
            x0, x1, x2 = x[j, c], x[j + 1, c], x[j + 2, c]
            for a in range(6):
                out[i + a, c] += blocks[n, a, 0] * x0 + blocks[n, a, 1] * x1 + blocks[n, a, 2] * x2


@njit(cache=True)
def coupling_tdot(blocks, pose, point, y, out):  # pragma: no cover - compiled
    """out (3M,q) += Wp^T y for y (6N,q), Wp given by its per-item blocks (k,6,3) at (pose, point)."""
    q = y.shape[1]
    for n in range(len(pose)):
        i = 6 * pose[n]
        j = 3 * point[n]
        for c in range(q):
            for b in range(3):
                s = 0.0
                for a in range(6):
                    s += blocks[n, a, b] * y[i + a, c]
                out[j + b, c] += s


@njit(cache=True)
def pose_point_jacobians(JX, w, R, pose, Xc, J_pose, J_point):  # pragma: no cover - compiled
    """Whitened Jacobians of image observations from d(uv)/d(X_cam) JX (k,2,3), the whitening w = 1/sigma (k,2),
    the rotations R (N,3,3) world -> camera, each item's pose (k,) and X_cam (k,3): J_point = w JX R (k,2,3) and
    J_pose = [-J_point, w JX [X_cam]x] (k,2,6) (`dgcal.fields.pose`: C += dC, R_cam_to_world Exp(dtheta))."""
    for n in range(len(pose)):
        i = pose[n]
        x0, x1, x2 = Xc[n, 0], Xc[n, 1], Xc[n, 2]
        for e in range(2):
            a0, a1, a2 = JX[n, e, 0] * w[n, e], JX[n, e, 1] * w[n, e], JX[n, e, 2] * w[n, e]
            for c in range(3):
                v = a0 * R[i, 0, c] + a1 * R[i, 1, c] + a2 * R[i, 2, c]
                J_point[n, e, c] = v
                J_pose[n, e, c] = -v
            # a [x]_x with [x]_x = [[0,-x2,x1],[x2,0,-x0],[-x1,x0,0]]
            J_pose[n, e, 3] = a1 * x2 - a2 * x1
            J_pose[n, e, 4] = a2 * x0 - a0 * x2
            J_pose[n, e, 5] = a0 * x1 - a1 * x0


@njit(cache=True)
def to_camera(R, C, X, pose, point):  # pragma: no cover - compiled
    """X_cam (k,3) = R[pose] (X[point] - C[pose]) for every item (R (N,3,3) world -> camera, C (N,3), X (M,3))."""
    k = len(pose)
    out = np.empty((k, 3))
    for n in range(k):
        i = pose[n]
        j = point[n]
        d0, d1, d2 = X[j, 0] - C[i, 0], X[j, 1] - C[i, 1], X[j, 2] - C[i, 2]
        for a in range(3):
            out[n, a] = R[i, a, 0] * d0 + R[i, a, 1] * d1 + R[i, a, 2] * d2
    return out
