"""Compiled sequential recursions over the keyframe chain: Schur complements, RTS passes, information filter.

Each keyframe step is a handful of products of n x n blocks (n ~ 17-40); from Python the call overhead of NumPy
is most of the time of a 3,600-keyframe hour (0.6 s), compiled it is a few milliseconds. The arithmetic is that
of the loops it replaces (`dgcal.pos.smoother.covariance`), step by step, in the same units.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _sym_inv(S: np.ndarray) -> np.ndarray:
    """Inverse of the symmetric part of S, symmetrised."""
    Si = np.linalg.inv(0.5 * (S + S.T))
    return 0.5 * (Si + Si.T)


@njit(cache=True)
def schur_inverses(D: np.ndarray, U: np.ndarray) -> np.ndarray:
    """Sinv (K,n,n): the inverses of the forward Schur complements of a block-tridiagonal information matrix with
    diagonal blocks D (K,n,n) and couplings U (K-1,n,n) (U[k] between k and k+1)."""
    K = D.shape[0]
    Sinv = np.empty_like(D)
    Sinv[0] = _sym_inv(D[0])
    for k in range(1, K):
        Uk = np.ascontiguousarray(U[k - 1])
        S = D[k] - Uk.T @ (Sinv[k - 1] @ Uk)
        Sinv[k] = _sym_inv(S)
    return Sinv


@njit(cache=True)
def rts_covariances(Sinv: np.ndarray, G: np.ndarray) -> np.ndarray:
    """P (K,n,n): the backward (Rauch-Tung-Striebel) pass P[k] = Sinv[k] + G[k] P[k+1] G[k]'."""
    K = Sinv.shape[0]
    P = np.empty_like(Sinv)
    P[K - 1] = Sinv[K - 1]
    for k in range(K - 2, -1, -1):
        Gk = np.ascontiguousarray(G[k])
        P[k] = Sinv[k] + Gk @ P[k + 1] @ Gk.T
    return P


@njit(cache=True)
def rts_step(Sinv: np.ndarray, G: np.ndarray, e: np.ndarray) -> np.ndarray:
    """dx (K,n): the solution of the block-tridiagonal system with information vector e (K,n), by the forward
    substitution y[k] = e[k] - G[k-1]' y[k-1] and the backward dx[k] = Sinv[k] y[k] - G[k] dx[k+1]."""
    K = Sinv.shape[0]
    ys = np.empty_like(e)
    ys[0] = e[0]
    for k in range(1, K):
        ys[k] = e[k] - np.ascontiguousarray(G[k - 1]).T @ ys[k - 1]
    dx = np.empty_like(e)
    dx[K - 1] = Sinv[K - 1] @ ys[K - 1]
    for k in range(K - 2, -1, -1):
        dx[k] = Sinv[k] @ ys[k] - np.ascontiguousarray(G[k]) @ dx[k + 1]
    return dx


@njit(cache=True)
def information_filter(Jt: np.ndarray, gt: np.ndarray, n: int):
    """Sf (K,n,n), yf (K,n): each keyframe's information and information vector given the rows up to it, from Jt,
    gt (K,2n,2n), (K,2n): the information of the rows whose latest keyframe is k over (k-1, k) (already regular)."""
    K = Jt.shape[0]
    Sf = np.empty((K, n, n))
    yf = np.empty((K, n))
    S = np.zeros((n, n))
    y = np.zeros(n)
    R = np.empty((n, n + 1))
    for k in range(K):
        J = Jt[k]
        Jll = 0.5 * (J[:n, :n] + J[:n, :n].T)
        R[:, :n] = J[:n, n:]
        R[:, n] = gt[k, :n] + y
        Gk = np.linalg.solve(Jll + S, R)
        Jnl = np.ascontiguousarray(J[n:, :n])
        S = J[n:, n:] - Jnl @ np.ascontiguousarray(Gk[:, :n])
        S = 0.5 * (S + S.T)
        y = gt[k, n:] - Jnl @ np.ascontiguousarray(Gk[:, n])
        Sf[k] = S
        yf[k] = y
    return Sf, yf
