"""Self-calibrating bundle adjustment: images x targets -> intrinsics, every image's pose, optionally targets.

Observation model (OpenCV camera frame, pixels as in docs/conventions.md)::

    X_cam = R_field_to_cam[i] @ (X_field[j] - C_field[i])        uv_ij = camera.project(X_cam)

Unknowns: the free camera parameters, every image's pose in the field frame (`dgcal.fields.pose`: the field is
the world) and, optionally, the target coordinates — either as a free network with a minimal datum (7
coordinates of three well-spread targets held, fixing position, orientation and scale, which image
observations cannot determine) or as weighted unknowns with their CSV sigmas as priors; or, for a flat board, its
bow (`warp`: two unknowns, mrcal's parabola along each board axis, `dgcal.bundle.solver.blocks.BoardWarp`): a
printed board is rarely flat to the millimetre, and a bow the model lacks goes into the focal length and the
principal point (mrcal's figueroa board, 1.0 and 0.5 mm: fx 1.4 px, ten of its sigmas). Solved by the
engine of `dgcal.bundle.solver` (Levenberg-Marquardt, targets eliminated by Schur complement), from the start
values first on every k-th observation of an image with many (targets held), then on all. Outliers are
rejected iteratively on the robustly scaled residual norm. Covariances are sigma0^2 N^-1 with sigma0 from
the final residuals.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from threadpoolctl import threadpool_limits

from dgcal.bundle.solver.blocks import BoardWarp, ImageObservations, PointPriors, State
from dgcal.bundle.solver.covariance import CameraSideCofactors, Covariance
from dgcal.bundle.solver.lm import LMOptions, minimise
from dgcal.bundle.solver.normals import Problem, linearise
from dgcal.calib.camera.conversions import convert_model
from dgcal.calib.camera.models import CameraModel, model_class
from dgcal.fields.errors import InputError
from dgcal.fields.io.labels import Labels
from dgcal.fields.pose import Poses

# median of the chi distribution with 2 degrees of freedom, in units of sigma
_CHI2_MEDIAN = float(np.sqrt(2 * np.log(2)))
MIN_POINTS_AFTER_REJECTION = 4   # an image keeps its pose with this many inliers (4 points of a plane fix it)
RESIDUAL_ROWS = 100_000          # observations whose residuals are evaluated at once (the engine's CHUNK_ITEMS)
# observations the engine linearises at once (its parts end where an image's do): each part's Jacobians (~3 MB)
# stay in cache and in memory the allocator reuses, where the whole of 55 000 took fresh pages every time (a
# linearisation 32 -> 24 ms); the engine's own CHUNK_ITEMS (100 000) only bounds the memory
SOLVER_CHUNK_ITEMS = 15_000
# the first solve, from distortion-free start values, sees every k-th observation of an image with k x this many
# (k >= 2): its far iterations need not see every point, and its minimum lies within ~sqrt(k - 1) sigma of the
# whole data's, which the solves after the rejection then reach in a few iterations
COARSE_POINTS = 200
COARSE_TOL_CHI2 = 1.0            # that first solve's stopping gain in chi^2 (a closer minimum would not help)
# initial damping of a solve that starts at a solution of nearly the same problem (after a rejection, the first
# solve, a subset): the engine's 1e-4 halves the steps along the weakest directions of the scaled reduced system
# (eigenvalues ~1e-4 on 60 images: the principal point against the poses' rotations), which then take 2-3 more
# iterations to converge
WARM_LAMBDA0 = 1e-8
REFINE_TARGETS = ("none", "free", "weighted", "warp")   # what of the target field the adjustment refines
# why an observation is not in the adjustment: codes of `_InitialPoses.reason` (1 byte an observation)
REASONS = ("", "image dropped: too few targets", "image dropped: no pose", "image dropped: too few inliers",
           "not in the subset")


@dataclass
class RejectedObservation:
    """An observation left out of the final adjustment, with its residual (px) and the reason."""

    image: str
    id: str
    residual_px: float
    reason: str = "outlier"


@dataclass
class IntrinsicBAResult:
    """Result of `adjust`: the camera with sigmas, poses, targets, residuals, covariance and statistics."""

    camera: CameraModel
    free: np.ndarray                       # bool (P,): adjusted camera parameters
    cov_camera: np.ndarray                 # (P,P) covariance of the camera parameters (0 for fixed ones)
    correlation: np.ndarray                # (P,P) correlation matrix (NaN for fixed parameters)
    image_names: list[str]
    poses: Poses                           # (M) in the field frame, cov [C (m), dtheta (rad)]; NaN when dropped
    point_ids: list[str]
    points_xyz: np.ndarray                 # (N,3) m, adjusted when targets were refined
    points_sigma: np.ndarray               # (N,3) m, 0 when held fixed
    points_free: np.ndarray                # (N,3) bool: coordinate adjusted
    obs_image: np.ndarray                  # (n,) image index of every input observation
    obs_point: np.ndarray                  # (n,) point index
    obs_xy: np.ndarray                     # (n,2) measured px
    obs_sigma: np.ndarray                  # (n,2) a priori px (relative weights)
    residuals: np.ndarray                  # (n,2) projected - measured, px
    used: np.ndarray                       # (n,) bool: observation in the final adjustment
    sigma0: float                          # a posteriori standard deviation of unit weight
    rms_px: float                          # sqrt(mean |v|^2) over used observations (OpenCV's definition)
    rejected: list[RejectedObservation]
    dropped_images: list[str]
    refine_targets: str
    iterations: int
    converged: bool                        # the final Levenberg-Marquardt run converged
    redundancy: int
    rejection_settled: bool = True         # the outlier set stopped changing within max_rounds
    cov_camera_side: CameraSideCofactors | None = None  # sigma0^2 N^-1 of the poses [C (m), dtheta (rad)] and
    #                  the camera parameters (points eliminated): `.dense()` (6M+G)^2 (NaN = held/unobserved),
    #                  `.sandwich(L)`, by blocks for many images; G = P, + 2 with the board warp (its last columns)
    board_warp_m: np.ndarray | None = None        # (2,) the board's bow along its two axes (refine_targets='warp')
    board_warp_sigma_m: np.ndarray | None = None  # (2,) their sigmas

    @property
    def n_globals(self) -> int:
        """Global unknowns of the adjustment: the camera parameters, and the board warp's two when estimated."""
        return len(self.camera.PARAMS) + (0 if self.board_warp_m is None else 2)

    @property
    def n_observations(self) -> int:
        return int(self.used.sum())

    @property
    def n_rejected(self) -> int:
        return int((~self.used).sum())

    def per_image_rms(self) -> dict[str, float]:
        """RMS residual norm (px) of each image's used observations."""
        M = len(self.image_names)
        n2 = np.zeros(M)
        count = np.zeros(M, np.int64)
        for s in _row_chunks(len(self.used)):
            u = self.used[s]
            img = self.obs_image[s][u]
            r = self.residuals[s][u]
            n2 += np.bincount(img, r[:, 0] ** 2 + r[:, 1] ** 2, M)
            count += np.bincount(img, minlength=M)
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt(n2 / count)
        return {name: float(rms[i]) if count[i] else float("nan") for i, name in enumerate(self.image_names)}

    @property
    def R_field_to_cam(self) -> np.ndarray:
        """(M,3,3) rotations taking field vectors into camera axes (NaN for dropped images)."""
        return self.poses.R_world_to_cam

    @property
    def pose_sigma(self) -> np.ndarray:
        """(M,6) sigmas of the projection centre (m, field axes) and of the rotation (deg, camera axes)."""
        s = self.poses.sigmas()
        s[:, 3:] = np.degrees(s[:, 3:])
        return s

    def camera_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Projection centres in the field frame (M,3) m and their sigmas (M,3) m."""
        return self.poses.C_world, self.poses.sigmas()[:, :3]

    def camera_sigmas(self) -> dict[str, float]:
        """Sigma of every camera parameter by name (0 for fixed ones)."""
        return {k: float(s) for k, s in zip(self.camera.PARAMS, np.sqrt(np.maximum(np.diag(self.cov_camera), 0)))}


def _row_chunks(n: int) -> list[slice]:
    """Slices of at most RESIDUAL_ROWS rows covering n rows."""
    return [slice(a, min(a + RESIDUAL_ROWS, n)) for a in range(0, n, RESIDUAL_ROWS)]


# ---------------------------------------------------------------------------------------------
def _plane_frame(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Centroid, rotation field->plane (rows = plane axes) and whether the points are (nearly) planar."""
    c = xyz.mean(axis=0)
    _, s, Vt = np.linalg.svd(xyz - c, full_matrices=False)
    if np.linalg.det(Vt) < 0:
        Vt[2] *= -1
    planar = s[2] <= 1e-3 * s[0]
    return c, Vt, bool(planar)


def _pnp(obj: np.ndarray, img: np.ndarray, K: np.ndarray, planar: bool, thresh_px: float):
    """Pose (R_obj_to_cam, t) and inlier mask of one image with a distortion-free K: plain PnP on every point
    (IPPE on a plane, SQPnP otherwise); only when a residual beyond `thresh_px` calls for it, RANSAC PnP and
    plain PnP again on its inliers (the adjustment refines every pose anyway: a start pose needs no iterative
    refinement of its own, the iteration counts and results are the same)."""
    obj64 = np.ascontiguousarray(obj, np.float64)
    img64 = np.ascontiguousarray(img, np.float64)
    if len(obj64) < 6:
        return None
    pose = _pnp_all(obj64, img64, K, planar)
    if pose is not None and np.all(_pinhole_errors(obj64, img64, K, *pose) <= thresh_px):
        rvec, tvec = pose
        mask = np.ones(len(obj64), bool)
    else:                     # outliers (or no plain solution): RANSAC, then all of its inliers
        pose, mask = _pnp_ransac(obj64, img64, K, planar, thresh_px)
        if pose is None:
            return None
        rvec, tvec = _pnp_all(obj64[mask], img64[mask], K, planar) or pose
    R_obj_to_cam = cv2.Rodrigues(rvec)[0]
    if not (np.all(np.isfinite(R_obj_to_cam)) and np.all(np.isfinite(tvec))):
        return None
    if np.median((obj[mask] @ R_obj_to_cam.T + tvec.ravel())[:, 2]) <= 0:
        return None
    return R_obj_to_cam, tvec.ravel(), mask


def _pnp_all(obj: np.ndarray, img: np.ndarray, K: np.ndarray, planar: bool):
    """(rvec, tvec) of plain PnP on all points (IPPE for a plane, SQPnP otherwise), None when it fails."""
    try:
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, None, flags=cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_SQPNP)
    except cv2.error:
        return None
    if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
        return None
    return rvec, tvec


def _pinhole_errors(obj: np.ndarray, img: np.ndarray, K: np.ndarray, rvec, tvec) -> np.ndarray:
    """Reprojection error norms (px) through the pinhole K; inf behind the camera."""
    Xc = obj @ cv2.Rodrigues(rvec)[0].T + np.ravel(tvec)
    with np.errstate(all="ignore"):
        uv = Xc[:, :2] / Xc[:, 2:3] @ K[:2, :2].T + K[:2, 2]
        e = np.linalg.norm(uv - img, axis=1)
    return np.where((Xc[:, 2] > 0) & np.isfinite(e), e, np.inf)


def _pnp_ransac(obj: np.ndarray, img: np.ndarray, K: np.ndarray, planar: bool, thresh_px: float):
    """((rvec, tvec), inlier mask) of RANSAC PnP, (None, None) without a pose of 6 inliers or more."""
    flags = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_EPNP
    try:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, K, None, iterationsCount=200,
                                                 reprojectionError=thresh_px, confidence=0.999, flags=flags)
    except cv2.error:
        ok = False
    if not ok or inl is None or len(inl) < 6:
        return None, None
    mask = np.zeros(len(obj), bool)
    mask[inl.ravel()] = True
    return (rvec, tvec), mask


def _focal_guess(groups, xyz, image_size, planar, plane_xyz) -> float:
    """Initial focal length (px): OpenCV's homography estimate for planar fields, else a PnP focal sweep."""
    w, h = image_size
    if planar:
        try:
            # every k-th point of an image with many: a homography of ~COARSE_POINTS spread points is as good
            step = [max(1, len(j) // COARSE_POINTS) for _, j, _ in groups[:40]]
            objs = [plane_xyz[j[::k]].astype(np.float32) for (_, j, _), k in zip(groups[:40], step)]
            imgs = [uv[::k].astype(np.float32) for (_, _, uv), k in zip(groups[:40], step)]
            K = cv2.initCameraMatrix2D(objs, imgs, (w, h))
            f = float(np.sqrt(K[0, 0] * K[1, 1]))
            if np.isfinite(f) and 0.05 * w < f < 50 * w:
                return f
        except cv2.error:
            pass
    best = (np.inf, float(max(w, h)))
    sample = groups[:: max(1, len(groups) // 12)][:12]
    for f in max(w, h) * np.geomspace(0.15, 8.0, 24):
        K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
        errs = []
        for _, j, uv in sample:
            pose = _pnp(xyz[j], uv, K, False, 0.05 * max(w, h))
            if pose is None:
                errs.append(np.inf)
                continue
            R_obj_to_cam, t_cam, _ = pose
            Xc = xyz[j] @ R_obj_to_cam.T + t_cam
            proj = Xc[:, :2] / Xc[:, 2:3] * f + K[:2, 2]
            errs.append(np.median(np.linalg.norm(proj - uv, axis=1)))
        score = np.median(errs)
        if score < best[0]:
            best = (score, float(f))
    return best[1]


# ---------------------------------------------------------------------------------------------
def _problem(cam: CameraModel, free_cam: np.ndarray, active: np.ndarray, obs_img, obs_pt, meas_xy, sig,
             X0: np.ndarray, pt_free: np.ndarray, pt_prior_w: np.ndarray, M: int,
             warp: BoardWarp | None = None) -> Problem:
    """The engine problem on the active observations: all camera parameters are globals (held ones masked),
    the targets are points (held where `pt_free` is False), weighted targets get coordinate priors; a board
    warp adds its two globals after the camera's."""
    refine = bool(pt_free.any())
    blocks = [ImageObservations(cam, obs_img[active], obs_pt[active], meas_xy[active], sig[active], cam.PARAMS, 0,
                                points_fixed=not refine, warp=warp)]
    prior = pt_free & (pt_prior_w > 0)
    if prior.any():
        blocks.append(PointPriors.from_arrays(np.where(prior, X0, np.nan), 1.0 / np.where(prior, pt_prior_w, 1.0)))
    free = free_cam if warp is None else np.r_[free_cam, True, True]
    return Problem(blocks, M, len(X0), len(free), point_free=pt_free, global_free=free,
                   chunk_items=SOLVER_CHUNK_ITEMS)


def _lm(prob: Problem, state: State, max_iter: int = 100, tol_chi2: float = 0.01,
        lambda0: float = LMOptions.lambda0) -> tuple[State, int, bool]:
    """Levenberg-Marquardt to convergence; returns (state, iterations, converged).

    Converged when a step lowers chi^2 (cost / sigma0^2) by less than `tol_chi2`: the parameters are then
    within a small fraction of their sigmas of the minimum (ill-conditioned models such as the rational one
    otherwise crawl along a flat valley with negligible gains). `lambda0`: the initial damping."""
    sol = minimise(prob, state, LMOptions(max_iterations=max_iter, tol_chi2=tol_chi2, tol_rel=0.0, lambda0=lambda0))
    return sol.state, sol.iterations, sol.converged


def _datum_points(xyz: np.ndarray, seen: np.ndarray) -> tuple[int, int, int, int]:
    """Three well-spread observed targets (a, b, c) and the axis of c to hold for a minimal datum."""
    idx = np.flatnonzero(seen)
    P = xyz[idx]
    c0 = P.mean(axis=0)
    a = idx[np.argmax(np.linalg.norm(P - c0, axis=1))]
    b = idx[np.argmax(np.linalg.norm(P - xyz[a], axis=1))]
    ab = xyz[b] - xyz[a]
    n = np.cross(ab, P - xyz[a])
    c = idx[np.argmax(np.linalg.norm(n, axis=1))]
    # a rotation about the a-b axis moves c along (b-a) x (c-a): hold c's coordinate along that axis
    axis = int(np.argmax(np.abs(np.cross(ab, xyz[c] - xyz[a]))))
    return int(a), int(b), int(c), axis


def adjust(field_ids, field_xyz, meas_image, meas_id, meas_xy, image_size, model: str = "fraser7",
           meas_sigma=None, field_sigma=None, fixed=(), refine_targets: str = "none",
           initial: CameraModel | None = None, reject_k: float = 4.0, max_rounds: int = 6,
           min_points_per_image: int = 6, progress=None) -> IntrinsicBAResult:
    """Self-calibrating bundle adjustment of one camera from image measurements (px) of field targets (m).

    refine_targets: 'none' (targets fixed), 'free' (free network, minimal datum of 7 held coordinates),
    'weighted' (targets with their CSV sigmas `field_sigma` (m) as priors; NaN sigma = held) or 'warp' (a flat
    board's bow: two unknowns, the targets otherwise held).
    fixed: names of camera parameters held at their initial values. meas_sigma (px) are relative weights.
    reject_k: an observation beyond k robust sigmas (of all observations and of its own image's) is rejected;
    0 or inf keeps every observation.
    """
    # the dense blocks are small (<= ~1000): BLAS threads cost more than they give, and much more on a
    # busy machine (a 190x190 solve took 170 ms with threads competing, 1 ms on one)
    with threadpool_limits(limits=1):
        return _adjust(field_ids, field_xyz, meas_image, meas_id, meas_xy, image_size, model, meas_sigma,
                       field_sigma, fixed, refine_targets, initial, reject_k, max_rounds, min_points_per_image,
                       progress)


def _adjust(field_ids, field_xyz, meas_image, meas_id, meas_xy, image_size, model: str = "fraser7",
            meas_sigma=None, field_sigma=None, fixed=(), refine_targets: str = "none",
            initial: CameraModel | None = None, reject_k: float = 4.0, max_rounds: int = 6,
            min_points_per_image: int = 6, progress=None) -> IntrinsicBAResult:
    """The adjustment itself (see `adjust`)."""
    w, h = int(image_size[0]), int(image_size[1])
    cls = model_class(model)
    if not reject_k > 0:        # 0 (or negative): no outlier rejection, every observation kept (as OpenCV)
        reject_k = np.inf
    obs = _observations(field_ids, field_xyz, meas_image, meas_id, meas_xy, meas_sigma)
    bad = [k for k in fixed if k not in cls.PARAMS]
    if bad:
        raise InputError(f"unknown parameter(s) to fix {bad}; {model} has {', '.join(cls.PARAMS)}", field="fixed")
    if refine_targets not in REFINE_TARGETS:
        raise InputError(f"refine_targets must be {', '.join(REFINE_TARGETS)}, got {refine_targets!r}",
                         field="refine_targets")
    M = obs.M
    c0, R_field_to_plane, planar = _plane_frame(obs.field_xyz[np.unique(obs.obs_pt)])
    plane_xyz = (obs.field_xyz - c0) @ R_field_to_plane.T
    if planar:
        plane_xyz[:, 2] = 0.0
    rows = obs.rows_by_image()
    groups_ok = _Groups(obs, rows, [i for i in range(M) if len(rows[i]) >= min_points_per_image])
    if len(groups_ok) < 3:
        raise InputError(f"only {len(groups_ok)} image(s) with at least {min_points_per_image} target "
                         f"measurements; need 3 or more")
    cam = _initial_camera(cls, model, initial, groups_ok, obs.field_xyz, plane_xyz, planar, (w, h))
    init = _initial_poses(obs, rows, cam, initial is not None, plane_xyz, planar, R_field_to_plane, c0,
                          min_points_per_image, progress)
    del rows, groups_ok           # every observation's index (40 MB at 5 M): not needed any more
    if M - len(init.dropped) < 3:
        raise InputError(f"only {M - len(init.dropped)} usable image(s) (no pose for {', '.join(init.dropped[:5])}); "
                         "need 3 or more")
    X0, pt_free, pt_prior_w = _target_unknowns(refine_targets, obs, init.active, field_sigma)
    warp = None
    if refine_targets == "warp":
        if not planar:
            raise InputError("refine_targets='warp' bows a flat board; this field is not planar (refine its targets "
                             "with 'free' or 'weighted')", field="refine_targets")
        warp = board_warp(obs.field_xyz, R_field_to_plane, len(cls.PARAMS))
    # all requested parameters at once (staging focal length/K1 first converged slower in tests)
    adj = _Adjustment(cam, np.array([k not in fixed for k in cls.PARAMS]), obs, X0, pt_free, pt_prior_w, warp)
    start = State(Poses.from_R_t(init.R_field_to_cam, init.t_cam), X0.copy(),
                  cam.params.copy() if warp is None else np.r_[cam.params, 0.0, 0.0])
    state, total_it = adj.solve_from_start(start, init.active)
    state, active, usable, settled, it = _reject_outliers(adj, state, init, reject_k, max_rounds, min_points_per_image)
    total_it += it
    if M - len(init.dropped) < 3:
        raise InputError(f"only {M - len(init.dropped)} usable image(s) after outlier rejection; need 3 or more")
    state, it, lm_conv = adj.solve(state, active)
    return _result(adj, state, active, usable, init, refine_targets, total_it + it, bool(lm_conv), settled, (w, h))


class _Groups:
    """The (image, target indices, pixels) of the images `which`, built when asked for (a list of them all would
    copy every observation)."""

    def __init__(self, obs: "_Observations", rows: list[np.ndarray], which: list[int]):
        self.obs, self.rows, self.which = obs, rows, which

    def __len__(self) -> int:
        return len(self.which)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return _Groups(self.obs, self.rows, self.which[k])
        i = self.which[k]
        return i, self.obs.obs_pt[self.rows[i]], self.obs.xy[self.rows[i]]


@dataclass
class _Observations:
    """The measurements of `adjust`, indexed: image and target of every observation, pixel sigmas."""

    field_ids: np.ndarray
    field_xyz: np.ndarray
    meas_image: Labels      # image label of every observation (codes into the distinct labels)
    meas_id: Labels         # target id of every observation
    xy: np.ndarray          # (n,2) px
    sig: np.ndarray         # (n,2) px (relative weights)
    obs_img: np.ndarray     # (n,) int32 image index
    obs_pt: np.ndarray      # (n,) int32 target index
    image_names: list[str]

    @property
    def M(self) -> int:
        return len(self.image_names)

    @property
    def N(self) -> int:
        return len(self.field_ids)

    @property
    def n(self) -> int:
        return len(self.obs_img)

    def index(self, names: list[str]) -> list[int]:
        """Indices of image names."""
        return [self.image_names.index(k) for k in names]

    def rows_by_image(self) -> list[np.ndarray]:
        """The observation rows of every image (M index arrays, ascending)."""
        order = np.argsort(self.obs_img, kind="stable")
        bounds = np.searchsorted(self.obs_img[order], np.arange(self.M + 1))
        return [order[bounds[i]:bounds[i + 1]] for i in range(self.M)]


def _observations(field_ids, field_xyz, meas_image, meas_id, meas_xy, meas_sigma) -> _Observations:
    """Index the measurements by image and target; InputError for a target id not in the field. Image labels and
    target ids may be arrays or `Labels` (a measurement file's codes: nothing is copied a row)."""
    field_ids = np.asarray(field_ids).astype(str)
    img_lab = Labels.of(meas_image).as_str()
    id_lab = Labels.of(meas_id).as_str()
    n = len(id_lab)
    if meas_sigma is None:
        sig = np.ones((n, 2))
    else:
        sig = np.asarray(meas_sigma, float)
        if not np.isfinite(sig).all():
            sig = sig.copy()
            sig[~np.isfinite(sig)] = 1.0
    # target index of every distinct id (of a duplicated field id the last, as a dict keeps), then of every row
    where = {k: i for i, k in enumerate(field_ids.tolist())}
    pt_of = np.array([where.get(str(k), -1) for k in id_lab.names.tolist()], np.int64)
    missing = pt_of < 0
    if missing[id_lab.codes].any():
        present = id_lab.present()
        unknown = [str(id_lab.names[c]) for c in present if missing[c]]
        raise InputError(f"target id(s) not in the field: {', '.join(unknown[:5])}", field="id")
    obs_pt = pt_of.astype(np.int32)[id_lab.codes]
    # images in the order of their first measurement
    present = img_lab.present()
    rank = np.full(len(img_lab.names), -1, np.int32)
    rank[present] = np.arange(len(present), dtype=np.int32)
    image_names = [str(k) for k in img_lab.names[present].tolist()]
    return _Observations(field_ids, np.asarray(field_xyz, float), img_lab, id_lab, np.asarray(meas_xy, float), sig,
                         rank[img_lab.codes], obs_pt, image_names)


def _initial_camera(cls, model: str, initial: CameraModel | None, groups_ok, field_xyz, plane_xyz, planar: bool,
                    size: tuple[int, int]) -> CameraModel:
    """The start camera: `initial` (converted to `model` if it is another one), else a focal-length guess with the
    principal point at the image centre."""
    w, h = size
    if initial is not None:
        if isinstance(initial, cls):
            return cls((w, h), initial.params)
        # another model: its closest equivalent (exact where one model contains the other)
        return cls((w, h), convert_model(initial, model)[0].params)
    f0 = _focal_guess(groups_ok, field_xyz if not planar else plane_xyz, (w, h), planar, plane_xyz)
    return cls.from_dict((w, h), {"f": f0, "fx": f0, "fy": f0, "cx": (w - 1) / 2, "cy": (h - 1) / 2})


@dataclass
class _InitialPoses:
    """Start poses (R_field_to_cam (M,3,3), t_cam (M,3)), the observations kept (PnP inliers), dropped images and
    why."""

    R_field_to_cam: np.ndarray
    t_cam: np.ndarray
    active: np.ndarray
    dropped: list[str]
    reason: np.ndarray       # (n,) int8: index into REASONS (0: none, i.e. an outlier when left out)


def _initial_poses(obs: _Observations, rows: list[np.ndarray], cam: CameraModel, with_camera: bool, plane_xyz,
                   planar: bool, R_field_to_plane: np.ndarray, c0: np.ndarray, min_points: int,
                   progress) -> _InitialPoses:
    """Every image's start pose by PnP in the field's plane frame, RANSAC where outliers call for it (images with
    too few targets or no pose are dropped; PnP outliers leave the adjustment). `rows`: each image's observation
    rows (`_Observations.rows_by_image`)."""
    w, h = cam.image_size
    K0 = cam.pinhole_K()
    M = obs.M
    out = _InitialPoses(np.tile(np.eye(3), (M, 1, 1)), np.zeros((M, 3)), np.ones(obs.n, bool), [],
                        np.zeros(obs.n, np.int8))
    for i in (range(M) if progress is None else progress(range(M))):
        m = rows[i]
        if len(m) < min_points:
            out.dropped.append(obs.image_names[i])
            out.active[m] = False
            out.reason[m] = REASONS.index("image dropped: too few targets")
            continue
        obj, uv = plane_xyz[obs.obs_pt[m]], obs.xy[m]
        pose = _pnp(obj, uv, K0, planar, 0.02 * max(w, h))
        if with_camera:
            pose = _pose_fitting_camera(cam, K0, obj, uv, pose, planar, min_points)
        if pose is None:
            out.dropped.append(obs.image_names[i])
            out.active[m] = False
            out.reason[m] = REASONS.index("image dropped: no pose")
            continue
        R_plane_to_cam, t_cam, inl = pose
        out.R_field_to_cam[i] = R_plane_to_cam @ R_field_to_plane
        out.t_cam[i] = t_cam - R_plane_to_cam @ R_field_to_plane @ c0
        out.active[m[~inl]] = False
    return out


def _pose_fitting_camera(cam: CameraModel, K0: np.ndarray, obj: np.ndarray, uv: np.ndarray, pose, planar: bool,
                         min_points: int):
    """With a start camera: PnP on undistorted pixels too, and whichever pose (of that and `pose`) the camera fits
    better, with its inliers; None without either."""
    w, h = cam.image_size
    with np.errstate(all="ignore"):
        xy_n = cam.undistort_normalized(uv)
        ok = np.all(np.isfinite(xy_n), axis=1) & np.all(np.abs(xy_n) < 100, axis=1)
    cands = [] if pose is None else [pose]
    if ok.sum() >= min_points:
        alt = _pnp(obj[ok], xy_n[ok] @ K0[:2, :2].T + K0[:2, 2], K0, planar, 0.02 * max(w, h))
        if alt is not None:
            cands.append(alt)
    best = np.inf
    pose = None
    for R_plane_to_cam, t_cam, _ in cands:
        with np.errstate(all="ignore"):
            e = np.linalg.norm(cam.project(obj @ R_plane_to_cam.T + t_cam) - uv, axis=1)
        if np.nanmedian(e) < best:
            best = float(np.nanmedian(e))
            pose = (R_plane_to_cam, t_cam, np.nan_to_num(e, nan=np.inf) < max(0.02 * max(w, h), 3 * best))
    return pose


def board_warp(field_xyz: np.ndarray, R_field_to_plane: np.ndarray, glob_offset: int) -> BoardWarp:
    """The bow of a flat board (`BoardWarp`) with targets `field_xyz` (N,3) m: u, v from the targets' extent along
    the board's own axes — the field's x and y when the board lies in its x-y plane (a board file's rows and
    columns; the bow positive along +z), else the plane's principal axes and normal —, the two warp unknowns at
    globals glob_offset, glob_offset + 1."""
    normal = np.asarray(R_field_to_plane[2], float)
    axes = R_field_to_plane[:2]
    if abs(normal[2]) > 0.999:     # a board in the field's x-y plane: its axes, and a bow positive along +z (mrcal's)
        axes, normal = np.eye(3)[:2], np.array([0.0, 0.0, 1.0])
    xy = field_xyz @ axes.T
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    uv = 2.0 * (xy - lo) / np.where(hi > lo, hi - lo, 1.0) - 1.0
    return BoardWarp(1.0 - uv ** 2, normal, glob_offset + np.arange(2))


def _target_unknowns(refine_targets: str, obs: _Observations, active: np.ndarray,
                     field_sigma) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start targets (N,3) (m), which coordinates are free, and prior weights (1/sigma, 1/m; 0 = no prior): none
    free, a free network with a minimal datum, or targets seen twice weighted by their sigmas."""
    N = obs.N
    X0 = obs.field_xyz.copy()
    pt_free = np.zeros((N, 3), bool)
    pt_prior_w = np.zeros((N, 3))
    if refine_targets in ("none", "warp"):
        return X0, pt_free, pt_prior_w
    img_count = np.bincount(obs.obs_pt[active], minlength=N)  # each image measures a target once
    seen = img_count >= 2
    pt_free[seen] = True
    if refine_targets == "free":
        a, b, c, axis = _datum_points(obs.field_xyz, seen)
        pt_free[a] = pt_free[b] = False
        pt_free[c, axis] = False
    else:
        fs = np.full((N, 3), np.nan) if field_sigma is None else np.asarray(field_sigma, float)
        ok = np.isfinite(fs) & (fs > 0)
        pt_free &= ok
        pt_prior_w[ok] = 1.0 / fs[ok]
        if not pt_free.any():
            raise InputError("refine_targets='weighted' needs target sigmas sx,sy,sz in the field file",
                             field="sx")
    return X0, pt_free, pt_prior_w


@dataclass
class _Adjustment:
    """The parts of the problem that stay: camera model and its free parameters, observations, target unknowns."""

    cam: CameraModel
    free_cam: np.ndarray
    obs: _Observations
    X0: np.ndarray
    pt_free: np.ndarray
    pt_prior_w: np.ndarray
    warp: BoardWarp | None = None

    def problem(self, active: np.ndarray) -> Problem:
        """The engine problem on the active observations."""
        o = self.obs
        return _problem(self.cam, self.free_cam, active, o.obs_img, o.obs_pt, o.xy, o.sig, self.X0, self.pt_free,
                        self.pt_prior_w, o.M, self.warp)

    def solve(self, state: State, active: np.ndarray) -> tuple[State, int, bool]:
        """Levenberg-Marquardt on the active observations from `state`, a solution of (nearly) the same problem:
        damped little at first (WARM_LAMBDA0)."""
        return _lm(self.problem(active), state, lambda0=WARM_LAMBDA0)

    def solve_from_start(self, state: State, active: np.ndarray) -> tuple[State, int]:
        """Levenberg-Marquardt from the start values on a thinned set of the active observations (`_thinned`), to
        COARSE_TOL_CHI2, when the targets are held (free targets keep every ray: a thinned one may be seen once);
        on all of them, converged, otherwise. Returns (state, iterations)."""
        thin = None if self.pt_free.any() else _thinned(self.obs.obs_img, active, self.obs.M, COARSE_POINTS)
        if thin is None:
            state, it, _ = _lm(self.problem(active), state)
        else:
            state, it, _ = _lm(self.problem(thin), state, tol_chi2=COARSE_TOL_CHI2)
        return state, it

    def whitened_residuals(self, state: State, rows: np.ndarray) -> np.ndarray:
        """(k,2) residuals / sigma of observation rows (a bool mask or indices) at `state`, evaluated
        RESIDUAL_ROWS at a time."""
        o = self.obs
        idx = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows)
        out = np.empty((len(idx), 2))
        for s in _row_chunks(len(idx)):
            k = idx[s]
            blk = ImageObservations(self.cam, o.obs_img[k], o.obs_pt[k], o.xy[k], o.sig[k], self.cam.PARAMS, 0,
                                    points_fixed=self.warp is not None, warp=self.warp)
            out[s] = blk.evaluate(state, False).r
        return out


def _thinned(obs_img: np.ndarray, active: np.ndarray, M: int, per_image: int) -> np.ndarray | None:
    """(n,) bool: every k-th active observation of each image, k = its active count // per_image (at least 1),
    in row order (spread over the frame as the rows are); None when no image has 2 x per_image."""
    idx = np.flatnonzero(active)
    img = obs_img[idx]
    counts = np.bincount(img, minlength=M)
    stride = np.maximum(counts // per_image, 1)
    if stride.max() < 2:
        return None
    order = np.argsort(img, kind="stable")
    rank = np.empty(len(idx), np.int64)         # position of an observation among its image's active ones
    rank[order] = np.arange(len(idx)) - np.repeat(np.cumsum(counts) - counts, counts)
    out = np.zeros(len(active), bool)
    out[idx[rank % stride[img] == 0]] = True
    return out


def _reject_outliers(adj: _Adjustment, state: State, init: _InitialPoses, reject_k: float, max_rounds: int,
                     min_points: int):
    """Solve, reject |v|/sigma > k sigma_robust over all observations, repeat until the set settles; images left
    with too few inliers are dropped (`init.dropped`, `init.reason` updated). Returns (state, active, usable,
    settled, iterations)."""
    obs = adj.obs
    M, n = obs.M, obs.n
    active = init.active
    usable = ~np.isin(obs.obs_img, obs.index(init.dropped))
    settled = False
    total_it = 0
    for _ in range(max_rounds):
        norm = np.full(n, np.inf)
        idx = np.flatnonzero(usable)
        for s in _row_chunks(len(idx)):
            norm[idx[s]] = np.linalg.norm(adj.whitened_residuals(state, idx[s]), axis=1)
        del idx
        s_rob = np.median(norm[usable]) / _CHI2_MEDIAN  # over all: a median of survivors would creep
        # an outlier is inconsistent with its own image too: a frame that fits worse as a whole (motion, rolling
        # shutter, a bent board) keeps its observations (OpenCV keeps them all) and is reported instead
        s_img = _image_scales(norm, obs.obs_img, usable, M) / _CHI2_MEDIAN
        new_active = usable & (norm <= reject_k * np.maximum(s_rob, s_img[obs.obs_img]))
        # keep every usable image solvable
        counts = np.bincount(obs.obs_img[new_active], minlength=M)
        # an image needs min_points to start, but keeps its pose with fewer after rejection (a plane: 4)
        keep_min = min(min_points, MIN_POINTS_AFTER_REJECTION)
        for i in np.flatnonzero((counts < keep_min) & (np.bincount(obs.obs_img[usable], minlength=M) > 0)):
            init.dropped.append(obs.image_names[i])
            usable &= obs.obs_img != i
            new_active &= obs.obs_img != i
            init.reason[obs.obs_img == i] = REASONS.index("image dropped: too few inliers")
        changed = int(np.sum(new_active != active))
        if changed <= 5e-3 * usable.sum():  # later rounds only trade a few borderline points
            settled = True
            active = new_active
            break
        active = new_active
        state, it, _ = adj.solve(state, active)
        total_it += it
    return state, active, usable, settled, total_it


def _image_scales(norm: np.ndarray, obs_img: np.ndarray, usable: np.ndarray, M: int) -> np.ndarray:
    """(M,) median whitened residual norm of each image's usable observations (0 for an image without any)."""
    out = np.zeros(M)
    idx = np.flatnonzero(usable)
    if not len(idx):
        return out
    order = idx[np.lexsort((norm[idx], obs_img[idx]))]
    img = obs_img[order]
    starts = np.flatnonzero(np.r_[True, img[1:] != img[:-1]])
    counts = np.diff(np.r_[starts, len(order)])
    lo = norm[order[starts + (counts - 1) // 2]]
    hi = norm[order[starts + counts // 2]]
    out[img[starts]] = 0.5 * (lo + hi)
    return out


def _result(adj: _Adjustment, state: State, active: np.ndarray, usable: np.ndarray, init: _InitialPoses,
            refine_targets: str, iterations: int, converged: bool, settled: bool,
            size: tuple[int, int]) -> IntrinsicBAResult:
    """Statistics and covariances (sigma0^2 N^-1) at the final state, residuals and the rejected observations."""
    obs, cls = adj.obs, type(adj.cam)
    M, N, n = obs.M, obs.N, obs.n
    prob = adj.problem(active)
    nrm = linearise(prob, state)
    cov = Covariance.at(prob, nrm)
    keep_img = np.ones(M, bool)
    keep_img[obs.index(init.dropped)] = False
    redundancy = int(nrm.redundancy)
    sigma0 = float(np.sqrt(nrm.cost / max(redundancy, 1)))
    cov_side = cov.camera_side.scaled(sigma0**2)
    Pn = len(cls.PARAMS)
    free_cam = adj.free_cam
    fi = np.flatnonzero(free_cam)
    cov_cam = np.zeros((Pn, Pn))
    cov_cam[np.ix_(fi, fi)] = sigma0**2 * cov.global_cofactors(fi)
    sd = np.sqrt(np.maximum(np.diag(cov_cam), 0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_cam / np.outer(sd, sd)
    corr[~free_cam, :] = np.nan
    corr[:, ~free_cam] = np.nan
    pose_cov = sigma0**2 * cov.pose_cofactors()
    pose_cov[~keep_img] = np.nan
    pt_free = adj.pt_free
    pts_sigma = np.zeros((N, 3))
    if pt_free.any():
        var = np.maximum(np.einsum("naa->na", cov.point_cofactors()), 0)
        pts_sigma = np.nan_to_num(sigma0 * np.sqrt(var)) * pt_free
    warp_m = warp_sigma = None
    points = state.points.copy()
    if adj.warp is not None:      # the targets as bowed (a refit holds them there); the bow and its sigmas
        wi = adj.warp.glob
        warp_m = state.globals[wi].copy()
        warp_sigma = sigma0 * np.sqrt(np.maximum(np.diag(cov.global_cofactors(wi)), 0))
        points = adj.warp.points(state.points, state.globals)
    camera = cls(size, state.globals[:Pn])
    camera.sigmas = sd
    del prob, nrm, cov            # the problem's copies of the observations go before the residuals come
    r_all = np.full((n, 2), np.nan)
    idx = np.flatnonzero(usable)
    for s in _row_chunks(len(idx)):
        k = idx[s]
        r_all[k] = adj.whitened_residuals(state, k) * obs.sig[k]
    del idx
    rms = float(np.sqrt(np.mean(np.sum(r_all[active] ** 2, axis=1))))
    rejected = []
    img_names, id_names = obs.meas_image.names, obs.meas_id.names
    for k in np.flatnonzero(~active):
        rejected.append(RejectedObservation(str(img_names[obs.meas_image.codes[k]]),
                                            str(id_names[obs.meas_id.codes[k]]),
                                            float(np.linalg.norm(r_all[k])) if usable[k] else float("nan"),
                                            REASONS[init.reason[k]] or "outlier"))
    R_world_to_cam, C_world = state.poses.R_world_to_cam.copy(), state.poses.C_world.copy()
    R_world_to_cam[~keep_img] = np.nan
    C_world[~keep_img] = np.nan
    return IntrinsicBAResult(
        camera=camera, free=free_cam.copy(), cov_camera=cov_cam, correlation=corr, cov_camera_side=cov_side,
        image_names=obs.image_names, poses=Poses(R_world_to_cam, C_world, pose_cov),
        point_ids=list(obs.field_ids), points_xyz=points, points_sigma=pts_sigma,
        points_free=pt_free.copy(), obs_image=obs.obs_img, obs_point=obs.obs_pt, obs_xy=obs.xy, obs_sigma=obs.sig,
        residuals=r_all, used=active, sigma0=sigma0, rms_px=rms, rejected=rejected, dropped_images=list(init.dropped),
        refine_targets=refine_targets, iterations=iterations, converged=converged, rejection_settled=settled,
        redundancy=int(redundancy), board_warp_m=warp_m, board_warp_sigma_m=warp_sigma)


def refit(result: IntrinsicBAResult, images: np.ndarray) -> IntrinsicBAResult:
    """The adjustment of `result` again on the used observations of a subset of its images (bool (M,) or names),
    started from its solution, targets held where they are, no new rejection (e.g. the halves of a
    cross-validation)."""
    names = np.array(result.image_names, dtype=object)
    sel = np.isin(names, list(images)) if np.asarray(images).dtype != bool else np.asarray(images, bool)
    ids = np.array(result.point_ids, dtype=object)
    obs = _Observations(ids.astype(str), result.points_xyz.copy(), Labels(result.obs_image, names.astype(str)),
                        Labels(result.obs_point, ids.astype(str)), result.obs_xy, result.obs_sigma, result.obs_image,
                        result.obs_point, list(result.image_names))
    cam = result.camera.copy()
    cam.sigmas = None
    N = len(ids)
    adj = _Adjustment(cam, result.free.copy(), obs, result.points_xyz.copy(), np.zeros((N, 3), bool), np.zeros((N, 3)))
    active = result.used & sel[result.obs_image]
    counts = np.bincount(result.obs_image[active], minlength=len(names))
    keep = counts >= MIN_POINTS_AFTER_REJECTION
    active &= keep[result.obs_image]
    if keep.sum() < 3:
        raise InputError(f"only {int(keep.sum())} image(s) in the subset; need 3 or more")
    R_world_to_cam = np.where(keep[:, None, None], np.nan_to_num(result.poses.R_world_to_cam), np.eye(3))
    C_world = np.where(keep[:, None], np.nan_to_num(result.poses.C_world), 0.0)
    start = Poses(R_world_to_cam, C_world)
    state, it, conv = adj.solve(State(start, result.points_xyz.copy(), cam.params.copy()), active)
    dropped = [str(n) for n, k in zip(names, keep) if not k]
    init = _InitialPoses(R_world_to_cam, start.t_cam, active.copy(), dropped,
                         np.full(len(active), REASONS.index("not in the subset"), np.int8))
    init.reason[active] = 0
    return _result(adj, state, active, active.copy(), init, "none", it, bool(conv), True, cam.image_size)
