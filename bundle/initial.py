"""The initial orientation of a block, in the world frame of the adjustment, from whatever it offers.

1. Approximate EOPs (from a previous run, or a POS with a nominal mounting): those images start oriented;
   the others are resected through the tie points triangulated from them.
2. Camera centres without angles (GNSS/RTK priors, approximate EOPs without rotations): nadir poses with kappa
   from image motion, refined by a bundle adjustment on the centres (`dgcal.bundle.centre_start`).
3. Otherwise pycolmap's incremental mapper orients the block from its measurements alone
   (`dgcal.bundle.mapper`), first on a thinned set of observations (the longest tracks, and every control
   point), again on all of them when that start leaves connected images out, breaks into several models or
   disagrees with control. Every point a model's images see is intersected in the model's frame, and the model
   is moved onto the control points by a robust 3-D similarity (RANSAC over triples, then least squares on
   the inliers: a wrong control coordinate does not tilt the block); a model with too little control joins
   the placed ones through the tie points they share. The better attempt is kept (more images, fewer models,
   closer to control). Images the mapper leaves out are resected through the points, repeatedly.
4. If the mapper finds nothing (too few tie points), images are resected from the control points and grown
   through the tie points in the world frame (`dgcal.bundle.resection.grow_orientation`), or a relative
   orientation is scaled onto the control points, whichever orients more images. The adjustment refines the
   result and retries the images left out (`dgcal.bundle.triangulation`).
COLMAP's own log lines are kept in the notes, off the console.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dgcal.bundle.centre_start import adjust_start, orient_from_centres
from dgcal.bundle.mapper import orient_by_mapper
from dgcal.bundle.resection import (grow_orientation, relative_bootstrap, resect_by_relative_orientation,
                                    similarity_umeyama, triangulate_tracks)
from dgcal.calib.camera.models import CameraModel


MAPPER_PER_IMAGE = 150     # observations per image of the mapper's thinned first attempt (longest tracks)


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


def connected_images(obs_image: np.ndarray, obs_point: np.ndarray, n_images: int, min_shared: int = 10) -> np.ndarray:
    """Images with >= `min_shared` observations of points that other images see too; (n,) bool."""
    n_img = np.bincount(obs_point)
    shared = n_img[obs_point] >= 2
    return np.bincount(obs_image[shared], minlength=n_images) >= min_shared


def model_points(rays_cam: np.ndarray, oi: np.ndarray, op: np.ndarray, m: int, R_model_to_cam: np.ndarray,
                 C_model: np.ndarray, registered: np.ndarray, min_angle_deg: float = 1.0) -> np.ndarray:
    """Every point seen by two or more registered images, intersected in the model's frame from all its rays
    (the mapper triangulates only the points it was given: control too must reach the model); (m,3), NaN
    where fewer rays, too narrow an angle or behind a camera."""
    X = np.full((m, 3), np.nan)
    sel = registered[oi]
    cnt = np.bincount(op[sel], minlength=m)
    sel &= cnt[op] >= 2
    if not sel.any():
        return X
    ks = np.flatnonzero(sel)[np.argsort(op[sel], kind="stable")]
    pts, starts = np.unique(op[ks], return_index=True)
    Xp, ang, front = triangulate_tracks(C_model[oi[ks]], R_model_to_cam[oi[ks]], rays_cam[ks], starts)
    ok = (ang >= min_angle_deg) & front
    X[pts[ok]] = Xp[ok]
    return X


@dataclass
class PlacedModels:
    """Mapper models moved into the world: poses of the images they oriented, points, control residuals."""

    R_world_to_cam: np.ndarray
    C_world: np.ndarray
    oriented: np.ndarray
    X_world: np.ndarray
    n_models: int
    n_unplaced: int
    control_rms_m: float
    n_control_outliers: int
    n_control_used: int
    notes: list[str]

    def score(self) -> tuple:
        """Better: more images oriented, fewer pieces, closer to control."""
        return int(self.oriented.sum()), -self.n_unplaced, -self.n_models, -self.control_rms_m


def place_models(models: list, rays_cam: np.ndarray, oi: np.ndarray, op: np.ndarray, X_control: np.ndarray,
                 control_tol_m: float, label: str) -> PlacedModels:
    """Each model (`MapperResult.models`: poses in its own frame, -, registered) onto the control points
    (world, m; NaN for ties) it intersects from `rays_cam` (camera-frame rays of the observations) by a robust
    similarity; a model with too little control joins the models already placed through the tie points both
    intersect; largest model first (the mapper's order)."""
    n, m = len(models[0][0].C_world), len(X_control)
    R_world_to_cam = np.tile(np.eye(3), (n, 1, 1))
    C_world = np.zeros((n, 3))
    oriented = np.zeros(n, bool)
    X_world = np.full((m, 3), np.nan)
    known = np.isfinite(X_control).all(1)
    notes: list[str] = []
    res_ctrl: list[np.ndarray] = []
    n_out = n_used = 0
    pending = []
    for k, (poses, _Xm, reg) in enumerate(models):
        Xm = model_points(rays_cam, oi, op, m, poses.R_world_to_cam, poses.C_world, reg)
        pairs = known & np.isfinite(Xm).all(1)
        sim = robust_similarity(Xm[pairs], X_control[pairs], control_tol_m) if pairs.sum() >= 3 else None
        if sim is None:
            pending.append((k, poses, Xm, reg, int(pairs.sum())))
            continue
        s, R_model_to_world, t, inl = sim
        n_used += int(pairs.sum())
        err = np.linalg.norm(s * Xm[pairs] @ R_model_to_world.T + t - X_control[pairs], axis=1)
        res_ctrl.append(err[inl])
        if (~inl).any():
            n_out += int((~inl).sum())
            notes.append(f"{int((~inl).sum())} control point(s) off the similarity of {label} model {k + 1} by "
                         f"more than {control_tol_m:g} m: left out of its datum")
        _take(poses, Xm, reg, s, R_model_to_world, t, R_world_to_cam, C_world, oriented, X_world)
    progress = True
    while pending and progress:      # models without their own datum: through the ties of those placed
        progress = False
        for item in list(pending):
            k, poses, Xm, reg, n_ctrl = item
            common = ~known & np.isfinite(Xm).all(1) & np.isfinite(X_world).all(1)
            if common.sum() < 10:
                continue
            # tie points of two separately placed models agree to a few control tolerances at best
            sim = robust_similarity(Xm[common], X_world[common], 3 * control_tol_m)
            if sim is None or sim[3].sum() < 10:
                continue
            s, R_model_to_world, t, inl = sim
            _take(poses, Xm, reg, s, R_model_to_world, t, R_world_to_cam, C_world, oriented, X_world)
            notes.append(f"{label} model {k + 1} ({int(reg.sum())} images, {n_ctrl} control point(s)) joined "
                         f"through {int(inl.sum())} tie points shared with the models on control")
            pending.remove(item)
            progress = True
    for k, _poses, _Xm, reg, n_ctrl in pending:
        notes.append(f"{label} model {k + 1} ({int(reg.sum())} images) has {n_ctrl} control point(s) usable "
                     "for its datum and no tie points shared with the others: left out")
    X_world[known] = X_control[known]
    rms = float(np.sqrt(np.mean(np.concatenate(res_ctrl) ** 2))) if res_ctrl else float("inf")
    return PlacedModels(R_world_to_cam, C_world, oriented, X_world, len(models), len(pending), rms, n_out, n_used,
                        notes)


def _take(poses, Xm, reg, s, R_model_to_world, t, R_world_to_cam, C_world, oriented, X_world) -> None:
    """Images of a model not yet oriented, and points not yet known, moved into the world by (s, R, t)."""
    take = reg & ~oriented
    C_world[take] = s * poses.C_world[take] @ R_model_to_world.T + t
    R_world_to_cam[take] = poses.R_world_to_cam[take] @ R_model_to_world.T
    oriented |= take
    X_model_in_world = s * Xm @ R_model_to_world.T + t
    fill = np.isfinite(X_model_in_world).all(1) & ~np.isfinite(X_world).all(1)
    X_world[fill] = X_model_in_world[fill]


def _from_mapper(camera, names, oi, op, uv, X_control, control_tol_m, notes, seconds) -> InitialOrientation | None:
    """The mapper on a thinned set of observations (control always whole); again on all of them when the
    thinned start leaves connected images out, breaks into several models, or disagrees with control."""
    n, m = len(names), len(X_control)
    known = np.isfinite(X_control).all(1)
    rays_cam = camera.ray(uv)
    connected = connected_images(oi, op, n)
    attempts: list[PlacedModels] = []
    for label, per_image in (("mapper", MAPPER_PER_IMAGE), ("mapper (all points)", None)):
        res = orient_by_mapper(camera, names, oi, op, uv, m, per_image=per_image, keep_points=known)
        tag = "mapper" if per_image else "mapper_all"
        seconds.update({f"{tag}_{k}": round(v, 3) for k, v in res.seconds.items()})
        # COLMAP's errors and warnings (glog: "E1207 ...", "W1207 ..."), kept in the notes, off the console
        notes.extend(f"COLMAP ({label}): {line}" for line in res.log if line[0] in "EWF")
        if not res.models:
            notes.append(f"the incremental {label} found no model ({res.n_verified_pairs} verified image pairs)")
        else:
            placed = place_models(res.models, rays_cam, oi, op, X_control, control_tol_m, label)
            attempts.append(placed)
            # one model, on control (a few control blunders aside: more than a third off is the model's fault,
            # as are residuals of half the tolerance), missing at most 5 % of the connected images (resected next)
            missing = int((connected & ~placed.oriented).sum())
            good = (placed.n_models == 1 and 3 * placed.n_control_outliers <= placed.n_control_used
                    and placed.control_rms_m <= 0.5 * control_tol_m and missing <= max(1, 0.05 * connected.sum()))
            if good:
                break
        if per_image is None or res.n_observations == len(oi):
            break      # the thinned run was given everything already
        why = "no model" if not res.models else (
            f"{placed.n_models} models, {int(placed.oriented[connected].sum())} of {int(connected.sum())} connected "
            f"images placed, control residuals {placed.control_rms_m:.2f} m RMS, {placed.n_control_outliers} of "
            f"{placed.n_control_used} control points off")
        notes.append(f"the incremental mapper on the thinned observations gave {why}: again with all points")
    if not attempts:
        return None
    best = max(attempts, key=PlacedModels.score)
    notes.extend(best.notes)
    if not best.oriented.any():
        return None
    return InitialOrientation(best.R_world_to_cam, best.C_world, best.oriented, best.X_world,
                              np.isfinite(best.X_world).all(1), "mapper", notes, seconds)


def initial_orientation(camera: CameraModel, image_names: list[str], obs_image: np.ndarray, obs_point: np.ndarray,
                        obs_uv: np.ndarray, X_control: np.ndarray, R0: np.ndarray | None = None,
                        C0: np.ndarray | None = None, control_tol_m: float = 2.0,
                        use_mapper: bool = True, *, C_world_prior: np.ndarray | None = None,
                        centre_sigma_m: float = 0.5) -> InitialOrientation:
    """Initial poses and points of a block (world frame, m): see the module docstring.

    X_control (m,3): control coordinates (NaN for tie points); R0, C0: approximate poses (NaN where unknown).
    C_world_prior (n,3): camera centres known without angles (GNSS/RTK; NaN rows where unknown): the block
    starts from them with kappa from image motion (`dgcal.bundle.centre_start`, sigma `centre_sigma_m` in its
    adjustment); approximate centres C0 without rotations R0 are taken the same way."""
    import time
    n = len(image_names)
    oi, op = np.asarray(obs_image, int), np.asarray(obs_point, int)
    notes: list[str] = []
    seconds: dict = {}
    t0 = time.perf_counter()
    has_approx = (R0 is not None and C0 is not None and (np.isfinite(np.asarray(C0)).all(1)
                                                         & np.isfinite(np.asarray(R0)).all((1, 2))).any())
    if has_approx:
        R, C, ok, X, okp = grow_orientation(camera, n, oi, op, obs_uv, X_control, R0, C0)
        seconds["growth"] = round(time.perf_counter() - t0, 3)
        return InitialOrientation(R, C, ok, X, okp, "approximate EOPs", notes, seconds)
    if C_world_prior is None and C0 is not None:
        C_world_prior = C0     # centres without angles
    if C_world_prior is not None and np.isfinite(np.asarray(C_world_prior, float)).all(1).any():
        R, C, ok, X, okp, more = orient_from_centres(camera, n, oi, op, obs_uv, X_control, C_world_prior,
                                                     centre_sigma_m)
        notes.extend(more)
        seconds["centre_start"] = round(time.perf_counter() - t0, 3)
        return InitialOrientation(R, C, ok, X, okp, "camera centres and kappa from image motion", notes, seconds)
    mapped = _from_mapper(camera, image_names, oi, op, obs_uv, X_control, control_tol_m, notes, seconds) \
        if use_mapper else None
    seconds["mapper"] = round(time.perf_counter() - t0, 3)
    t1 = time.perf_counter()
    if mapped is not None:
        # images the mapper left out: resected through the points it triangulated, growing from its poses
        R0 = np.where(mapped.oriented[:, None, None], mapped.R_world_to_cam, np.nan)
        C0 = np.where(mapped.oriented[:, None], mapped.C_world, np.nan)
        X_known = np.where(mapped.point_ok[:, None], mapped.X_world, X_control)
        R, C, ok, X, okp, more = reach_leftovers(camera, n, oi, op, obs_uv, X_known, R0, C0, X_control)
        if more:
            notes.append(f"{more} image(s) the mapper left out resected through its points")
        seconds["growth"] = round(time.perf_counter() - t1, 3)
        return InitialOrientation(R, C, ok, X, okp, "incremental mapper", notes, seconds)
    candidates = []
    R, C, ok, X, okp = grow_orientation(camera, n, oi, op, obs_uv, X_control)
    candidates.append(InitialOrientation(R, C, ok, X, okp, "resection and growth from control", notes, seconds))
    if not ok[np.unique(oi)].all():
        boot = relative_bootstrap(camera, n, oi, op, obs_uv, X_control)
        if boot is not None:
            candidates.append(InitialOrientation(*boot, "relative orientation scaled onto control", notes, seconds))
    best = max(candidates, key=lambda c: int(c.oriented.sum()))
    if best.oriented.any() and not best.oriented[connected_images(oi, op, n)].all():
        X_known = np.where(best.point_ok[:, None], best.X_world, X_control)
        R, C, ok, X, okp, more = reach_leftovers(
            camera, n, oi, op, obs_uv, X_known, np.where(best.oriented[:, None, None], best.R_world_to_cam, np.nan),
            np.where(best.oriented[:, None], best.C_world, np.nan), X_control)
        if more:
            notes.append(f"{more} image(s) joined through the points of the oriented ones or their relative "
                         "orientations to them")
            best = InitialOrientation(R, C, ok, X, okp, best.method, notes, seconds)
    seconds["growth"] = round(time.perf_counter() - t1, 3)
    best.notes, best.seconds = notes, seconds
    return best


def reach_leftovers(camera: CameraModel, n: int, oi: np.ndarray, op: np.ndarray, uv: np.ndarray,
                    X_known: np.ndarray, R0: np.ndarray, C0: np.ndarray, X_control: np.ndarray, rounds: int = 50):
    """Images not yet oriented, joined until none joins: resected (PnP) through the points intersected from the
    oriented ones (`grow_orientation`), and, where too few points are known (ties seen in two images only), from
    the relative orientations to two or more oriented neighbours, then all adjusted on the control points
    `X_control` (`dgcal.bundle.centre_start.adjust_start`). `X_known` (m,3) world points (NaN unknown),
    R0, C0 the oriented images' poses (NaN elsewhere). Returns (R_world_to_cam, C_world, oriented, X, point_ok,
    number of images joined)."""
    start = np.isfinite(C0).all(1) & np.isfinite(R0).all((1, 2))
    connected = connected_images(oi, op, n)
    tried_at: dict[int, int] = {}
    for _ in range(rounds):
        R, C, ok, X, okp = grow_orientation(camera, n, oi, op, uv, X_known, R0, C0)
        X = np.where(np.isfinite(X_known).all(1)[:, None], X_known, X)
        joined = False
        for i in np.flatnonzero(connected & ~ok):
            if tried_at.get(int(i)) == int(ok.sum()):
                continue     # nothing new around it since the last try
            tried_at[int(i)] = int(ok.sum())
            got = resect_by_relative_orientation(camera, int(i), R, C, ok, oi, op, uv)
            if got is not None:
                R[i], C[i] = got
                ok[i] = joined = True
        if joined:
            # chains of relative orientations drift: adjust what is oriented before growing from it
            R, C, X, _ = adjust_start(camera, R, C, ok, X, np.isfinite(X).all(1), oi, op, uv, X_control)
        R0 = np.where(ok[:, None, None], R, np.nan)
        C0 = np.where(ok[:, None], C, np.nan)
        X_known = np.where(np.isfinite(X).all(1)[:, None], X, X_known)
        if not joined:
            break
    return R, C, ok, X, np.isfinite(X).all(1), int(ok.sum() - start.sum())
