"""The initial orientation of a block, in the world frame of the adjustment, from whatever it offers.

1. Approximate EOPs (from a previous run, or a POS with a nominal mounting): those images start oriented;
   the others are resected through the tie points triangulated from them.
2. Otherwise pycolmap's incremental mapper orients the block from its measurements alone
   (`dgcal.bundle.mapper`); each model it returns is moved onto the control points it triangulated by a
   robust 3-D similarity (RANSAC over triples, then least squares on the inliers: a wrong control
   coordinate does not tilt the block).
   Images the mapper leaves out are resected through the points it triangulated.
3. If the mapper finds nothing (too few tie points), images are resected from the control points and grown
   through the tie points in the world frame (`dgcal.bundle.resection.grow_orientation`), or a relative
   orientation is scaled onto the control points, whichever orients more images. The adjustment refines the
   result and retries the images left out (`dgcal.bundle.triangulation`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dgcal.bundle.mapper import orient_by_mapper
from dgcal.bundle.resection import grow_orientation, relative_bootstrap, similarity_umeyama
from dgcal.calib.camera.models import CameraModel


@dataclass
class InitialOrientation:
    """Initial poses (R_world_to_cam, C_world; meaningful where `oriented`) and points (where `point_ok`)."""

    R_world_to_cam: np.ndarray
    C_world: np.ndarray
    oriented: np.ndarray
    X_world: np.ndarray
    point_ok: np.ndarray
    method: str
    notes: list[str] = field(default_factory=list)
    seconds: dict = field(default_factory=dict)


def robust_similarity(src: np.ndarray, dst: np.ndarray, tol: float, rng: np.random.Generator | None = None,
                      trials: int = 300) -> tuple[float, np.ndarray, np.ndarray, np.ndarray] | None:
    """Scale, rotation, translation with dst ~ s R src + t from point pairs with outliers: RANSAC over triples
    (inlier when the transformed point is within `tol` of its target, m), least squares on the inliers.
    Returns (s, R, t, inlier mask) or None with fewer than 3 non-collinear pairs."""
    k = len(src)
    if k < 3:
        return None
    rng = rng or np.random.default_rng(0)
    best = None
    combos = [tuple(rng.choice(k, 3, replace=False)) for _ in range(trials)] if k > 6 else \
        [(a, b, c) for a in range(k) for b in range(a + 1, k) for c in range(b + 1, k)]
    for tri in combos:
        idx = np.array(tri)
        d = dst[idx] - dst[idx].mean(0)
        if np.linalg.svd(d, compute_uv=False)[1] < 1e-3 * max(np.linalg.norm(d), 1e-9):
            continue   # collinear triple
        s, R, t = similarity_umeyama(src[idx], dst[idx])
        err = np.linalg.norm(s * src @ R.T + t - dst, axis=1)
        inl = err < tol
        score = (inl.sum(), -np.sum(np.minimum(err, tol) ** 2))
        if best is None or score > best[0]:
            best = (score, inl)
    if best is None or best[1].sum() < 3:
        return None
    inl = best[1]
    for _ in range(3):   # least squares on the inliers, then re-select them once the fit settles
        s, R, t = similarity_umeyama(src[inl], dst[inl])
        err = np.linalg.norm(s * src @ R.T + t - dst, axis=1)
        new = err < tol
        if new.sum() < 3 or np.array_equal(new, inl):
            break
        inl = new
    return s, R, t, inl


def _from_mapper(camera, names, oi, op, uv, X_control, control_tol_m, notes, seconds) -> InitialOrientation | None:
    n, m = len(names), len(X_control)
    res = orient_by_mapper(camera, names, oi, op, uv, m)
    seconds.update({f"mapper_{k}": round(v, 3) for k, v in res.seconds.items()})
    if not res.models:
        notes.append(f"the incremental mapper found no model ({res.n_verified_pairs} verified image pairs)")
        return None
    R_world_to_cam = np.tile(np.eye(3), (n, 1, 1))
    C_world = np.zeros((n, 3))
    oriented = np.zeros(n, bool)
    X = np.full((m, 3), np.nan)
    known = np.isfinite(X_control).all(1)
    for k, (poses, Xm, reg) in enumerate(res.models):
        pairs = known & np.isfinite(Xm).all(1)
        sim = robust_similarity(Xm[pairs], X_control[pairs], control_tol_m) if pairs.sum() >= 3 else None
        if sim is None:
            notes.append(f"mapper model {k + 1} ({int(reg.sum())} images) has {int(pairs.sum())} control point(s) "
                         "usable for its datum: left out")
            continue
        s, R_model_to_world, t, inl = sim
        if (~inl).any():
            bad = np.flatnonzero(pairs)[~inl]
            notes.append(f"{len(bad)} control point(s) off the similarity of mapper model {k + 1} by more than "
                         f"{control_tol_m:g} m: left out of its datum")
        take = reg & ~oriented
        C_world[take] = s * poses.C_world[take] @ R_model_to_world.T + t
        R_world_to_cam[take] = poses.R_world_to_cam[take] @ R_model_to_world.T
        oriented |= take
        X_model_in_world = s * Xm @ R_model_to_world.T + t
        fill = np.isfinite(X_model_in_world).all(1) & ~np.isfinite(X).all(1)
        X[fill] = X_model_in_world[fill]
    if not oriented.any():
        return None
    X[known] = X_control[known]
    return InitialOrientation(R_world_to_cam, C_world, oriented, X, np.isfinite(X).all(1), "mapper", notes, seconds)


def initial_orientation(camera: CameraModel, image_names: list[str], obs_image: np.ndarray, obs_point: np.ndarray,
                        obs_uv: np.ndarray, X_control: np.ndarray, R0: np.ndarray | None = None,
                        C0: np.ndarray | None = None, control_tol_m: float = 2.0,
                        use_mapper: bool = True) -> InitialOrientation:
    """Initial poses and points of a block (world frame, m): see the module docstring.

    X_control (m,3): control coordinates (NaN for tie points); R0, C0: approximate poses (NaN where unknown)."""
    import time
    n = len(image_names)
    oi, op = np.asarray(obs_image, int), np.asarray(obs_point, int)
    notes: list[str] = []
    seconds: dict = {}
    t0 = time.perf_counter()
    has_approx = R0 is not None and C0 is not None and np.isfinite(np.asarray(C0)).all(1).any()
    if has_approx:
        R, C, ok, X, okp = grow_orientation(camera, n, oi, op, obs_uv, X_control, R0, C0)
        return InitialOrientation(R, C, ok, X, okp, "approximate EOPs", notes, seconds)
    mapped = _from_mapper(camera, image_names, oi, op, obs_uv, X_control, control_tol_m, notes, seconds) \
        if use_mapper else None
    seconds["mapper"] = round(time.perf_counter() - t0, 3)
    t1 = time.perf_counter()
    if mapped is not None:
        # images the mapper left out: resected through the points it triangulated, growing from its poses
        R0 = np.where(mapped.oriented[:, None, None], mapped.R_world_to_cam, np.nan)
        C0 = np.where(mapped.oriented[:, None], mapped.C_world, np.nan)
        R, C, ok, X, okp = grow_orientation(camera, n, oi, op, obs_uv, X_control, R0, C0)
        more = int(ok.sum() - mapped.oriented.sum())
        if more:
            notes.append(f"{more} image(s) the mapper left out resected through its points")
        X = np.where(mapped.point_ok[:, None], mapped.X_world, X)
        seconds["growth"] = round(time.perf_counter() - t1, 3)
        return InitialOrientation(R, C, ok, X, np.isfinite(X).all(1), "incremental mapper", notes, seconds)
    candidates = []
    R, C, ok, X, okp = grow_orientation(camera, n, oi, op, obs_uv, X_control)
    candidates.append(InitialOrientation(R, C, ok, X, okp, "resection and growth from control", notes, seconds))
    if not ok[np.unique(oi)].all():
        boot = relative_bootstrap(camera, n, oi, op, obs_uv, X_control)
        if boot is not None:
            candidates.append(InitialOrientation(*boot, "relative orientation scaled onto control", notes, seconds))
    seconds["growth"] = round(time.perf_counter() - t1, 3)
    best = max(candidates, key=lambda c: int(c.oriented.sum()))
    best.notes, best.seconds = notes, seconds
    return best
