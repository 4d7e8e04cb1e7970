"""Initial exterior orientation: PnP resection from known points and incremental growth through tie points.

Frames as in `dgcal.bundle.adjustment`: `R_world_to_cam`, `C_world` in a local Cartesian world frame (m).
"""
from __future__ import annotations

import cv2
import numpy as np

from dgcal.calib.camera.models import CameraModel


def pnp(camera: CameraModel, uv: np.ndarray, X_world: np.ndarray, threshold_px: float = 4.0,
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Resect one image from >= 4 pixel/world correspondences: (R_world_to_cam, C_world, inlier mask) or None.

    Pixels are undistorted to ideal normalised coordinates first, so PnP runs on an identity camera.
    RANSAC (threshold in pixels) when there are 6 or more points, then Levenberg-Marquardt refinement.
    """
    uv = np.asarray(uv, float)
    X = np.asarray(X_world, float)
    if len(uv) < 4:
        return None
    xy = camera.undistort_normalized(uv)
    f = float(camera.pinhole_K()[0, 0])
    K = np.eye(3)
    origin = X.mean(0)   # PnP on centred coordinates keeps large map coordinates out of the solver
    Xc = np.ascontiguousarray(X - origin)
    sv = np.linalg.svd(Xc, compute_uv=False)
    if sv[1] < 1e-2 * sv[0]:
        return None      # collinear points leave the rotation about their line undetermined
    xy = np.ascontiguousarray(xy)
    inl = np.ones(len(uv), bool)
    try:   # degenerate geometry (collinear points, too few) makes OpenCV assert: no pose, not a crash
        if len(uv) >= 6:
            ok, rvec, tvec, idx = cv2.solvePnPRansac(Xc, xy, K, None, reprojectionError=threshold_px / f,
                                                     iterationsCount=500, confidence=0.9999, flags=cv2.SOLVEPNP_SQPNP)
            if not ok or idx is None or len(idx) < 4:
                return None
            inl = np.zeros(len(uv), bool)
            inl[idx.ravel()] = True
        else:
            ok, rvec, tvec = cv2.solvePnP(Xc, xy, K, None, flags=cv2.SOLVEPNP_SQPNP)
            if not ok:
                return None
        rvec, tvec = cv2.solvePnPRefineLM(Xc[inl], xy[inl], K, None, rvec, tvec)
    except cv2.error:
        return None
    R_world_to_cam = cv2.Rodrigues(rvec)[0]
    C_world = -R_world_to_cam.T @ tvec.ravel() + origin
    Xcam = (X - C_world) @ R_world_to_cam.T
    proj = Xcam[:, :2] / Xcam[:, 2:3]
    err = np.linalg.norm(proj - xy, axis=1) * f
    inl = inl & (Xcam[:, 2] > 0) & (err < max(threshold_px, 3 * np.median(err[inl]) if inl.any() else 0))
    if inl.sum() < 4:
        return None
    return R_world_to_cam, C_world, inl


def triangulate_midpoint(C_world: np.ndarray, d_world: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares intersection of rays C + t d (k,3 each): the point (3,) and the widest ray angle (deg)."""
    d = d_world / np.linalg.norm(d_world, axis=1, keepdims=True)
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = P.sum(0)
    b = np.einsum("kij,kj->i", P, C_world)
    X = np.linalg.lstsq(A, b, rcond=None)[0]
    cosang = np.clip(d @ d.T, -1, 1)
    return X, float(np.degrees(np.arccos(cosang.min())))


def triangulate_tracks(C_world: np.ndarray, R_world_to_cam: np.ndarray, rays_cam: np.ndarray,
                       starts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`triangulate_midpoint` of many tracks at once: rays C + t R^T ray (k items, sorted by track; `starts` (p,)
    where each track begins). Returns the points (p,3) m, each track's widest ray angle (p,) deg and whether
    the point lies in front of all its cameras (p,)."""
    d = np.einsum("kji,kj->ki", R_world_to_cam, rays_cam)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = np.add.reduceat(P, starts, axis=0)
    b = np.add.reduceat(np.einsum("kij,kj->ki", P, C_world), starts, axis=0)
    X = np.einsum("pij,pj->pi", np.linalg.pinv(A), b)      # the least-squares (minimum-norm) point, as lstsq
    # every pair of rays of a track: the widest angle
    k = len(d)
    length = np.diff(np.append(starts, k))
    track = np.repeat(np.arange(len(starts)), length)
    n_pair = length[track]
    a = np.repeat(np.arange(k), n_pair)
    first = np.repeat(starts[track], n_pair)
    b_idx = first + np.arange(len(a)) - np.repeat(np.cumsum(n_pair) - n_pair, n_pair)
    cos_min = np.minimum.reduceat(np.clip(np.sum(d[a] * d[b_idx], axis=1), -1, 1), np.cumsum(length * length)
                                  - length * length)
    depth = np.einsum("kij,kj->ki", R_world_to_cam, X[track] - C_world)[:, 2]
    in_front = np.logical_and.reduceat(depth > 0, starts)
    return X, np.degrees(np.arccos(cos_min)), in_front


def grow_orientation(camera: CameraModel, n_images: int, obs_image: np.ndarray, obs_point: np.ndarray,
                     obs_uv: np.ndarray, X_known: np.ndarray, R0: np.ndarray | None = None,
                     C0: np.ndarray | None = None, min_angle_deg: float = 1.0,
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Initial orientation of every image it can reach, and initial points.

    `X_known` (m,3) holds coordinates of control points (NaN for tie points). Images with known
    approximate orientation (`R0`, `C0`, NaN where unknown) start oriented; the others are resected
    (PnP) from control and from tie points triangulated in already oriented images, repeatedly.
    Returns (R_world_to_cam (n,3,3), C_world (n,3), oriented mask (n,), X (m,3), point known mask (m,)).
    """
    oi, op = np.asarray(obs_image, int), np.asarray(obs_point, int)
    m = len(X_known)
    X = np.array(X_known, float)
    known = np.isfinite(X).all(1)
    R_world_to_cam = np.tile(np.eye(3), (n_images, 1, 1)) if R0 is None else np.array(R0, float)
    C_world = np.zeros((n_images, 3)) if C0 is None else np.array(C0, float)
    oriented = np.zeros(n_images, bool)
    if R0 is not None and C0 is not None:
        oriented = np.isfinite(np.asarray(R0)).all((1, 2)) & np.isfinite(np.asarray(C0)).all(1)
    rays = camera.ray(obs_uv)
    X_tie = X.copy()
    failed_at = np.zeros(n_images, int)
    used = np.zeros(m, int)
    while True:
        # triangulate tie points seen from two or more oriented images
        cnt = np.bincount(op[oriented[oi]], minlength=m)
        todo = ~known & (cnt >= 2) & (cnt > used) & (used < 4)   # more rays than last time, few so far
        sel = oriented[oi] & todo[op]
        if sel.any():
            order = np.argsort(op[sel], kind="stable")
            ks = np.nonzero(sel)[0][order]
            pts, starts = np.unique(op[ks], return_index=True)
            used[pts] = np.diff(np.append(starts, len(ks)))
            Xp, ang, depth_ok = triangulate_tracks(C_world[oi[ks]], R_world_to_cam[oi[ks]], rays[ks], starts)
            ok = (ang >= min_angle_deg) & depth_ok
            X_tie[pts[ok]] = Xp[ok]
        usable = known | np.isfinite(X_tie).all(1)
        # resect the not-yet-oriented image with the most usable points
        per_image = np.bincount(oi[usable[op]], minlength=n_images)
        per_image = np.where(oriented | (per_image <= np.maximum(failed_at, 3)), -1, per_image)
        best = int(np.argmax(per_image)) if per_image.max() > 0 else -1
        best_n = per_image[best] if best >= 0 else 0
        if best < 0:
            break
        kk = np.nonzero((oi == best) & usable[op])[0]
        Xs = np.where(known[op[kk]][:, None], X[op[kk]], X_tie[op[kk]])
        res = pnp(camera, obs_uv[kk], Xs)
        if res is None:
            failed_at[best] = best_n   # retry only once more points become usable
            continue
        R_world_to_cam[best], C_world[best], _ = res
        oriented[best] = True
    X_out = np.where(known[:, None], X, X_tie)
    return R_world_to_cam, C_world, oriented, X_out, np.isfinite(X_out).all(1)


def similarity_umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Scale s, rotation R, translation t with dst ~ s R src + t (least squares, Umeyama 1991)."""
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (np.sum(a * a) / len(src)))
    return s, R, md - s * R @ ms


def relative_bootstrap(camera: CameraModel, n_images: int, obs_image: np.ndarray, obs_point: np.ndarray,
                       obs_uv: np.ndarray, X_known: np.ndarray, max_pairs: int = 5):
    """Orientation without any image seeing 4 control points: relative orientation of the pair with the
    most common points (essential matrix), growth in that model frame, then a 3-D similarity onto the
    control points triangulated in it. Returns grow_orientation's tuple in the world frame, or None."""
    oi, op = np.asarray(obs_image, int), np.asarray(obs_point, int)
    m = len(X_known)
    known = np.isfinite(X_known).all(1)
    # co-observation counts of image pairs (sparse: points seen in few images)
    M = np.zeros((n_images, m), bool)
    M[oi, op] = True
    co = M.astype(np.int32) @ M.T.astype(np.int32)
    np.fill_diagonal(co, 0)
    xy = camera.undistort_normalized(obs_uv)
    f = float(camera.pinhole_K()[0, 0])
    lookup = -np.ones((n_images, m), int)
    lookup[oi, op] = np.arange(len(oi))
    order = np.argsort(co, axis=None)[::-1]
    for flat in order[:2 * max_pairs:2]:
        i, j = np.unravel_index(flat, co.shape)
        common = np.nonzero(M[i] & M[j])[0]
        if len(common) < 8:
            break
        x1, x2 = xy[lookup[i, common]], xy[lookup[j, common]]
        try:
            E, mask = cv2.findEssentialMat(x1, x2, np.eye(3), cv2.RANSAC, 0.999, 2.0 / f)
            if E is None or E.shape != (3, 3):
                continue
            _, R_model_to_cam_j, t_cam_j, mask = cv2.recoverPose(E, x1, x2, np.eye(3), mask=mask)
        except cv2.error:
            continue   # a degenerate pair: try the next one
        R_model_to_cam_0 = np.full((n_images, 3, 3), np.nan)
        C_model_0 = np.full((n_images, 3), np.nan)
        R_model_to_cam_0[i], C_model_0[i] = np.eye(3), np.zeros(3)
        R_model_to_cam_0[j], C_model_0[j] = R_model_to_cam_j, (-R_model_to_cam_j.T @ t_cam_j).ravel()
        R_model_to_cam, C_model, ok, X_model, okp = grow_orientation(
            camera, n_images, oi, op, obs_uv, np.full((m, 3), np.nan), R_model_to_cam_0, C_model_0, min_angle_deg=0.5)
        ctrl = known & okp
        if ctrl.sum() < 3 or np.linalg.matrix_rank(X_model[ctrl] - X_model[ctrl].mean(0), tol=1e-9) < 2:
            continue
        s, R_model_to_world, ts = similarity_umeyama(X_model[ctrl], X_known[ctrl])
        C_world = s * C_model @ R_model_to_world.T + ts
        R_world_to_cam = R_model_to_cam @ R_model_to_world.T
        X_world = s * X_model @ R_model_to_world.T + ts
        X_world[known] = X_known[known]
        return R_world_to_cam, C_world, ok, X_world, okp | known
    return None


def resect_by_relative_orientation(camera: CameraModel, image: int, R_world_to_cam: np.ndarray, C_world: np.ndarray,
                                   oriented: np.ndarray, obs_image: np.ndarray, obs_point: np.ndarray,
                                   obs_uv: np.ndarray, min_shared: int = 12, threshold_px: float = 2.0,
                                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """Pose of an image that shares points with two or more oriented images but too few known points for PnP
    (tie points seen in two images only): its rotation from the relative orientations (essential matrices) to
    those images, its centre where their baseline directions meet. (R_world_to_cam (3,3), C_world (3,)) or None."""
    oi, op = np.asarray(obs_image, int), np.asarray(obs_point, int)
    mine = np.flatnonzero(oi == image)
    f = float(camera.pinhole_K()[0, 0])
    rots, origins, dirs, weights, pairs = [], [], [], [], []
    pts_i = op[mine]
    for j in np.flatnonzero(oriented):
        theirs = np.flatnonzero(oi == j)
        common, ki, kj = np.intersect1d(pts_i, op[theirs], return_indices=True)
        if len(common) < min_shared:
            continue
        x_i = camera.undistort_normalized(obs_uv[mine[ki]])
        x_j = camera.undistort_normalized(obs_uv[theirs[kj]])
        try:
            E, mask = cv2.findEssentialMat(x_j, x_i, np.eye(3), cv2.RANSAC, 0.999, threshold_px / f)
            if E is None or E.shape != (3, 3):
                continue
            n_in, R_j_to_i, t_i, mask = cv2.recoverPose(E, x_j, x_i, np.eye(3), mask=mask)
        except cv2.error:
            continue
        if n_in < min_shared:
            continue
        R_i = R_j_to_i @ R_world_to_cam[j]
        pairs.append((x_j, x_i, j))
        rots.append(R_i)
        origins.append(C_world[j])
        # x_i ~ R_j_to_i x_j + t: camera j's centre in camera i is t, so C_i = C_j - s R_i^T t (s > 0)
        dirs.append(-R_i.T @ t_i.ravel())
        weights.append(float(n_in))
    if len(rots) < 2:
        return None
    rots, origins, dirs, w = np.array(rots), np.array(origins), np.array(dirs), np.array(weights)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    # the estimates most others agree with (a planar patch or a weak pair can flip a relative orientation)
    tr = np.einsum("aij,bij->ab", rots, rots)             # trace of R_a R_b^T: the angle between them
    agree = np.degrees(np.arccos(np.clip((tr - 1) / 2, -1, 1))) < 1.0
    keep = agree[np.argmax(agree @ w)]
    while keep.sum() >= 2:
        C, widest = triangulate_midpoint(origins[keep], dirs[keep])
        if widest < 2.0:
            return None      # baselines nearly parallel: the centre slides along them
        v = C - origins
        off = np.degrees(np.arccos(np.clip(np.einsum("kj,kj->k", v, dirs) / np.linalg.norm(v, axis=1), -1, 1)))
        worst = int(np.argmax(np.where(keep, off, -1)))
        if off[worst] < 2.0:
            U, _, Vt = np.linalg.svd(np.einsum("k,kij->ij", w[keep], rots[keep]))   # chordal mean
            R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
            # the pose must explain every kept neighbour's shared rays (epipolar distances): a start is a few
            # tenths of a degree off (0.01 f), a wrong one far more
            for k in np.flatnonzero(keep):
                x_j, x_i, j = pairs[k]
                if np.median(epipolar_px(x_j, x_i, R_world_to_cam[j], C_world[j], R, C, f)) > 0.01 * f:
                    return None
            return R, C
        keep[worst] = False
    return None


def epipolar_px(x_a: np.ndarray, x_b: np.ndarray, R_a: np.ndarray, C_a: np.ndarray, R_b: np.ndarray,
                C_b: np.ndarray, f_px: float) -> np.ndarray:
    """Distances (px) of image b's normalised points x_b (k,2) from the epipolar lines of x_a (k,2), for poses
    (R_world_to_cam, C_world) a and b."""
    R_ab = R_b @ R_a.T
    t = R_b @ (C_a - C_b)
    E = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ R_ab
    ha = np.column_stack([x_a, np.ones(len(x_a))])
    hb = np.column_stack([x_b, np.ones(len(x_b))])
    line = ha @ E.T
    return f_px * np.abs(np.sum(hb * line, 1)) / np.maximum(np.hypot(line[:, 0], line[:, 1]), 1e-12)

