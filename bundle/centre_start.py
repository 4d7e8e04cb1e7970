"""Initial orientation from known camera centres (GNSS/RTK/PPK priors, approximate EOPs without angles).

A nadir block whose centres are known needs only each image's heading (kappa) to start: omega = phi = 0.
Kappa comes from image motion: for every pair of images that share tie points, a 2-D similarity maps one
image's ideal (undistorted, normalised) coordinates onto the other's; its rotation is the difference of the
two kappas, and its shift is the motion of the ground in the image, the baseline between the two centres seen
through the image's kappa (for a nadir camera at height H, `x_j = A_j A_i^T x_i - A_j (C_j - C_i) / H`,
A the 2x2 reflection world E, N -> camera x, y). Each pair so gives both images a kappa, independent of how
the camera is mounted or which way the strips are flown; an image's kappa is the circular mean of its pairs'
(weighted by the baseline over the height). Images that share no points with another image with a centre
take the direction of flight between their neighbours in the list (image top forward).
Tie points are then intersected, images without a centre resected through them, and a bundle adjustment with
the centres (and any control) as observations refines the start (`dgcal.bundle.adjustment`).
"""
from __future__ import annotations

import numpy as np

from dgcal.bundle.adjustment import BundleInput, BundleOptions, adjust
from dgcal.bundle.mapper import image_pairs_by_shared_points
from dgcal.bundle.resection import grow_orientation
from dgcal.calib.camera.models import CameraModel

CONTROL_SIGMA_M = 0.05      # control coordinates' weight in the start's adjustment (only the start: m)


def nadir_rotation(alpha: np.ndarray) -> np.ndarray:
    """R_world_to_cam (n,3,3) of nadir cameras (ENU world; camera x right, y down, z down to the ground) whose
    image axes x, y point along world E, N by the reflection angle alpha (rad): x = (cos a, sin a, 0),
    y = (sin a, -cos a, 0) in the world (alpha 0: image top north)."""
    c, s = np.cos(alpha), np.sin(alpha)
    z = np.zeros_like(c)
    return np.stack([np.stack([c, s, z], -1), np.stack([s, -c, z], -1),
                     np.stack([z, z, -np.ones_like(c)], -1)], 1)


def kappa_from_image_motion(camera: CameraModel, C_world: np.ndarray, obs_image: np.ndarray, obs_point: np.ndarray,
                            obs_uv: np.ndarray, min_shared: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Nadir rotations R_world_to_cam (n,3,3) from image motion and known centres C_world (n,3) m, ENU world
    (NaN rows: unknown), and which images got one (n,) bool; see the module docstring."""
    n = len(C_world)
    oi, op = np.asarray(obs_image, int), np.asarray(obs_point, int)
    have_c = np.isfinite(C_world).all(1)
    sel = have_c[oi]
    rows = np.flatnonzero(sel)
    ia, ib, ra, rb = image_pairs_by_shared_points(oi[sel], op[sel], n, min_shared)
    alpha_sum = np.zeros((n, 2))
    if len(ia):
        ra, rb = rows[ra], rows[rb]
        xy = camera.undistort_normalized(np.asarray(obs_uv, float))
        starts = np.flatnonzero(np.r_[True, (ia[1:] != ia[:-1]) | (ib[1:] != ib[:-1])])
        cnt = np.diff(np.r_[starts, len(ia)])
        a, b = ia[starts], ib[starts]
        pa, pb = xy[ra], xy[rb]
        ma = np.add.reduceat(pa, starts) / cnt[:, None]
        mb = np.add.reduceat(pb, starts) / cnt[:, None]
        da, db = pa - np.repeat(ma, cnt, 0), pb - np.repeat(mb, cnt, 0)
        # 2-D similarity x_b = s Rot(theta) x_a + c (least squares, closed form)
        dot = np.add.reduceat(np.sum(da * db, 1), starts)
        crs = np.add.reduceat(da[:, 0] * db[:, 1] - da[:, 1] * db[:, 0], starts)
        theta = np.arctan2(crs, dot)
        s = np.hypot(dot, crs) / np.add.reduceat(np.sum(da * da, 1), starts)
        ct, st = np.cos(theta), np.sin(theta)
        c = mb - s[:, None] * np.column_stack([ct * ma[:, 0] - st * ma[:, 1], st * ma[:, 0] + ct * ma[:, 1]])
        u = C_world[b, :2] - C_world[a, :2]                # baseline E, N (m)
        # a reflection A(alpha) turns a vector at angle phi to alpha - phi: A_b u points along -c
        alpha_b = np.arctan2(-c[:, 1], -c[:, 0]) + np.arctan2(u[:, 1], u[:, 0])
        # A_a = Rot(theta)^T A_b, a reflection at alpha_b - theta
        alpha_a = alpha_b - theta
        # weight: the image shift |c| against a few degrees of unknown tilt; tiny shifts say nothing
        w = np.where(np.hypot(*c.T) > 0.02, np.hypot(*c.T) * np.sqrt(cnt), 0.0)
        for img, al in ((a, alpha_a), (b, alpha_b)):
            np.add.at(alpha_sum, img, w[:, None] * np.column_stack([np.cos(al), np.sin(al)]))
    ok = have_c & (np.hypot(*alpha_sum.T) > 0)
    alpha = np.arctan2(alpha_sum[:, 1], alpha_sum[:, 0])
    # images without a neighbour to compare: the flight direction between the centres before and after them
    for i in np.flatnonzero(have_c & ~ok):
        prev = [j for j in range(i - 1, -1, -1) if have_c[j]][:1]
        nxt = [j for j in range(i + 1, n) if have_c[j]][:1]
        if not prev and not nxt:
            continue
        d = C_world[(nxt or [i])[0], :2] - C_world[(prev or [i])[0], :2]
        if np.hypot(*d) == 0:
            continue
        heading = np.arctan2(d[0], d[1])                      # azimuth from north
        alpha[i] = -heading                                   # image top forward: y = -(flight direction)
        ok[i] = True
    return nadir_rotation(alpha), ok


def orient_from_centres(camera: CameraModel, n_images: int, obs_image: np.ndarray, obs_point: np.ndarray,
                        obs_uv: np.ndarray, X_control: np.ndarray, C_world_prior: np.ndarray,
                        centre_sigma_m: float = 0.5, rounds: int = 3,
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Initial orientation from camera centres (n,3, world m, NaN where unknown): nadir poses with kappa from
    image motion, growth to the images without a centre, then a bundle adjustment with the centres as
    observations (sigma `centre_sigma_m`) and control (5 cm), repeated while more images join.
    Returns (R_world_to_cam, C_world, oriented, X_world, point_ok, notes)."""
    oi, op = np.asarray(obs_image, int), np.asarray(obs_point, int)
    C_prior = np.asarray(C_world_prior, float)
    R0, ok = kappa_from_image_motion(camera, C_prior, oi, op, obs_uv)
    notes = [f"{int(ok.sum())} image(s) started from their camera centres with kappa from image motion "
             "(omega = phi = 0)"]
    R0 = np.where(ok[:, None, None], R0, np.nan)
    C0 = np.where(ok[:, None], C_prior, np.nan)
    R, C, oriented, X, point_ok = grow_orientation(camera, n_images, oi, op, obs_uv, X_control, R0, C0)
    for _ in range(rounds):
        before = int(oriented.sum())
        R, C, X, solved = adjust_start(camera, R, C, oriented, X, point_ok, oi, op, obs_uv, X_control, C_prior,
                                       centre_sigma_m)
        if not solved:
            notes.append("the bundle adjustment of the start from camera centres did not converge")
        R0 = np.where(oriented[:, None, None], R, np.nan)
        C0 = np.where(oriented[:, None], C, np.nan)
        Xk = np.where(point_ok[:, None], X, X_control)
        R, C, oriented, X_grown, ok_grown = grow_orientation(camera, n_images, oi, op, obs_uv, Xk, R0, C0)
        X = np.where(point_ok[:, None], X, X_grown)
        point_ok = point_ok | ok_grown
        if int(oriented.sum()) == before:
            break
    return R, C, oriented, X, point_ok, notes


def adjust_start(camera: CameraModel, R: np.ndarray, C: np.ndarray, oriented: np.ndarray, X: np.ndarray,
                 point_ok: np.ndarray, oi: np.ndarray, op: np.ndarray, uv: np.ndarray, X_control: np.ndarray,
                 C_prior: np.ndarray | None = None, centre_sigma_m: float = 0.5,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """One robust bundle adjustment (Huber, 1 px) of the oriented images of a start and the points they see
    (2+ rays, or control at 5 cm), with centres (n,3, NaN none) as observations if given: the refined
    (R_world_to_cam, C_world, X_world) and whether it converged. Unchanged when nothing fixes the datum
    (fewer than 3 control points seen and no centres)."""
    known = np.isfinite(X_control).all(1)
    use = oriented[oi] & point_ok[op]
    cnt = np.bincount(op[use], minlength=len(X))
    use &= (cnt[op] >= 2) | known[op]
    img = np.flatnonzero(oriented & (np.bincount(oi[use], minlength=len(R)) > 0))
    pts = np.flatnonzero(np.bincount(op[use], minlength=len(X)) > 0)
    im_map = -np.ones(len(R), int)
    im_map[img] = np.arange(len(img))
    pt_map = -np.ones(len(X), int)
    pt_map[pts] = np.arange(len(pts))
    use &= im_map[oi] >= 0
    k = np.flatnonzero(use)
    has_centres = C_prior is not None and np.isfinite(C_prior[img]).all(1).sum() >= 3
    if not len(img) or (known[pts].sum() < 3 and not has_centres):
        return R, C, X, False
    prior = np.where(known[pts, None], X_control[pts], np.nan)
    inp = BundleInput(camera, [str(i) for i in img], R[img], C[img], [str(j) for j in pts], X[pts], im_map[oi[k]],
                      pt_map[op[k]], np.asarray(uv, float)[k], np.ones((len(k), 2)), prior,
                      np.full((len(pts), 3), CONTROL_SIGMA_M), None if C_prior is None else C_prior[img],
                      None if C_prior is None else np.full((len(img), 3), centre_sigma_m))
    try:
        res = adjust(inp, BundleOptions(loss="huber", loss_scale=3.0, max_iterations=40, aposteriori=False))
    except np.linalg.LinAlgError:
        return R, C, X, False     # a datum the control does not fix after all (points in a line)
    R, C, X = R.copy(), C.copy(), X.copy()
    R[img], C[img], X[pts] = res.R_world_to_cam, res.C_world, res.X_world
    return R, C, X, bool(res.converged)
