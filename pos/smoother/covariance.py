"""Covariances of the smoother's keyframe states from the linearised graph, by block-tridiagonal recursion.

Why not `gtsam.Marginals`: the receiver clock variables are in seconds (gtsam's GNSS factors), so their
Jacobian columns are ~c/sigma = 1e9 larger than the others and the Cholesky of the normal matrix breaks
down (Jacobian condition ~1e10). Here the information of every keyframe pair comes from the linearised graph's
rows grouped by keyframe, with the clock columns rescaled to metres (`dgcal.pos.smoother.linearised`), and the
marginals follow from the exact block-tridiagonal recursion (forward Schur complements, backward
Rauch-Tung-Striebel pass). The same forward pass restricted to the factors available at each epoch is a Kalman
filter in information form (`forward_pass`, `forward_innovations`).

Covariances are in gtsam's local coordinates: Pose3 = [rotation (body, rad), position (body axes, m)].
"""
from __future__ import annotations

import numpy as np

from dgcal.pos.smoother.linearised import KeyframeBlocks, KeyframeRows, keyframe_rows
from dgcal.pos.smoother.recursions import information_filter, rts_covariances, rts_step, schur_inverses

__all__ = ["KeyframeBlocks", "smoothed_covariances", "forward_pass", "forward_innovations"]


def _pair_blocks(rows: KeyframeRows, blocks: KeyframeBlocks):
    """From the rows of each keyframe: D (K,n,n) the information of the rows whose latest keyframe is k, on k;
    U (K-1,n,n) the coupling of k and k+1; Dn (K,n,n) the rows reaching k+1, on k; and the matching information
    vectors eD, en (K,n)."""
    n, K = blocks.n, blocks.K
    H, g = rows.normal()
    D = H[:, n:, n:]
    eD = g[:, n:]
    Dn = np.zeros_like(D)
    en = np.zeros_like(eD)
    Dn[:-1] = H[1:, :n, :n]
    en[:-1] = g[1:, :n]
    U = H[1:, :n, n:] if K > 1 else np.zeros((0, n, n))
    return D, U, Dn, eD, en


def _unscale(P: np.ndarray, blocks: KeyframeBlocks) -> np.ndarray:
    s = blocks.scale
    return P * s[..., :, None] * s[..., None, :]


def smoothed_covariances(graph, values, blocks: KeyframeBlocks, rows: KeyframeRows | None = None,
                         step: bool = False):
    """Marginal covariance (K,n,n) of every keyframe block given all data (clock entries in s, s/s); `rows`: the
    graph already linearised at `values` (`dgcal.pos.smoother.linearised.keyframe_rows`). With `step`, also the
    Gauss-Newton step (K,n) of the linearised problem from `values` (same units): what an optimiser stopped short
    of the minimum would still move."""
    rows = rows if rows is not None else keyframe_rows(graph, values, blocks)
    D, U, Dn, eD, en = _pair_blocks(rows, blocks)
    D = blocks.pad_inactive(D + Dn)
    e = eD + en
    # forward Schur complements (sequential), then the RTS gains of all keyframes at once and the backward pass
    D = np.ascontiguousarray(D)
    U = np.ascontiguousarray(U)
    Sinv = schur_inverses(D, U)
    G = Sinv[:-1] @ U
    P = rts_covariances(Sinv, G)
    if not step:
        return _unscale(P, blocks)
    dx = rts_step(Sinv, G, np.ascontiguousarray(e))
    return _unscale(P, blocks), dx * blocks.scale


def variance_factors(graph, values, blocks: KeyframeBlocks, rows: KeyframeRows, group: np.ndarray,
                     n_groups: int) -> tuple[np.ndarray, np.ndarray]:
    """Helmert's variance components of groups of rows: per group, the sum of its whitened squared residuals and its
    redundancy, the sum over its rows of 1 - a J a' (a the row, J the posterior covariance of the two keyframes it
    reaches, from the block-tridiagonal recursion with the lag-one covariances -G[k] P[k+1]). Their ratio is the
    factor by which the group's noise variance is too small (1 when the model fits); the redundancy tells how well
    the data determine it. `group` (gtsam's rows of the graph): the group of each row, -1 for none. Returns (sum of
    squares (n_groups,), redundancy (n_groups,))."""
    K, n = blocks.K, blocks.n
    D, U, Dn, _, _ = _pair_blocks(rows, blocks)
    D = blocks.pad_inactive(D + Dn)
    Sinv = schur_inverses(np.ascontiguousarray(D), np.ascontiguousarray(U))
    G = Sinv[:-1] @ U
    P = rts_covariances(Sinv, np.ascontiguousarray(G))
    J = np.zeros((K, 2 * n, 2 * n))
    J[:, n:, n:] = P
    if K > 1:
        C = -G @ P[1:]
        J[1:, :n, :n] = P[:-1]
        J[1:, :n, n:] = C
        J[1:, n:, :n] = np.swapaxes(C, 1, 2)
    g = np.where(rows.row >= 0, np.asarray(group)[np.maximum(rows.row, 0)], -1)
    h = np.einsum("kmj,kmj->km", rows.A @ J, rows.A)        # each row's leverage a J a'
    ok = g >= 0
    ss = np.bincount(g[ok], weights=rows.b[ok] ** 2, minlength=n_groups)
    red = np.bincount(g[ok], weights=1.0 - h[ok], minlength=n_groups)
    return ss, red


def forward_pass(graph, values, blocks: KeyframeBlocks, rows: KeyframeRows | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Kalman filter on the graph linearised at `values`: for each keyframe k the correction (K,n) to its
    linearisation point and the covariance (K,n,n) given only the factors up to keyframe k (clock entries
    in s, s/s)."""
    K, n = blocks.K, blocks.n
    rows = rows if rows is not None else keyframe_rows(graph, values, blocks)
    D, U, Dn, eD, en = _pair_blocks(rows, blocks)
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
    return dx * blocks.scale, _unscale(P, blocks)


def _inv_sym(S: np.ndarray) -> np.ndarray:
    """Inverse of the symmetric part of S (..., m, m), symmetrised."""
    St = np.swapaxes(S, -1, -2)
    Si = np.linalg.inv(0.5 * (S + St))
    return 0.5 * (Si + np.swapaxes(Si, -1, -2))


def forward_innovations(graph, values, blocks: KeyframeBlocks, row_kind: np.ndarray, kinds: list,
                        rows: KeyframeRows | None = None):
    """Kalman filter on the graph linearised at `values`, with innovations: for each keyframe k the correction
    (K,n) to its linearisation point and the covariance (K,n,n) given only the data up to k (clock entries in s,
    s/s), the normalised innovation squared of each measurement kind at k, kind -> [(k, NIS, rows)], and every
    measurement row's whitened innovation (NaN for process rows).

    `row_kind` (gtsam's rows of the graph): -1 for process rows (priors, IMU, clock and bias processes), else the
    index in `kinds` of the measurement the row belongs to. At keyframe k the filtered k-1 and the process rows
    ending at k give the predicted joint of (k-1, k); each kind's rows A, b (error A x - b) at the predicted mean
    x give NIS = r' (A P A' + I)^-1 r, r = A x - b; then all measurement rows update and k-1 is marginalised."""
    K, n = blocks.K, blocks.n
    rows = rows if rows is not None else keyframe_rows(graph, values, blocks)
    pad_row = rows.row < 0
    kind = np.where(pad_row, -2, np.asarray(row_kind)[np.where(pad_row, 0, rows.row)])
    proc = kind == -1
    Jp, gp = rows.normal(proc)          # the process rows come first in each keyframe (the graph's order)
    Jt, gt = rows.normal()
    pad = np.zeros((K, n))
    if blocks.n_slots:
        pad[~blocks.active] = 1.0
    diag = np.arange(n, 2 * n)
    Jp[:, diag, diag] += pad
    Jp[0, :n, :n] += np.eye(n)       # no keyframe before the first: a decoupled placeholder
    # the filter's information recursion is sequential; everything else runs on all keyframes at once after it
    Sf, yf = _filter_information(Jt, gt, pad, n)
    # the prediction of (k-1, k) from the filtered k-1 and the process rows ending at k
    Jp[1:, :n, :n] += Sf[:-1]
    gp[1:, :n] += yf[:-1]
    Ppred = _inv_sym(Jp)
    xpred = np.einsum("kij,kj->ki", Ppred, gp)
    P = _inv_sym(Sf)
    dx = np.einsum("kij,kj->ki", P, yf)
    innov = np.full(len(rows.b_all), np.nan)
    res = np.einsum("kmi,ki->km", rows.A, xpred) - rows.b
    meas = kind >= 0
    innov[rows.row[meas]] = res[meas]
    nis: dict = {}
    for kd in range(len(kinds)):
        m = kind == kd
        ks = np.flatnonzero(m.any(axis=1))
        if not len(ks):
            continue
        for k, v, d in zip(ks, *_nis(rows.A[ks], res[ks], m[ks], Ppred[ks])):
            if np.isfinite(v):
                nis.setdefault(kinds[kd], []).append((int(k), float(v), int(d)))
    return dx * blocks.scale, _unscale(P, blocks), nis, innov


def _filter_information(Jt: np.ndarray, gt: np.ndarray, pad: np.ndarray, n: int):
    """Information (K,n,n) and vector (K,n) of each keyframe given the rows up to it: Jt, gt (K,2n,2n), (K,2n) the
    information of the rows whose latest keyframe is k, over (k-1, k); `pad` (K,n) unit information of the empty
    slots. Sequential: each keyframe's Schur complement after the previous one's (`information_filter`)."""
    Jt = Jt.copy()
    diag = np.arange(n, 2 * n)
    Jt[:, diag, diag] += pad
    Jt[0, :n, :n] += np.eye(n)
    return information_filter(Jt, np.ascontiguousarray(gt), n)


def _nis(A: np.ndarray, r: np.ndarray, m: np.ndarray, P: np.ndarray):
    """NIS r' (A P A' + I)^-1 r of the rows `m` (K,M) of each keyframe, and their number; the rows are first packed
    to the most any keyframe has (padding rows are zero with zero residual: decoupled, they add nothing)."""
    cnt = m.sum(axis=1)
    L = int(cnt.max())
    slot = np.cumsum(m, axis=1) - 1
    kk, jj = np.nonzero(m)
    Am = np.zeros((len(A), L, A.shape[2]))
    rm = np.zeros((len(A), L))
    Am[kk, slot[kk, jj]] = A[kk, jj]
    rm[kk, slot[kk, jj]] = r[kk, jj]
    S = Am @ P @ np.swapaxes(Am, 1, 2) + np.eye(L)
    try:
        v = np.einsum("km,km->k", rm, np.linalg.solve(S, rm[..., None])[..., 0])
    except np.linalg.LinAlgError:
        v = np.array([_nis_one(S[i], rm[i]) for i in range(len(S))])
    return v, cnt


def _nis_one(S: np.ndarray, r: np.ndarray) -> float:
    try:
        return float(r @ np.linalg.solve(S, r))
    except np.linalg.LinAlgError:
        return np.nan
