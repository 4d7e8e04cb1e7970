"""Aerial triangulation pipeline: camera + ground points + image measurements -> EOPs with covariance.

`triangulate(...)` is what a Python user calls (and `dgcal triangulate` wraps). It
1. sorts measured ids into control (role control), check (role check) and tie points (not in the ground
   point file), and warns about anything it cannot use instead of dropping it silently;
2. moves everything into the world frame of the adjustment, a local ENU frame at the control centroid
   (`dgcal.fields.world.World`);
3. orients the images (`dgcal.bundle.initial`): from approximate EOPs, else by pycolmap's incremental mapper
   on the measurements moved onto the control points, else by resection and growth from control;
4. adjusts the block (`dgcal.bundle.adjustment`, on the engine of `dgcal.bundle.solver`) and cleans it:
   tie observations beyond k robust sigmas are dropped (each one named), images left out are retried by
   resection through the adjusted points, then data snooping on the control (Baarda's w-tests on each image
   measurement and on each control point's coordinates as a group: a wrong coordinate is named as such and
   the point becomes a tie point, its rays stay), one at a time until no test exceeds the critical value;
5. evaluates the check points: adjusted as tie points when their measurements help the block
   (`check_as_tie`), else intersected from the adjusted images; errors in grid E, N, Up with sigmas;
6. converts EOPs and their 6x6 covariances to the map CRS (grid-level PATB angles);
7. judges the result: not converged, sigma0 above `max_sigma0` or more than `max_left_out` of the connected
   images left out is a failure (`ResultError`) unless `accept_poor`.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc, gammaln, ndtri_exp   # not scipy.stats: 0.5-0.8 s to import

from dgcal.bundle.adjustment import BundleInput, BundleOptions, BundleResult, adjust
from dgcal.bundle.blunders import CRITICAL_W, Suspect
from dgcal.bundle.datum import (datum_statement, focal_height_correlation, focal_height_warning,
                                principal_point_correlation, principal_point_warning, reference_sigma_m, weak_datum)
from dgcal.bundle.initial import initial_orientation
from dgcal.bundle.intersection import intersect, propagate_pose_covariance
from dgcal.bundle.resection import pnp, triangulate_tracks
from dgcal.bundle.solver.blocks import PointPriors
from dgcal.calib.camera.models import CameraModel
from dgcal.fields.errors import InputError, ResultError
from dgcal.fields.io.formats import EOP, Measurements, Points
from dgcal.fields.pose import Poses
from dgcal.fields.world import World

DEFAULT_SIGMA_PX = 0.5          # image measurement sigma when the file gives none
DEFAULT_GCP_SIGMA_M = (0.02, 0.02, 0.03)
DEFAULT_CENTRE_SIGMA_M = 0.05   # camera-centre prior sigma (m) where the centres file gives none
MIN_IMAGE_POINTS = 4            # an image keeping fewer points after cleaning is left out (named), not trusted on them
MAX_REJECTED_CONTROL = 1 / 3    # more control points rejected than this share: the inputs disagree, not blunders
_CHI2_MEDIAN_2D = float(np.sqrt(2 * np.log(2)))   # median of the norm of a 2-D standard normal
START_CUT_FACTOR = 4.0     # the cut at the initial orientation, in units of the tie-outlier cut (gross errors only)
START_CUT_ROUNDS = 50      # rounds of that cut at most (the worst ray of each point per round)


@dataclass
class TriangulationOptions:
    """Choices of the triangulation: weights, intrinsics, robust loss, blunder handling, quality limits."""

    sigma_px: float = DEFAULT_SIGMA_PX
    tie_sigma_px: float | None = None          # default: sigma_px
    gcp_sigma_m: tuple[float, float, float] = DEFAULT_GCP_SIGMA_M   # used where gcp file gives none
    fixed_gcps: bool = False
    refine: tuple[str, ...] = ()               # camera parameters to refine in flight
    loss: str = "huber"
    loss_scale: float = 3.0
    reject_blunders: bool = True
    critical_w: float = CRITICAL_W
    max_rejections: int = 50                   # data-snooping rounds; the rest are listed as suspects
    tie_outlier_sigma: float = 5.0             # tie observations beyond this many robust sigmas are dropped
    check_as_tie: bool | None = None           # None: on for measurement-only input (no image folder)
    geoid: float | str | None = None           # constant undulation (m) or PROJ vertical grid
    aposteriori: bool = True
    use_mapper: bool = True                    # pycolmap's incremental mapper for the initial orientation
    max_sigma0: float = 3.0                    # sigma0 above this: the result is not trusted
    max_left_out: float = 0.1                  # share of connected images that may stay unoriented
    antenna_offset_cam: tuple[float, float, float] | None = None   # m, camera axes: the centres are of an antenna
                                               # at C + R_cam_to_world offset (applied with each image's rotation)
    flight_shift: bool = False                 # estimate a shift (E, N, Up) of the centres per flight (needs control)
    accept_poor: bool = False                  # return an untrusted result (with its problems) instead of failing
    verbose: bool = False


@dataclass
class TriangulationResult:
    """Everything a report needs: EOPs in the map CRS, the adjustment, per-point and per-image figures."""

    eop: EOP                                   # map CRS, sigma (n,6) and cov (n,6,6) (m, deg)
    georef: World                              # the world frame of the adjustment and the map CRS
    bundle: BundleResult
    camera: CameraModel                        # the camera of the adjustment (refined when `refine` was asked)
    images: list[str]
    point_ids: list[str]
    point_kind: np.ndarray                     # 'control' | 'tie' | 'check' per adjusted point
    gcp: list[dict]
    check: list[dict]
    image_stats: list[dict]
    suspects: list[Suspect]
    warnings: list[str]
    unknown_ids: list[str]                     # measured ids absent from the ground point file
    summary: dict = field(default_factory=dict)
    R_world_to_cam: np.ndarray | None = None
    C_world: np.ndarray | None = None
    dropped: list[dict] = field(default_factory=list)   # tie observations left out: image, id, residual_px
    problems: list[str] = field(default_factory=list)    # why the result is not to be trusted (empty: fine)


def _warn(msgs: list[str], text: str, verbose: bool) -> None:
    msgs.append(text)
    if verbose:
        print("warning:", text)


@dataclass
class _Block:
    """The adjustment's observations and points, before compaction to the oriented images."""

    images: list[str]
    point_ids: list[str]
    kind: np.ndarray            # control / tie / check per point
    rows: np.ndarray            # row of `meas` behind each observation
    oi: np.ndarray
    op: np.ndarray
    uv: np.ndarray
    sig: np.ndarray
    X_prior: np.ndarray         # (m,3) control coordinates in the world frame, NaN for others
    S_prior: np.ndarray


def _check_measurements(camera: CameraModel, meas: Measurements, image_size) -> None:
    if image_size is not None and tuple(int(v) for v in image_size) != tuple(camera.image_size):
        raise InputError(f"image size {tuple(image_size)} differs from the camera's {tuple(camera.image_size)}",
                         field="image_size")
    w_img, h_img = camera.image_size
    out = ((meas.xy[:, 0] < -0.5) | (meas.xy[:, 1] < -0.5) | (meas.xy[:, 0] > w_img - 0.5)
           | (meas.xy[:, 1] > h_img - 0.5))
    if out.any():
        i = int(np.argmax(out))
        raise InputError(f"measurement ({meas.xy[i, 0]:.1f}, {meas.xy[i, 1]:.1f}) lies outside the "
                         f"{w_img}x{h_img} image", meas.path, None if meas.lines is None else int(meas.lines[i]), "x")


def centres_in_block(centre_priors: EOP | None, meas: Measurements) -> np.ndarray:
    """Rows of `centre_priors` (map CRS) with finite X, Y, Z that name a measured image (empty: none)."""
    if centre_priors is None or not len(centre_priors.image):
        return np.zeros(0, int)
    measured = set(meas.image.astype(str))
    ok = np.isfinite(centre_priors.xyz).all(1)
    return np.array([r for r in np.flatnonzero(ok) if str(centre_priors.image[r]) in measured], int)


def no_datum_reason(centre_priors: EOP | None) -> str:
    """Why a block without measured control has no datum (the message of the early refusal)."""
    if centre_priors is None:
        return ("none of the control points (role 'control') is measured in any image and no camera centres are "
                "given: the block has no datum; measure control points, or give GNSS camera centres (--gnss)")
    return (f"none of the control points (role 'control') is measured in any image and none of the "
            f"{len(centre_priors.image)} camera centres names a measured image (with finite X, Y, Z): the block "
            "has no datum")


def _georef(points: Points, meas: Measurements, crs: str | None, opt: TriangulationOptions,
            centre_priors: EOP | None = None) -> tuple[World, np.ndarray]:
    """The world frame at the centroid of the measured control points (without them: of the camera centres, at
    the height of the measured ground points if any), and every ground point in it."""
    role_of = {str(k): str(r) for k, r in zip(points.ids, points.role)}
    measured = set(meas.id.astype(str))
    ctrl_mask = np.array([str(c) in measured and role_of[str(c)] == "control" for c in points.ids], bool)
    c_rows = centres_in_block(centre_priors, meas)
    if ctrl_mask.any():
        origin = points.xyz[ctrl_mask].mean(0)
    elif len(c_rows):
        origin = centre_priors.xyz[c_rows].mean(0)
        gp = np.array([str(c) in measured for c in points.ids], bool)
        if gp.any():
            origin[2] = float(np.median(points.xyz[gp, 2]))
    else:
        raise InputError(no_datum_reason(centre_priors), meas.path, field="id")
    geo = World.from_crs(crs, origin, opt.geoid, points.path if ctrl_mask.any() else centre_priors.path)
    P_world = geo.to_world(points.xyz)
    if not np.isfinite(P_world).all():
        bad = int(np.argmax(~np.isfinite(P_world).all(1)))
        raise InputError(f"point {points.ids[bad]} is not a valid coordinate in CRS {crs}", points.path,
                         None if points.lines is None else int(points.lines[bad]), "x")
    spread = np.ptp(P_world[ctrl_mask], axis=0) if ctrl_mask.any() else np.zeros(3)
    if ctrl_mask.sum() > 2 and max(spread[:2]) > 5e4:
        raise InputError(f"control points span {max(spread[:2]) / 1e3:.0f} km in CRS {crs}: wrong CRS or "
                         "coordinate order?", points.path, field="crs")
    if len(c_rows):
        C_world = geo.to_world(centre_priors.xyz[c_rows])
        bad = ~np.isfinite(C_world).all(1)
        if bad.any():
            r = int(c_rows[np.argmax(bad)])
            raise InputError(f"camera centre of {centre_priors.image[r]} is not a valid coordinate in CRS {crs}",
                             centre_priors.path, None if centre_priors.lines is None else int(centre_priors.lines[r]),
                             "X")
        if max(np.ptp(C_world[:, :2], axis=0)) > 5e4:
            raise InputError(f"camera centres span {max(np.ptp(C_world[:, :2], axis=0)) / 1e3:.0f} km in CRS {crs}: "
                             "wrong CRS or coordinate order?", centre_priors.path, field="crs")
    return geo, P_world


def _block(points: Points, P_world: np.ndarray, meas: Measurements, opt: TriangulationOptions, check_as_tie: bool,
           all_images: list[str] | None, msgs: list[str], has_centres: bool = False) -> _Block:
    """Observations of control, tie (and check, as ties) points; points measured once (not control) left out.
    Without control points the camera centres (`has_centres`) must give the datum."""
    pidx = points.index()
    ids = meas.id.astype(str)
    role_of = {str(k): str(r) for k, r in zip(points.ids, points.role)}
    control_ids = [str(k) for k, r in zip(points.ids, points.role) if r == "control"]
    if not control_ids and not has_centres:
        raise InputError("no control points (role 'control') in the ground point file and no camera centres (--gnss):"
                         " the block has no datum", points.path, field="role")
    measured = set(ids)
    for pid in points.ids:
        if str(pid) not in measured:
            _warn(msgs, f"ground point {pid} ({role_of[str(pid)]}) has no image measurements: not used", opt.verbose)
    counts = dict(zip(*np.unique(ids, return_counts=True)))
    for pid in control_ids:
        if counts.get(pid, 0) == 1:
            _warn(msgs, f"control point {pid} is measured in one image only: it constrains that image weakly "
                        "and its measurement cannot be checked for blunders", opt.verbose)
    is_check = np.array([role_of.get(i) == "check" for i in ids])
    use = ~is_check | check_as_tie
    uniq, cnt = np.unique(ids[use], return_counts=True)
    once = set(uniq[cnt < 2]) - set(control_ids)
    if 0 < len(once) <= 20:
        for pid in sorted(once):
            _warn(msgs, f"{'check' if role_of.get(pid) == 'check' else 'tie'} point {pid} is measured in one image "
                        "only: not used in the adjustment", opt.verbose)
    elif len(once) > 20:
        _warn(msgs, f"{len(once)} tie points are measured in one image only: not used", opt.verbose)
    if once:
        use &= np.array([i not in once for i in ids], bool)   # np.isin on object arrays is quadratic
    images = list(dict.fromkeys((all_images or []) + meas.images()))
    img_index = {n: i for i, n in enumerate(images)}
    point_ids = list(dict.fromkeys(ids[use].tolist()))
    pt_index = {p: i for i, p in enumerate(point_ids)}
    kind = np.array([role_of.get(p, "tie") for p in point_ids], dtype=object)
    rows = np.flatnonzero(use)
    oi = np.array([img_index[n] for n in meas.image[rows].astype(str)], int)
    op = np.array([pt_index[p] for p in ids[rows]], int)
    sig_default = np.where(kind[op] == "control", opt.sigma_px, opt.tie_sigma_px or opt.sigma_px)
    sig = np.where(np.isfinite(meas.sigma[rows]), meas.sigma[rows], sig_default[:, None])
    m = len(point_ids)
    X_prior = np.full((m, 3), np.nan)
    S_prior = np.full((m, 3), np.nan)
    for j, p in enumerate(point_ids):
        if kind[j] == "control":
            r = pidx[p]
            X_prior[j] = P_world[r]
            s = points.sigma[r]
            S_prior[j] = 0.0 if opt.fixed_gcps else np.where(np.isfinite(s), s, opt.gcp_sigma_m)
    return _Block(images, point_ids, kind, rows, oi, op, meas.xy[rows], sig, X_prior, S_prior)


def _approx_poses(approx: EOP | None, geo: World, images: list[str]) -> tuple[np.ndarray | None, np.ndarray | None]:
    if approx is None:
        return None, None
    n = len(images)
    R_world_to_cam, C_world = np.full((n, 3, 3), np.nan), np.full((n, 3), np.nan)
    a_idx = {str(k): i for i, k in enumerate(approx.image)}
    have = [i for i, name in enumerate(images) if name in a_idx]
    if have:
        rows = [a_idx[images[i]] for i in have]
        p = geo.eop_to_poses(approx.xyz[rows], approx.opk[rows])
        R_world_to_cam[have], C_world[have] = p.R_world_to_cam, p.C_world
    return R_world_to_cam, C_world


def _centre_priors(centre_priors: EOP | None, geo: World, images: list[str]):
    """Camera-centre priors (n,3) in the world frame and their sigmas (n,3) (m; NaN where an image has none;
    a sigma the file leaves blank is DEFAULT_CENTRE_SIGMA_M). The file's sigmas are along grid E, N, Up, taken
    as world E, N, Up (they differ by the meridian convergence, a few degrees at most)."""
    if centre_priors is None:
        return None, None
    cprior = np.full((len(images), 3), np.nan)
    csig = np.full((len(images), 3), np.nan)
    c_idx = {str(k): i for i, k in enumerate(centre_priors.image)}
    have = [i for i, name in enumerate(images) if name in c_idx]
    if not have:
        return None, None
    rows = np.array([c_idx[images[i]] for i in have])
    cprior[have] = geo.to_world(centre_priors.xyz[rows])
    s = centre_priors.sigma[rows, :3] if centre_priors.sigma is not None else np.full((len(rows), 3), np.nan)
    csig[have] = np.where(np.isfinite(s) & (s > 0), s, DEFAULT_CENTRE_SIGMA_M)
    cprior[~np.isfinite(cprior).all(1)] = np.nan
    if not np.isfinite(cprior).any():
        return None, None
    return cprior, csig


def _warn_unmatched_centres(centre_priors: EOP | None, images: list[str], cprior: np.ndarray | None, msgs: list[str],
                            verbose: bool) -> None:
    """Warnings for centres that name no image of the block and for images without a centre (the file's image
    names must be the measurements' or the folder's)."""
    if centre_priors is None:
        return
    names = set(images)
    extra = [str(k) for k in centre_priors.image if str(k) not in names]
    if extra:
        _warn(msgs, f"{len(extra)} camera centre(s) name no image of the block (e.g. {extra[0]}): not used", verbose)
    missing = [images[i] for i in range(len(images))] if cprior is None else \
        [images[i] for i in np.flatnonzero(~np.isfinite(cprior).all(1))]
    if missing:
        _warn(msgs, f"{len(missing)} image(s) have no camera centre (e.g. {missing[0]}): they are held by their rays "
                    "only", verbose)


def _control_measured(points: Points, meas: Measurements) -> bool:
    """True when a control point (role control) is measured in an image."""
    ctrl = {str(k) for k, r in zip(points.ids, points.role) if r == "control"}
    return bool(ctrl & set(meas.id.astype(str)))


def _flights(centre_priors: EOP, centre_flights: np.ndarray | None, images: list[str]) -> tuple[np.ndarray, list[str]]:
    """Flight index per image (0 where an image has no centre) and the flights' names: from `centre_flights`
    (a label per row of the centres), else one flight."""
    if centre_flights is None:
        return np.zeros(len(images), int), ["all"]
    lab = {str(k): str(f) for k, f in zip(centre_priors.image, centre_flights)}
    names = sorted({lab[n] for n in images if n in lab})
    idx = {f: i for i, f in enumerate(names)}
    return np.array([idx.get(lab.get(n, ""), 0) for n in images], int), names


def _approx_with_centre_angles(approx: EOP | None, centre_priors: EOP | None) -> EOP | None:
    """Approximate EOPs, completed by the rows of the centres file that give angles (a camera-centre file with
    omega, phi, kappa is a full approximate orientation); `approx` wins where both give an image."""
    if centre_priors is None:
        return approx
    full = np.isfinite(centre_priors.xyz).all(1) & np.isfinite(centre_priors.opk).all(1)
    if approx is not None:
        full &= ~np.isin(centre_priors.image.astype(str), approx.image.astype(str))
    if not full.any():
        return approx
    extra = EOP(centre_priors.image[full], centre_priors.xyz[full], centre_priors.opk[full])
    if approx is None:
        return extra
    return EOP(np.concatenate([approx.image, extra.image]), np.vstack([approx.xyz, extra.xyz]),
               np.vstack([approx.opk, extra.opk]))


class _Adjuster:
    """The block being adjusted: which images are oriented, which observations are active, the last result."""

    def __init__(self, camera, blk: _Block, R_world_to_cam, C_world, oriented, X, point_ok, cprior, csig,
                 opt: TriangulationOptions):
        self.camera, self.blk, self.opt = camera, blk, opt
        self.R_world_to_cam, self.C_world = R_world_to_cam.copy(), C_world.copy()
        self.oriented, self.X, self.point_ok = oriented.copy(), X.copy(), point_ok
        self.cprior, self.csig = cprior, csig
        self.flight: np.ndarray | None = None      # (n,) flight index per image when a shift per flight is estimated
        self.flight_names: list[str] = []
        self.active = np.ones(len(blk.oi), bool)
        self.excluded = np.zeros(len(blk.images), bool)     # images left out for good (too few rays kept)
        self.is_prior = np.isfinite(blk.X_prior).all(1)     # control points whose coordinates are observations
        self.res: BundleResult | None = None
        self.img_keep = self.pt_keep = self.obs_keep = None
        self.runs: list[dict] = []           # every adjustment: iterations, converged, why it stopped, seconds
        self.datum: dict | None = None       # what fixes the datum (`dgcal.bundle.datum.datum_statement`)

    def bundle_input(self) -> BundleInput:
        b = self.blk
        free = ~self.is_prior
        use = self.active & self.oriented[b.oi] & ~self.excluded[b.oi] & self.point_ok[b.op]
        self.lone = np.zeros(len(b.oi), bool)
        while True:   # tie points need two active rays
            cnt = np.bincount(b.op[use], minlength=len(b.point_ids))
            lone = use & free[b.op] & (cnt[b.op] < 2)
            if not lone.any():
                break
            use &= ~lone
            self.lone |= lone & self.active & self.oriented[b.oi]
        img_keep = np.flatnonzero(self.oriented & (np.bincount(b.oi[use], minlength=len(b.images)) > 0))
        pt_keep = np.flatnonzero(np.bincount(b.op[use], minlength=len(b.point_ids)) > 0)
        im_map = -np.ones(len(b.images), int)
        im_map[img_keep] = np.arange(len(img_keep))
        pt_map = -np.ones(len(b.point_ids), int)
        pt_map[pt_keep] = np.arange(len(pt_keep))
        use &= im_map[b.oi] >= 0
        self.img_keep, self.pt_keep, self.obs_keep = img_keep, pt_keep, np.flatnonzero(use)
        k = self.obs_keep
        cp = cs = fl = None
        if self.cprior is not None:
            cp, cs = self.cprior[img_keep], self.csig[img_keep]
            if self.flight is not None:
                fl = self.flight[img_keep]
        Xp = np.where(self.is_prior[:, None], b.X_prior, np.nan)
        off = None if self.opt.antenna_offset_cam is None else np.asarray(self.opt.antenna_offset_cam, float)
        return BundleInput(self.camera, [b.images[i] for i in img_keep], self.R_world_to_cam[img_keep],
                           self.C_world[img_keep], [b.point_ids[j] for j in pt_keep], self.X[pt_keep],
                           im_map[b.oi[k]], pt_map[b.op[k]], b.uv[k], b.sig[k], Xp[pt_keep], b.S_prior[pt_keep], cp,
                           cs, off, fl, tuple(self.opt.refine))

    def run(self, loss: str | None = None) -> BundleResult:
        bopt = BundleOptions(loss=loss or self.opt.loss, loss_scale=self.opt.loss_scale,
                             aposteriori=self.opt.aposteriori, verbose=self.opt.verbose)
        t0 = time.perf_counter()
        res = adjust(self.bundle_input(), bopt)
        self.runs.append({"iterations": int(res.iterations), "converged": bool(res.converged),
                          "stop_reason": res.stop_reason, "seconds": round(time.perf_counter() - t0, 3)})
        self.R_world_to_cam[self.img_keep], self.C_world[self.img_keep] = res.R_world_to_cam, res.C_world
        self.X[self.pt_keep] = res.X_world
        self.oriented[:] = False
        self.oriented[self.img_keep] = True
        self.res = res
        return res

    def retry_left_out(self, msgs: list[str]) -> int:
        """Resect images left out through the adjusted points; returns how many joined."""
        b = self.blk
        known = np.zeros(len(b.point_ids), bool)
        known[self.pt_keep] = True
        joined = 0
        for i in np.flatnonzero(~self.oriented & ~self.excluded):
            kk = np.flatnonzero((b.oi == i) & known[b.op] & self.active)
            if len(kk) < 6:
                continue
            got = pnp(self.camera, b.uv[kk], self.X[b.op[kk]])
            if got is None:
                continue
            self.R_world_to_cam[i], self.C_world[i], inl = got
            self.oriented[i] = True
            joined += 1
        if joined:
            _warn(msgs, f"{joined} image(s) left out by the initial orientation resected through the adjusted "
                        "points and adjusted", self.opt.verbose)
        return joined


def _drop_tie_outliers(adj: _Adjuster, msgs: list[str], dropped: list[dict]) -> bool:
    """Drop tie observations of the last adjustment whose standardised residual exceeds `tie_outlier_sigma`
    robust sigmas; True if any."""
    return _cut_ties(adj, adj.obs_keep, adj.res.obs_point, adj.res.residuals_px, adj.opt.tie_outlier_sigma, msgs,
                     dropped) > 0


def _drop_gross_ties_at_start(adj: _Adjuster, msgs: list[str], dropped: list[dict]) -> bool:
    """The same cut on the residuals of the initial orientation, before any adjustment: SIFT mismatches hundreds
    of sigmas off would otherwise drag the first adjustment through dozens of slow robust iterations. Only
    gross errors (`START_CUT_FACTOR` times the usual cut), and the worst ray of each point at a time, the point
    intersected again from its remaining rays before its next ray is judged (a blunder throws a point that is
    not yet fitted so far that its good rays look gross too); the scale is the first round's."""
    bi = adj.bundle_input()
    rows, point = adj.obs_keep, bi.obs_point
    poses = Poses(bi.R_world_to_cam, bi.C_world)
    is_tie = adj.blk.kind[adj.blk.op[rows]] != "control"
    X = bi.X_world.copy()
    L = np.bincount(point, minlength=len(X))
    keep = np.ones(len(rows), bool)
    e = _standardised(poses, X, bi, np.arange(len(rows)), L)
    s_rob = max(float(np.median(e)) / _CHI2_MEDIAN_2D, 1.0)
    k = START_CUT_FACTOR * adj.opt.tie_outlier_sigma
    rays = None
    for _ in range(START_CUT_ROUNDS):
        bad = is_tie & keep & (e > k * s_rob)
        if not bad.any():
            break
        by_point = np.lexsort((-e, point))           # each point's rays, worst first: the worst goes
        by_point = by_point[bad[by_point]]
        first = np.r_[True, point[by_point][1:] != point[by_point][:-1]]
        cut = by_point[first]
        keep[cut] = False
        for r in cut:
            fin = bool(np.isfinite(e[r]))
            dropped.append({"image": adj.blk.images[adj.blk.oi[rows[r]]], "id": adj.blk.point_ids[adj.blk.op[rows[r]]],
                            "reason": "outlier at the initial orientation", "residual_px": None,
                            "standardised": float(e[r]) if fin else None})
        # the touched points again from their remaining rays, and their rays judged again
        touched = np.zeros(len(X), bool)
        touched[point[cut]] = True
        sub = np.flatnonzero(touched[point] & keep)
        rays = adj.camera.ray(bi.obs_uv) if rays is None else rays
        X = _intersected_ties(bi, rays, sub, X)
        e[sub] = _standardised(poses, X, bi, sub, L)
    n = int((~keep).sum())
    if n:
        adj.active[rows[~keep]] = False
        adj.X[adj.pt_keep] = X
        _warn(msgs, f"{n} tie observation(s) beyond {k:g} robust sigmas ({k * s_rob:.1f} sigma) at the initial "
                    "orientation dropped (listed in the summary)", adj.opt.verbose)
    return n > 0


def _standardised(poses: Poses, X: np.ndarray, bi: BundleInput, sub: np.ndarray, L: np.ndarray) -> np.ndarray:
    """Standardised residual norms (as `_cut_ties`) of observations `sub` of a bundle input with points X; inf
    behind the camera or where the projection fails."""
    Xc = poses.to_cam(X[bi.obs_point[sub]], bi.obs_image[sub])
    with np.errstate(all="ignore"):
        r = bi.camera.project(Xc) - bi.obs_uv[sub]
        e = np.linalg.norm(r / bi.obs_sigma[sub], axis=1)
    e /= np.sqrt(np.clip(1.0 - 1.5 / np.maximum(L[bi.obs_point[sub]], 1), 0.1, 1.0))
    e[~(Xc[:, 2] > 0) | ~np.isfinite(e)] = np.inf
    return e


def _intersected_ties(bi: BundleInput, rays: np.ndarray, sub: np.ndarray, X: np.ndarray) -> np.ndarray:
    """X with the tie points of observations `sub` (of a bundle input) intersected from those observations' rays
    (camera frame, one per observation of the input) at the input's poses; control points and ties whose rays
    do not meet in front stay."""
    X = X.copy()
    if not len(sub):
        return X
    order = sub[np.argsort(bi.obs_point[sub], kind="stable")]
    pts, starts = np.unique(bi.obs_point[order], return_index=True)
    oi = bi.obs_image[order]
    Xp, angle, in_front = triangulate_tracks(bi.C_world[oi], bi.R_world_to_cam[oi], rays[order], starts)
    tie = ~np.isfinite(np.asarray(bi.point_prior, float)).all(1)[pts]
    ok = tie & in_front & (angle > 0.0) & np.isfinite(Xp).all(1)
    X[pts[ok]] = Xp[ok]
    return X


def _cut_ties(adj: _Adjuster, rows: np.ndarray, point: np.ndarray, residuals_px: np.ndarray, k: float,
              msgs: list[str], dropped: list[dict]) -> int:
    """Drop tie observations `rows` (of the block) whose standardised residual (px residuals of their points
    `point`) exceeds k robust sigmas (the scale from the median, so a pass full of mismatches
    does not loosen the cut); how many."""
    b, opt = adj.blk, adj.opt
    # standardised by the approximate redundancy of a ray of a point seen L times (its 3 coordinates are
    # shared by the 2L residuals): a blunder in one of few rays is half absorbed by the point
    L = np.bincount(point, minlength=int(point.max(initial=-1)) + 1)[point]
    r_approx = np.clip(1.0 - 1.5 / np.maximum(L, 1), 0.1, 1.0)
    e = np.linalg.norm(residuals_px / b.sig[rows], axis=1) / np.sqrt(r_approx)
    s_rob = max(float(np.median(e)) / _CHI2_MEDIAN_2D, 1.0)
    tie = b.kind[b.op[rows]] != "control"
    bad = tie & (e > k * s_rob)
    if not bad.any():
        return 0
    for r in np.flatnonzero(bad):
        fin = np.isfinite(residuals_px[r]).all()
        dropped.append({"image": b.images[b.oi[rows[r]]], "id": b.point_ids[b.op[rows[r]]], "reason": "outlier",
                        "residual_px": [float(v) for v in residuals_px[r]] if fin else None,
                        "standardised": float(e[r]) if fin else None})
    adj.active[rows[bad]] = False
    _warn(msgs, f"{int(bad.sum())} tie observation(s) beyond {k:g} robust sigmas ({k * s_rob:.1f} sigma) "
                "dropped (listed in the summary)", opt.verbose)
    return int(bad.sum())


def equivalent_w(T: float, dof: int) -> float:
    """The |w| of a one-dimensional test with the same false-alarm probability as the chi-square statistic T
    with `dof` degrees of freedom (two-sided; finite for any T, through log probabilities)."""
    with np.errstate(divide="ignore"):
        log_p = np.log(chdtrc(dof, T))   # chi2.logsf
    if not np.isfinite(log_p):   # far in the tail: the leading term of the upper incomplete gamma function
        log_p = -T / 2 + (dof / 2 - 1) * np.log(T / 2) - gammaln(dof / 2)
    return float(-ndtri_exp(log_p + np.log(0.5)))


def _snoop_control(adj: _Adjuster, msgs: list[str], suspects: list[Suspect], apply: bool) -> bool:
    """One round of data snooping on the control: w-tests of each image measurement of a control point and a
    3-dof test of each control point's coordinates (as an equivalent |w|). Removes the worst group when it
    exceeds the critical value (the measurement, or the point's coordinates: it becomes a tie point)."""
    res, b, opt = adj.res, adj.blk, adj.opt
    k = adj.obs_keep
    ctrl_obs = np.flatnonzero(adj.is_prior[b.op[k]])
    cand = []
    if len(ctrl_obs):
        w = res.standardized_residuals(ctrl_obs)
        r = res.redundancy_numbers(ctrl_obs)
        testable = r > 0.02
        w_obs = np.where(testable, np.abs(w), 0.0).max(1)
        for n, wk in zip(ctrl_obs, w_obs):
            if wk > opt.critical_w:
                cand.append((float(wk), "measurement", int(n), float(r[ctrl_obs == n].min())))
    # coordinate groups: residuals of the prior block (rows per coordinate) with their 3x3 cofactors
    blocks = adj.res.covariance.problem.blocks
    ib = next((i for i, blk in enumerate(blocks) if isinstance(blk, PointPriors)), None)
    if ib is not None and len(blocks[ib]) and not opt.fixed_gcps:
        ev = adj.res.covariance.normals.evals[ib]
        prior_block = blocks[ib]
        pts_local = np.unique(prior_block.point)
        Q = adj.res.covariance.point_cofactors(pts_local)
        for j_loc, Qj in zip(pts_local, Q):
            rows = np.flatnonzero(prior_block.point == j_loc)
            if len(rows) < 3 or not np.isfinite(Qj).all():
                continue
            axes = prior_block.axis[rows]
            wgt = prior_block.w[rows]
            Wq = np.diag(wgt) @ Qj[np.ix_(axes, axes)] @ np.diag(wgt)
            Qvv = np.eye(len(rows)) - Wq                      # cofactor of the whitened coordinate residuals
            v = ev.r[rows, 0]
            try:
                T = float(v @ np.linalg.solve(Qvv, v))
            except np.linalg.LinAlgError:
                continue
            if min(np.linalg.eigvalsh(Qvv)) < 0.02:
                continue                                      # the coordinates are not checked by the rays
            w_eq = equivalent_w(T, len(rows))
            if w_eq > opt.critical_w:
                cand.append((w_eq, "coordinates", int(adj.pt_keep[j_loc]), float(min(np.diag(Qvv)))))
    cand += _centre_candidates(adj)
    if not cand:
        return False
    cand.sort(key=lambda c: -c[0])
    if not apply:
        for wk, what, idx, red in cand:
            suspects.append(_suspect(adj, what, idx, wk, red, removed=False))
        return False
    wk, what, idx, red = cand[0]
    s = _suspect(adj, what, idx, wk, red, removed=True)
    suspects.append(s)
    if what == "measurement":
        adj.active[k[idx]] = False
        _warn(msgs, f"measurement of control point {s.point} in {s.image} rejected as a blunder "
                    f"(standardised residual {wk:.1f})", opt.verbose)
    elif what == "centre":
        adj.cprior[idx] = np.nan
        d = s.coordinate_error_m
        _warn(msgs, f"camera centre of {s.image} rejected as a blunder (test {wk:.1f} as |w|; the adjusted centre is "
                    f"{d[0]:+.3f}/{d[1]:+.3f}/{d[2]:+.3f} m E/N/Up from it): the image is kept on its rays",
              opt.verbose)
    else:
        adj.is_prior[idx] = False
        _warn(msgs, f"coordinates of control point {s.point} rejected as a blunder (test {wk:.1f} as |w|): "
                    "the point is kept as a tie point and its coordinates are compared afterwards", opt.verbose)
    return True


def _centre_candidates(adj: _Adjuster) -> list[tuple[float, str, int, float]]:
    """Camera centres whose 3-dof test (whitened residuals over their cofactor, `T = v' Qvv^-1 v`, as an equivalent
    |w|) exceeds the critical value: (w, "centre", image index of the block, smallest redundancy)."""
    if adj.cprior is None or not adj.opt.reject_blunders:
        return []
    res = adj.res
    cp, cs = adj.cprior[adj.img_keep], adj.csig[adj.img_keep]
    have = np.flatnonzero(np.isfinite(cp).all(1))
    if len(have) < 4:
        return []
    off = adj.opt.antenna_offset_cam
    pred = res.C_world[have].copy()
    if off is not None:
        pred += np.swapaxes(res.R_world_to_cam[have], -1, -2) @ np.asarray(off, float)
    if res.n_flights:
        pred += res.flight_shift[adj.flight[adj.img_keep][have]]
    v = (pred - cp[have]) / cs[have]
    Q = res.covariance.pose_cofactors()[have][:, :3, :3]
    W = 1.0 / cs[have]
    Qvv = np.eye(3)[None] - W[:, :, None] * Q * W[:, None, :]   # the antenna's cofactor taken as the centre's
    out = []
    for i, (vi, Qi) in enumerate(zip(v, Qvv)):
        if not np.isfinite(Qi).all() or np.linalg.eigvalsh(Qi).min() < 0.02:
            continue
        w_eq = equivalent_w(float(vi @ np.linalg.solve(Qi, vi)), 3)
        if w_eq > adj.opt.critical_w:
            out.append((w_eq, "centre", int(adj.img_keep[have[i]]), float(np.diag(Qi).min())))
    return out


def _suspect(adj: _Adjuster, what: str, idx: int, w: float, red: float, removed: bool) -> Suspect:
    b = adj.blk
    if what == "centre":
        i_loc = int(np.searchsorted(adj.img_keep, idx))
        d = adj.res.C_world[i_loc] - adj.cprior[idx]
        return Suspect(b.images[idx], "", (float("nan"), float("nan")), w, red, removed, kind="centre",
                       coordinate_error_m=tuple(float(v) for v in d))
    if what == "measurement":
        row = adj.obs_keep[idx]
        return Suspect(b.images[b.oi[row]], b.point_ids[b.op[row]], tuple(adj.res.residuals_px[idx]), w, red,
                       removed, kind="measurement")
    j_loc = int(np.searchsorted(adj.pt_keep, idx))
    d = adj.res.X_world[j_loc] - b.X_prior[idx]
    return Suspect("", b.point_ids[idx], (float("nan"), float("nan")), w, red, removed, kind="coordinates",
                   coordinate_error_m=tuple(float(v) for v in d))


def _leave_out_thin_images(adj: _Adjuster, msgs: list[str]) -> bool:
    """Images the cleaning left with fewer than MIN_IMAGE_POINTS points: each named and left out for good (its
    pose would rest on a handful of rays no test can check, with sigmas that do not show it); True if any."""
    b = adj.blk
    adj.bundle_input()          # the observations the next adjustment would use (after the latest cuts)
    n_pts = np.bincount(b.oi[adj.obs_keep], minlength=len(b.images))
    thin = np.flatnonzero(adj.oriented & ~adj.excluded & (n_pts < MIN_IMAGE_POINTS))
    if not len(thin):
        return False
    n_meas = np.bincount(b.oi, minlength=len(b.images))
    for i in thin:
        _warn(msgs, f"image {b.images[i]} kept {int(n_pts[i])} of its {int(n_meas[i])} measurements after the "
                    f"outliers were dropped (fewer than {MIN_IMAGE_POINTS} points): left out, its orientation would "
                    "rest on rays that nothing checks", adj.opt.verbose)
    adj.excluded[thin] = True
    adj.oriented[thin] = False
    return True


def _adjust_and_clean(adj: _Adjuster, msgs: list[str]) -> tuple[list[Suspect], list[dict], dict]:
    """Adjust, drop tie outliers, retry left-out images, snoop the control until clean (see the module doc)."""
    opt = adj.opt
    suspects: list[Suspect] = []
    dropped: list[dict] = []
    rounds = {"adjustments": 0, "tie_rounds": 0, "retries": 0, "snooping": 0}
    if (adj.blk.kind != "control").any() and _drop_gross_ties_at_start(adj, msgs, dropped):
        rounds["tie_rounds"] += 1
    adj.run()
    rounds["adjustments"] += 1
    for _ in range(6):
        changed = False
        if np.isfinite(adj.res.sigma0) and (adj.blk.kind != "control").any() and _drop_tie_outliers(adj, msgs, dropped):
            rounds["tie_rounds"] += 1
            changed = True
        if _leave_out_thin_images(adj, msgs):
            changed = True
        if (~adj.oriented).any() and adj.retry_left_out(msgs):
            rounds["retries"] += 1
            changed = True
        if not changed:
            break
        adj.run()
        rounds["adjustments"] += 1
    for _ in range(opt.max_rejections if opt.reject_blunders else 0):
        if not _snoop_control(adj, msgs, suspects, apply=True):
            break
        rounds["snooping"] += 1
        adj.run()
        rounds["adjustments"] += 1
        if control_disagrees(*rejected_control(adj.blk, suspects)):
            # the control as a whole disagrees (a unit, a CRS): snooping on would only hide it (and cost minutes)
            _warn(msgs, "data snooping stopped: more than a third of the control points rejected", opt.verbose)
            break
    # what is left above the critical value (not removed: the cap was reached, or rejection is off)
    _snoop_control(adj, msgs, suspects, apply=False)
    return suspects, dropped, rounds


def triangulate(camera: CameraModel, points: Points, meas: Measurements, crs: str | None,
                options: TriangulationOptions | None = None, image_size: tuple[int, int] | None = None,
                approx: EOP | None = None, centre_priors: EOP | None = None,
                all_images: list[str] | None = None, centre_flights: np.ndarray | None = None) -> TriangulationResult:
    """Aerial triangulation: EOPs (map CRS, PATB deg) with covariance from ground points and measurements (px).

    `meas` holds control, check and tie measurements (ids not in `points` are tie points). `approx`
    (map CRS) gives approximate EOPs where known, `centre_priors` GNSS centres with sigmas (sX..sZ).
    `all_images` lists images that should be oriented (those without measurements are reported).
    Raises `ResultError` when the result cannot be trusted (see `TriangulationOptions`), unless `accept_poor`.
    """
    opt = options or TriangulationOptions()
    clock = {"start": time.perf_counter()}
    msgs: list[str] = []
    _check_measurements(camera, meas, image_size)
    check_as_tie = (all_images is None) if opt.check_as_tie is None else bool(opt.check_as_tie)
    geo, P_world = _georef(points, meas, crs, opt, centre_priors)
    if opt.flight_shift and not _control_measured(points, meas):
        raise InputError("a shift of the camera centres per flight needs measured control points: with the centres "
                         "alone the shift is the datum itself", meas.path, field="flight_shift")
    blk = _block(points, P_world, meas, opt, check_as_tie, all_images, msgs,
                 has_centres=len(centres_in_block(centre_priors, meas)) > 0)
    unknown_ids = sorted(set(meas.id.astype(str)) - set(points.ids.astype(str)))
    clock["prepared"] = time.perf_counter()
    R_world_to_cam_0, C_world_0 = _approx_poses(_approx_with_centre_angles(approx, centre_priors), geo, blk.images)
    cprior, csig = _centre_priors(centre_priors, geo, blk.images)   # (n,3) world, NaN where an image has none
    _warn_unmatched_centres(centre_priors, blk.images, cprior, msgs, opt.verbose)
    init = initial_orientation(camera, blk.images, blk.oi, blk.op, blk.uv, blk.X_prior, R_world_to_cam_0, C_world_0,
                               use_mapper=opt.use_mapper, C_world_prior=cprior)
    for note in init.notes:
        _warn(msgs, note, opt.verbose)
    if not init.oriented.any():
        _emit(msgs)
        raise InputError("no image could be oriented: each needs >= 4 control points, or tie points shared with "
                         "oriented images, or approximate EOPs"
                         + ("" if np.isfinite(blk.X_prior).all(1).any() or cprior is None else
                            " (the camera centres did not start the orientation either: too few tie points shared "
                            "between neighbouring images? give --approx EOPs, or angles in the centres file)"),
                         meas.path)
    clock["initialised"] = time.perf_counter()
    adj = _Adjuster(camera, blk, init.R_world_to_cam, init.C_world, init.oriented, init.X_world, init.point_ok,
                    cprior, csig, opt)
    if opt.flight_shift and cprior is not None:
        adj.flight, adj.flight_names = _flights(centre_priors, centre_flights, blk.images)
    suspects, dropped, rounds = _adjust_and_clean(adj, msgs)
    res = adj.res
    lone = np.flatnonzero(adj.lone)
    if len(lone):
        dropped += [{"image": blk.images[blk.oi[r]], "id": blk.point_ids[blk.op[r]], "reason": "no other ray left",
                     "residual_px": None, "standardised": None} for r in lone]
        _warn(msgs, f"{len(lone)} tie observation(s) left out: their point has no other usable ray", opt.verbose)
    clock["adjusted"] = time.perf_counter()
    images_k = [blk.images[i] for i in adj.img_keep]
    for i in np.flatnonzero(~adj.oriented & ~adj.excluded):
        nm = int(np.sum(blk.oi == i))
        _warn(msgs, f"image {blk.images[i]} could not be oriented ({nm} usable measurements): left out"
              if nm else f"image {blk.images[i]} has no measurements: left out", opt.verbose)
    datum = _datum_diagnostics(res, adj, msgs)
    out = _outputs(camera, res, adj, geo, points, meas, images_k, blk, msgs, opt, suspects, unknown_ids, P_world)
    out.summary.update(datum)
    out.dropped = dropped
    out.summary.update({"initial_orientation": init.method, "rounds": rounds, "adjustment_runs": adj.runs,
                        "n_dropped_tie_observations": len(dropped), "dropped_tie_observations": dropped[:1000]})
    out.problems = _problems(res, adj, blk, opt, suspects)
    out.summary["problems"] = out.problems
    out.summary["trusted"] = not out.problems
    clock["done"] = time.perf_counter()
    names = list(clock)
    out.summary["timings_s"] = {f"{b}": round(clock[b] - clock[a], 3) for a, b in zip(names, names[1:])}
    out.summary["timings_s"].update(init.seconds)
    if opt.verbose:
        print(f"sigma0 {res.sigma0:.3f}, {len(images_k)} images, {len(adj.pt_keep)} points, "
              f"redundancy {res.redundancy}")
    _emit(msgs)
    if out.problems and not opt.accept_poor:
        raise ResultError("triangulation not trusted: " + "; ".join(out.problems)
                          + " (--accept-poor writes it anyway)", meas.path)
    return out


def _emit(msgs: list[str]) -> None:
    """Each warning once through Python's `warnings` (UserWarning): a library user sees what the CLI reports."""
    for text in dict.fromkeys(msgs):
        warnings.warn(text, UserWarning, stacklevel=3)


def _datum_diagnostics(res: BundleResult, adj: _Adjuster, msgs: list[str]) -> dict:
    """The summary's `datum` (what fixes position, scale and rotation, and how precisely: `dgcal.bundle.datum`),
    `f_height` (the focal length-height correlation when f is refined) and `principal_point` (cx/cy with the
    horizontal datum when they are refined); their warnings added to `msgs`."""
    b = adj.blk
    C_src = cs = np.zeros((0, 3))
    if adj.cprior is not None:
        cp, cs = adj.cprior[adj.img_keep], adj.csig[adj.img_keep]
        have = np.isfinite(cp).all(1)
        C_src, cs = cp[have], cs[have]
    ctrl = adj.pt_keep[adj.is_prior[adj.pt_keep]]
    G_src, gs = b.X_prior[ctrl], b.S_prior[ctrl]
    stmt = datum_statement(C_src, cs, G_src, gs)
    if stmt["not_fixed"]:
        _warn(msgs, "datum: " + stmt["text"], adj.opt.verbose)
    d = np.linalg.norm(res.X_world[res.obs_point] - res.C_world[res.obs_image], axis=1)
    gsd = float(np.median(d)) / float(res.camera["f"]) if len(d) else 0.0
    ref = reference_sigma_m(cs if len(cs) else None, gs if len(gs) else None, gsd)
    precision, warn = weak_datum(res, ref)
    stmt["precision"] = precision
    adj.datum = stmt
    for w in warn:
        _warn(msgs, w, adj.opt.verbose)
    centre_model = None
    if adj.cprior is not None:
        centre_model = {"antenna_offset_cam_m": None if adj.opt.antenna_offset_cam is None
                        else [float(v) for v in adj.opt.antenna_offset_cam], "flight_shift": []}
        if res.n_flights:
            cov = res.cov_flight_shift
            for f in range(res.n_flights):
                used = adj.flight[adj.img_keep] == f
                name = adj.flight_names[f] if f < len(adj.flight_names) else str(f)
                centre_model["flight_shift"].append({
                    "flight": name, "n_images": int(used.sum()), "shift_ENU_m": res.flight_shift[f].tolist(),
                    "sigma_ENU_m": np.sqrt(np.clip(np.diag(cov[f]), 0, None)).tolist()})
            stmt["text"] += (f"; a shift of the centres estimated per flight ({res.n_flights}): their position "
                             "comes from the GCPs")
    fh = focal_height_correlation(res)
    pp = principal_point_correlation(res)
    for w in (focal_height_warning(fh), principal_point_warning(pp)):
        if w:
            _warn(msgs, w, adj.opt.verbose)
    return {"datum": stmt, "f_height": fh, "principal_point": pp, "centre_model": centre_model}


def rejected_control(blk: _Block, suspects: list[Suspect]) -> tuple[int, int]:
    """(control points the images reject, control points): a point is rejected when its coordinates go, or most of
    its measurements (single bad clicks are blunders)."""
    ctrl = {blk.point_ids[j] for j in np.flatnonzero(np.isfinite(blk.X_prior).all(1))}
    n_obs = dict(zip(blk.point_ids, np.bincount(blk.op, minlength=len(blk.point_ids)).tolist()))
    meas_rej: dict[str, int] = {}
    for s_ in suspects:
        if s_.removed and s_.kind == "measurement" and s_.point in ctrl:
            meas_rej[s_.point] = meas_rej.get(s_.point, 0) + 1
    n_rej = len({s_.point for s_ in suspects if s_.removed and s_.kind == "coordinates" and s_.point in ctrl}
                | {p for p, k in meas_rej.items() if k > 0.5 * n_obs.get(p, 0)})
    return n_rej, len(ctrl)


def control_disagrees(n_rej: int, n_ctrl: int) -> bool:
    """More control rejected than single blunders explain: the control as a whole disagrees with the images."""
    return bool(n_ctrl) and n_rej >= 2 and n_rej > MAX_REJECTED_CONTROL * n_ctrl


def _problems(res: BundleResult, adj: _Adjuster, blk: _Block, opt: TriangulationOptions,
              suspects: list[Suspect] = ()) -> list[str]:
    """Why the result cannot be trusted (empty when it can)."""
    out = []
    if not res.converged:
        out.append(f"the adjustment did not converge ({res.stop_reason})")
    n_centres = 0 if adj.cprior is None else int(np.isfinite(adj.cprior).all(1).sum())
    n_c_rej = sum(1 for s_ in suspects if s_.removed and s_.kind == "centre")
    if n_c_rej >= 2 and n_c_rej > MAX_REJECTED_CONTROL * (n_centres + n_c_rej):
        out.append(f"{n_c_rej} of {n_centres + n_c_rej} camera centres were rejected as blunders: so many point to "
                   "the centres as a whole (another CRS or height reference? an antenna offset? a time shift?)")
    datum = adj.datum
    if datum is not None and datum["not_fixed"]:
        out.append(f"the datum is not fixed: {datum['text']}")
    capped = sum(not r["converged"] for r in adj.runs)
    if res.converged and capped > len(adj.runs) / 2:
        out.append(f"{capped} of {len(adj.runs)} adjustments stopped at their iteration limit (the start was far "
                   "from the solution, or the block does not fit together)")
    if not np.isfinite(res.sigma0) or res.sigma0 > opt.max_sigma0:
        out.append(f"sigma0 {res.sigma0:.2f} exceeds {opt.max_sigma0:g} (measurement sigmas or data inconsistent)")
    # images connected to the block: >= 10 observations of points that other images see too
    n_img = np.bincount(blk.op, minlength=len(blk.point_ids))
    shared = n_img[blk.op] >= 2
    connected = np.bincount(blk.oi[shared], minlength=len(blk.images)) >= 10
    left = connected & ~adj.oriented
    if connected.any() and left.sum() > opt.max_left_out * connected.sum():
        out.append(f"{int(left.sum())} of {int(connected.sum())} connected images left out "
                   f"(more than {opt.max_left_out:.0%})")
    # control points the images reject (their coordinates or their measurements): one is a blunder, many are a wrong
    # datum or unit
    n_rej, n_ctrl = rejected_control(blk, suspects)
    if control_disagrees(n_rej, n_ctrl):
        out.append(f"{n_rej} of {n_ctrl} control points had their coordinates or measurements rejected as "
                   "blunders: so many disagreeing with the images point to their coordinates as a whole (heights "
                   "in feet? another CRS, datum or vertical reference? a shifted file?), not to single blunders")
    return out



def _outputs(camera, res: BundleResult, adj: _Adjuster, geo: World, points: Points, meas: Measurements,
             images_k: list[str], blk: _Block, msgs: list[str], opt: TriangulationOptions, suspects: list[Suspect],
             unknown_ids: list[str], P_world: np.ndarray) -> TriangulationResult:
    """EOPs in the map CRS, per-image figures, control and check point reports, the summary."""
    pidx = points.index()
    pids_k = [blk.point_ids[j] for j in adj.pt_keep]
    kind_k = blk.kind[adj.pt_keep]
    prior_k = adj.is_prior[adj.pt_keep]
    geo_xyz, geo_opk, cov_map = geo.poses_to_eop(res.poses)
    sig_map = np.sqrt(np.clip(np.diagonal(cov_map, axis1=1, axis2=2), 0, None))
    eop = EOP(np.array(images_k, dtype=object), geo_xyz, geo_opk, sig_map, cov_map)
    a_oi, a_op = res.obs_image, res.obs_point
    image_stats = []
    for i, name in enumerate(images_k):
        kk = np.flatnonzero(a_oi == i)
        r = res.residuals_px[kk]
        image_stats.append({"image": name, "n_obs": int(len(kk)), "n_control": int(np.sum(prior_k[a_op[kk]])),
                            "rms_px": float(np.sqrt(np.mean(np.sum(r ** 2, 1)))) if len(kk) else float("nan"),
                            "sigma": sig_map[i].tolist()})
    ctrl_rows = np.flatnonzero(prior_k[a_op])
    w_std = res.standardized_residuals(ctrl_rows) if len(ctrl_rows) else np.zeros((0, 2))
    r_num = res.redundancy_numbers(ctrl_rows) if len(ctrl_rows) else np.zeros((0, 2))
    X_map = geo.to_map(res.X_world) if len(res.X_world) else np.zeros((0, 3))
    removed = {(s.image, s.point) for s in suspects if s.removed and s.kind == "measurement"}
    k_of = {p: j for j, p in enumerate(pids_k)}
    for s_ in suspects:
        if s_.kind == "coordinates" and s_.point in k_of:
            # the rejected coordinates against the point as the final adjustment places it (grid E, N, Up)
            j = k_of[s_.point]
            R_world_to_grid = geo.R_world_to_grid_at(res.X_world[j][None])[0]
            d_grid = R_world_to_grid @ (res.X_world[j] - P_world[pidx[s_.point]])
            s_.coordinate_error_m = tuple(float(v) for v in d_grid)
    gcp_rep = []
    for j, pid in enumerate(pids_k):
        if kind_k[j] != "control":
            continue
        r = pidx[pid]
        kk = np.flatnonzero(a_op == j)
        R_world_to_grid = geo.R_world_to_grid_at(res.X_world[j][None])[0]
        meas_rep = []
        if prior_k[j]:
            pos = np.searchsorted(ctrl_rows, kk)
            meas_rep = [{"image": images_k[a_oi[k]], "residual_px": res.residuals_px[k].tolist(),
                         "w": float(np.max(np.abs(w_std[p]))), "redundancy": float(r_num[p].min()),
                         "rejected": False} for k, p in zip(kk, pos)]
        rejected_meas = [{"image": im, "residual_px": None, "w": None, "redundancy": None, "rejected": True}
                         for im, p in sorted(removed) if p == pid]
        gcp_rep.append({"id": pid, "n_images": int(len(kk)), "xyz": points.xyz[r].tolist(),
                        "adjusted": X_map[j].tolist(),
                        "dENU_m": (R_world_to_grid @ (res.X_world[j] - P_world[r])).tolist(),
                        "coordinates_used": bool(prior_k[j]),
                        "rms_px": float(np.sqrt(np.mean(np.sum(res.residuals_px[kk] ** 2, 1)))) if len(kk) else None,
                        "measurements": meas_rep + rejected_meas})
    k_index = {p: j for j, p in enumerate(pids_k)}
    n_rays = np.bincount(a_op, minlength=len(pids_k))
    counts = dict(zip(*np.unique(meas.id.astype(str), return_counts=True)))
    unknown_rep = [{"id": pid, "n_images": int(n_rays[k_index[pid]]), "xyz": X_map[k_index[pid]].tolist()}
                   if pid in k_index else {"id": pid, "n_images": int(counts.get(pid, 0)), "xyz": None}
                   for pid in unknown_ids]
    check_rep = _check_points(camera, res, geo, points, meas, images_k, pids_k, kind_k, msgs, opt)
    summary = _summary(res, eop, blk.images, images_k, gcp_rep, check_rep, unknown_rep, suspects, msgs, geo, kind_k)
    return TriangulationResult(eop, geo, res, res.camera, images_k, pids_k, kind_k, gcp_rep, check_rep, image_stats,
                               suspects, msgs, unknown_ids, summary, res.R_world_to_cam, res.C_world)


def _check_points(camera, res: BundleResult, geo: World, points: Points, meas: Measurements, images_k: list[str],
                  pids_k: list[str], kind_k: np.ndarray, msgs: list[str], opt) -> list[dict]:
    """Check-point errors (evaluated - given) and sigmas in grid E, N, Up: from the adjustment where they were tie
    points, else intersected from the adjusted images (pixel and pose covariance)."""
    pidx = points.index()
    role = {str(k): str(r) for k, r in zip(points.ids, points.role)}
    ids = list(dict.fromkeys(str(i) for i in meas.id.astype(str) if role.get(i) == "check"))
    k_index = {p: j for j, p in enumerate(pids_k)}
    out = []
    todo = [p for p in ids if p not in k_index]
    ir_rows = {}
    if todo:
        im_idx = {n: i for i, n in enumerate(images_k)}
        want = set(todo)
        rows = np.array([r for r in range(len(meas)) if str(meas.id[r]) in want and str(meas.image[r]) in im_idx], int)
        pid_of = {p: j for j, p in enumerate(todo)}
        if len(rows):
            oi = np.array([im_idx[str(meas.image[r])] for r in rows])
            op = np.array([pid_of[str(meas.id[r])] for r in rows])
            sig = np.where(np.isfinite(meas.sigma[rows]), meas.sigma[rows], opt.sigma_px)
            ir = intersect(camera, res.C_world, np.swapaxes(res.R_world_to_cam, -1, -2), oi, op, meas.xy[rows], sig,
                           n_points=len(todo))
            cov = ir.cov + propagate_pose_covariance(ir, np.nan_to_num(res.cov_pose))
            ir_rows = {p: (ir, cov, pid_of[p]) for p in todo}
    for pid in ids:
        if pid in k_index:
            j = k_index[pid]
            X = res.X_world[j]
            cov_j = res.point_covariance(j)[0]
            n_rays = int(np.sum(res.obs_point == j))
            rms = float(np.sqrt(np.mean(res.residuals_px[res.obs_point == j] ** 2)))
            how = "adjusted as a tie point"
        else:
            got = ir_rows.get(pid)
            n_rays = int(got[0].n_rays[got[2]]) if got else 0
            if got is None or not got[0].ok[got[2]]:
                why = ("needs 2" if n_rays < 2 else "the rays do not intersect in front of the cameras")
                _warn(msgs, f"check point {pid} is measured in {n_rays} oriented image(s): {why}, not evaluated",
                      opt.verbose)
                out.append({"id": pid, "n_images": n_rays, "evaluated": False})
                continue
            ir, cov, j = got
            X, cov_j, rms, how = ir.xyz[j], cov[j], float(ir.rms_px[j]), "intersected"
        given = geo.to_world(points.xyz[pidx[pid]][None])[0]
        R_world_to_grid = geo.R_world_to_grid_at(X[None])[0]
        d = R_world_to_grid @ (X - given)
        s = np.sqrt(np.clip(np.diag(R_world_to_grid @ cov_j @ R_world_to_grid.T), 0, None))
        survey = points.sigma[pidx[pid]]
        survey = np.where(np.isfinite(survey), survey, 0.0)
        total = np.hypot(s, survey)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(total > 0, d / total, np.nan)
        out.append({"id": pid, "n_images": n_rays, "evaluated": True, "how": how,
                    "xyz": points.xyz[pidx[pid]].tolist(), "intersected": geo.to_map(X[None])[0].tolist(),
                    "dENU_m": d.tolist(), "sigma_ENU_m": s.tolist(), "survey_sigma_ENU_m": survey.tolist(),
                    "sigma_total_ENU_m": total.tolist(), "normalised": z.tolist(), "rms_px": rms})
    return out


def _summary(res, eop, images, images_k, gcp_rep, check_rep, unknown_rep, suspects, msgs, geo, kind_k) -> dict:
    ev = [c for c in check_rep if c.get("evaluated")]
    d = np.array([c["dENU_m"] for c in ev]) if ev else np.zeros((0, 3))
    z = np.array([c["normalised"] for c in ev], float) if ev else np.zeros((0, 3))
    g = np.array([c["dENU_m"] for c in gcp_rep if c["coordinates_used"]]) if gcp_rep else np.zeros((0, 3))
    g = g.reshape(-1, 3)
    fin = np.isfinite(res.residuals_px).all(1)
    cam = res.camera
    return {
        "crs": geo.crs_text or "local", "sigma0": res.sigma0, "redundancy": res.redundancy,
        "converged": bool(res.converged), "iterations": int(res.iterations), "stop_reason": res.stop_reason,
        "n_images": len(images), "n_oriented": len(images_k), "n_control": len(gcp_rep),
        "n_tie_points": int(np.sum(kind_k == "tie")), "n_observations": int(fin.sum()),
        "rms_px": float(np.sqrt(np.mean(np.sum(res.residuals_px[fin] ** 2, 1)))),
        "control_rmse_m": {"E": _rms(g[:, 0]), "N": _rms(g[:, 1]), "U": _rms(g[:, 2])},
        "check_rmse_m": {"E": _rms(d[:, 0]), "N": _rms(d[:, 1]), "U": _rms(d[:, 2]),
                          "horizontal": _rms(np.hypot(d[:, 0], d[:, 1])) if len(d) else None, "n": len(d)},
        # error over (adjustment sigma (+) survey sigma), RMS per axis: near 1 when the sigmas are honest
        "check_normalised_rms": {k: _rms(z[:, j][np.isfinite(z[:, j])]) for j, k in enumerate("ENU")},
        "median_sigma": {k: float(np.median(eop.sigma[:, j])) for j, k in
                         enumerate(("X_m", "Y_m", "Z_m", "omega_deg", "phi_deg", "kappa_deg"))},
        "camera": {"model": cam.NAME, "refined": list(res.refine), "params": cam.as_dict(),
                   "sigmas": {k: float(s) for k, s in zip(res.refine, np.sqrt(np.diag(res.cov_intrinsics)))}},
        "n_unknown_ids": len(unknown_rep),
        "unknown_points": [u for u in unknown_rep if not str(u["id"]).startswith("tie_")][:200],
        "suspects": [s.as_dict() for s in suspects], "warnings": list(msgs),
    }


def _rms(v) -> float | None:
    v = np.asarray(v, float)
    return float(np.sqrt(np.mean(v ** 2))) if v.size else None
