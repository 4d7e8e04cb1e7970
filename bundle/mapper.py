"""Initial orientation by pycolmap's incremental mapper, fed with dgcal's image measurements.

The measurements become COLMAP keypoints (undistorted through the known camera onto an ideal PINHOLE
camera, so any dgcal camera model is exact) and every pair of images that shares points becomes a match
list; COLMAP verifies the pairs geometrically and grows the block with its local and global bundle
adjustments, retriangulation and retries (what a hand-written incremental start does not survive on long
strips). The result is in COLMAP's arbitrary frame: poses (`dgcal.fields.pose` convention) and the points
it triangulated, by dgcal point index. `dgcal.bundle.initial` moves it onto the control points.

Pixels: COLMAP's origin is the top-left pixel's corner, dgcal's that pixel's centre (+0.5 px at this boundary).
"""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dgcal.calib.camera.models import CameraModel
from dgcal.fields.pose import Poses

COLMAP_PIXEL_SHIFT = 0.5


@dataclass
class MapperResult:
    """Models found by the mapper, each in its own frame: poses of its images (NaN elsewhere) and points."""

    models: list[tuple[Poses, np.ndarray, np.ndarray]] = field(default_factory=list)   # (poses, X (m,3), registered)
    n_verified_pairs: int = 0
    seconds: dict = field(default_factory=dict)
    log: list[str] = field(default_factory=list)    # COLMAP's own log lines (kept off the console)
    n_observations: int = 0                         # observations the mapper was given


@contextlib.contextmanager
def captured_stderr(lines: list[str]):
    """Run a block with file descriptor 2 sent to a temporary file (glog, which COLMAP logs through, writes
    there directly, past `sys.stderr`); its text is appended to `lines`, one entry per line."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield lines
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            lines.extend(t for t in tmp.read().decode(errors="replace").splitlines() if t.strip())


def image_pairs_by_shared_points(obs_image: np.ndarray, obs_point: np.ndarray, n_images: int,
                                 min_shared: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All matches implied by shared point ids: (image a, image b, row in a, row in b) with a < b, sorted by
    pair. Rows index the observations; pairs with fewer than `min_shared` matches are dropped."""
    order = np.lexsort((obs_image, obs_point))
    pt, im = obs_point[order], obs_image[order]
    starts = np.flatnonzero(np.r_[True, pt[1:] != pt[:-1]])
    lengths = np.diff(np.r_[starts, len(pt)])
    L = np.repeat(lengths, lengths)
    first = np.repeat(starts, lengths)
    pos = np.arange(len(pt)) - first                       # position within its track
    n_after = L - pos - 1                                  # partners after it in the track
    u = np.repeat(np.arange(len(pt)), n_after)
    v = u + 1 + (np.arange(len(u)) - np.repeat(np.cumsum(n_after) - n_after, n_after))
    ia, ib = im[u], im[v]
    keep = ia != ib                                        # one image measuring a point twice: no match
    ra, rb, ia, ib = order[u][keep], order[v][keep], ia[keep], ib[keep]
    swap = ia > ib
    ia, ib = np.where(swap, ib, ia), np.where(swap, ia, ib)
    ra, rb = np.where(swap, rb, ra), np.where(swap, ra, rb)
    key = ia.astype(np.int64) * n_images + ib
    o = np.argsort(key, kind="stable")
    ia, ib, ra, rb, key = ia[o], ib[o], ra[o], rb[o], key[o]
    if min_shared > 1:
        uk, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
        ok = cnt[inv] >= min_shared
        ia, ib, ra, rb = ia[ok], ib[ok], ra[ok], rb[ok]
    return ia, ib, ra, rb


def _strong_subset(oi: np.ndarray, op: np.ndarray, n_images: int, n_points: int, per_image: int,
                   keep_points: np.ndarray | None = None) -> np.ndarray:
    """Observations of the points taken, longest tracks first, while an image they see still has fewer than
    `per_image` taken observations, and all observations of `keep_points` (m,) bool; (k,) bool."""
    L = np.bincount(op, minlength=n_points)
    by_point = np.argsort(op, kind="stable")
    starts = np.concatenate([[0], np.cumsum(L)])
    have = np.zeros(n_images, int)
    take = np.zeros(n_points, bool)
    for j in np.argsort(-L, kind="stable"):
        imgs = oi[by_point[starts[j]:starts[j + 1]]]
        if len(imgs) and have[imgs].min() < per_image:
            take[j] = True
            have[imgs] += 1
    if keep_points is not None:
        take |= keep_points
    return take[op]


def orient_by_mapper(camera: CameraModel, image_names: list[str], obs_image: np.ndarray, obs_point: np.ndarray,
                     obs_uv: np.ndarray, n_points: int, *, min_matches: int = 8, num_threads: int = 1,
                     verify: bool = False, per_image: int | None = 150, keep_points: np.ndarray | None = None,
                     workdir: str | Path | None = None) -> MapperResult:
    """Orient a block from its measurements alone (no control, no approximate EOPs) with pycolmap's mapper.

    The mapper is given the points of the longest tracks until every image has `per_image` of them (all
    points when there are fewer): its cost grows with the observations, and an initial orientation needs
    no more; the adjustment that follows uses them all. With a fixed seed and one thread (the default) the
    mapper's answer, and so the triangulation's last digits, are the same in every run (two threads: about
    8 % faster on a 128-image block, but the start, and the adjustment's last digits, vary run to run).
    `per_image` None gives it every observation; `keep_points` (m,) bool: points always given whole (control:
    the model needs them to be moved onto the world). COLMAP's log lines go to `MapperResult.log`."""
    import pycolmap   # deferred: heavy, and only this step needs it
    import time
    pycolmap.logging.minloglevel = 2
    clock = time.perf_counter()
    n = len(image_names)
    oi, op = np.asarray(obs_image, int), np.asarray(obs_point, int)
    K = camera.pinhole_K()
    with np.errstate(all="ignore"):
        uv_ideal = camera.undistort_normalized(np.asarray(obs_uv, float)) @ K[:2, :2].T + K[:2, 2]
    good = np.isfinite(uv_ideal).all(1)
    # keypoint index of each observation within its image
    kp = np.zeros(len(oi), int)
    order = np.argsort(oi, kind="stable")
    counts = np.bincount(oi, minlength=n)
    kp[order] = np.arange(len(oi)) - np.repeat(np.cumsum(counts) - counts, counts)
    if per_image is not None:
        good &= _strong_subset(oi, op, n, n_points, per_image, keep_points)
    ia, ib, ra, rb = image_pairs_by_shared_points(oi[good], op[good], n, min_matches)
    rows_good = np.flatnonzero(good)
    ra, rb = rows_good[ra], rows_good[rb]
    result = MapperResult(n_observations=int(good.sum()))
    with tempfile.TemporaryDirectory(dir=workdir, prefix="dgcal-mapper-") as tmp:
        tmp = Path(tmp)
        db_path = tmp / "db.sqlite"
        with pycolmap.Database.open(db_path) as db:
            cam = pycolmap.Camera(model="PINHOLE", width=int(camera.image_size[0]), height=int(camera.image_size[1]),
                                  params=[K[0, 0], K[1, 1], K[0, 2] + COLMAP_PIXEL_SHIFT, K[1, 2] + COLMAP_PIXEL_SHIFT])
            cid = db.write_camera(cam)
            ids = []
            for i, name in enumerate(image_names):
                ids.append(db.write_image(pycolmap.Image(name=str(name), camera_id=cid)))
                rows = order[np.cumsum(counts)[i] - counts[i]:np.cumsum(counts)[i]]
                xy = np.where(np.isfinite(uv_ideal[rows]), uv_ideal[rows], -1e6) + COLMAP_PIXEL_SHIFT
                db.write_keypoints(ids[-1], np.ascontiguousarray(xy, np.float32))
            starts = np.flatnonzero(np.r_[True, (ia[1:] != ia[:-1]) | (ib[1:] != ib[:-1])]) if len(ia) else []
            ends = np.r_[starts[1:], len(ia)] if len(ia) else []
            lines = []
            for s0, s1 in zip(starts, ends):
                a, b = int(ia[s0]), int(ib[s0])
                db.write_matches(ids[a], ids[b], np.column_stack([kp[ra[s0:s1]], kp[rb[s0:s1]]]).astype(np.uint32))
                lines.append(f"{image_names[a]} {image_names[b]}\n")
        (tmp / "pairs.txt").write_text("".join(lines))
        result.seconds["database"] = time.perf_counter() - clock
        if verify:
            tvo = pycolmap.TwoViewGeometryOptions()
            tvo.min_num_inliers = min_matches
            # measured correspondences are nearly outlier-free: RANSAC ends after a few trials (its default
            # floor of 100 trials per model and pair costs more than the mapping of a 300-image block)
            tvo.ransac.min_num_trials = 20
            with captured_stderr(result.log):
                pycolmap.verify_matches(db_path, tmp / "pairs.txt", tvo)
        else:
            # the ids make the matches: every pair is taken as calibrated two-view geometry, and the mapper's
            # own robust estimation (initial pair, absolute poses, triangulation filters) meets any blunder
            with pycolmap.Database.open(db_path) as db:
                for s0, s1 in zip(starts, ends):
                    tvg = pycolmap.TwoViewGeometry()
                    tvg.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
                    tvg.inlier_matches = np.column_stack([kp[ra[s0:s1]], kp[rb[s0:s1]]]).astype(np.uint32)
                    db.write_two_view_geometry(ids[int(ia[s0])], ids[int(ib[s0])], tvg)
        with pycolmap.Database.open(db_path) as db:
            result.n_verified_pairs = int(db.num_verified_image_pairs())
        result.seconds["verification"] = time.perf_counter() - clock - result.seconds["database"]
        po = pycolmap.IncrementalPipelineOptions()
        po.ba_refine_focal_length = False          # the camera is known: COLMAP only orients
        po.ba_refine_principal_point = False
        po.ba_refine_extra_params = False
        po.min_num_matches = min_matches
        po.min_model_size = 3
        po.mapper.init_min_num_inliers = max(2 * min_matches, 16)
        po.mapper.abs_pose_min_num_inliers = max(min_matches, 6)
        po.extract_colors = False
        po.num_threads = num_threads
        po.random_seed = 0      # COLMAP otherwise draws a new seed per run: one block, one orientation
        # dgcal's own adjustment follows: COLMAP's bundle adjustments only need to keep the growth on track
        po.ba_global_frames_ratio = 1.4
        po.ba_global_points_ratio = 1.4
        po.ba_global_max_num_iterations = 20
        po.ba_local_max_num_iterations = 15
        po.ba_global_max_refinements = 2
        (tmp / "sparse").mkdir()
        with captured_stderr(result.log):   # "Failed to create any sparse model" is the caller's to report
            recs = pycolmap.incremental_mapping(db_path, tmp, tmp / "sparse", po)
        result.seconds["mapping"] = time.perf_counter() - clock - sum(result.seconds.values())
        id_to_index = {iid: i for i, iid in enumerate(ids)}
        # observation row of (image index, keypoint index)
        row_of = {}
        for r, (i, k) in enumerate(zip(oi, kp)):
            row_of[(i, k)] = r
        for rec in sorted(recs.values(), key=lambda r: -r.num_reg_images()):
            R_model_to_cam = np.full((n, 3, 3), np.nan)
            C_model = np.full((n, 3), np.nan)
            reg = np.zeros(n, bool)
            for iid, im in rec.images.items():
                if not im.has_pose:
                    continue
                i = id_to_index[iid]
                T_model_to_cam = im.cam_from_world().matrix()
                R_model_to_cam[i] = T_model_to_cam[:, :3]
                C_model[i] = -T_model_to_cam[:, :3].T @ T_model_to_cam[:, 3]
                reg[i] = True
            X_model = np.full((n_points, 3), np.nan)
            for p3 in rec.points3D.values():
                el = p3.track.elements
                if not len(el):
                    continue
                e = el[0]
                row = row_of.get((id_to_index[e.image_id], e.point2D_idx))
                if row is not None:
                    X_model[op[row]] = p3.xyz
            result.models.append((Poses(R_model_to_cam, C_model), X_model, reg))
    return result
