"""Self-calibrating bundle adjustment: images x targets -> intrinsics, every image's pose, optionally targets.

Observation model (OpenCV camera frame, pixels as in docs/conventions.md)::

    X_cam = R_field_to_cam[i] @ X_field[j] + t[i]        uv_ij = camera.project(X_cam)

Unknowns: the free camera parameters, six pose parameters per image (a left rotation increment
R <- exp([d]x) R and t) and, optionally, the target coordinates — either as a free network with a
minimal datum (7 coordinates of three well-spread targets held, fixing position, orientation and scale,
which image observations cannot determine) or as weighted unknowns with their CSV sigmas as priors.
Levenberg-Marquardt on the normal equations with the targets eliminated (Schur complement, 3x3 blocks),
so the reduced system is only (intrinsics + 6 x images) wide. Outliers are rejected iteratively on the
robustly scaled residual norm. Covariances are sigma0^2 N^-1 with sigma0 from the final residuals.
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from dgcal.calib.camera.models import CameraModel, model_class
from dgcal.fields.errors import InputError

# median of the chi distribution with 2 degrees of freedom, in units of sigma
_CHI2_MEDIAN = float(np.sqrt(2 * np.log(2)))


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
    R_field_to_cam: np.ndarray             # (M,3,3)
    t_cam: np.ndarray                      # (M,3) m, X_cam = R X_field + t
    pose_sigma: np.ndarray                 # (M,6) rotation (deg, about camera axes) and translation (m)
    pose_cov: np.ndarray                   # (M,6,6) covariance of (rotation increment rad, t m)
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

    @property
    def n_observations(self) -> int:
        return int(self.used.sum())

    @property
    def n_rejected(self) -> int:
        return int((~self.used).sum())

    def per_image_rms(self) -> dict[str, float]:
        """RMS residual norm (px) of each image's used observations."""
        out = {}
        n2 = np.sum(self.residuals**2, axis=1)
        for i, name in enumerate(self.image_names):
            m = self.used & (self.obs_image == i)
            out[name] = float(np.sqrt(n2[m].mean())) if m.any() else float("nan")
        return out

    def camera_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Projection centres in the field frame (M,3) m, C = -R^T t, and their sigmas (M,3) m."""
        Rt = self.R_field_to_cam.transpose(0, 2, 1)
        C = -np.einsum("mab,mb->ma", Rt, self.t_cam)
        # C(R exp, t + dt) ~ C - R^T [t]x d - R^T dt for the left rotation increment d
        t = self.t_cam
        tx = np.zeros((len(t), 3, 3))
        tx[:, 0, 1], tx[:, 0, 2], tx[:, 1, 2] = -t[:, 2], t[:, 1], -t[:, 0]
        tx[:, 1, 0], tx[:, 2, 0], tx[:, 2, 1] = t[:, 2], -t[:, 1], t[:, 0]
        J = np.concatenate([-Rt @ tx, -Rt], axis=2)
        cov = J @ self.pose_cov @ J.transpose(0, 2, 1)
        return C, np.sqrt(np.maximum(np.einsum("mkk->mk", cov), 0))

    def camera_sigmas(self) -> dict[str, float]:
        """Sigma of every camera parameter by name (0 for fixed ones)."""
        return {k: float(s) for k, s in zip(self.camera.PARAMS, np.sqrt(np.maximum(np.diag(self.cov_camera), 0)))}


# ---------------------------------------------------------------------------------------------
def _skew_batch(v: np.ndarray) -> np.ndarray:
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def _tdot(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A_n^T B_n for stacks of 2-row matrices (n,2,a), (n,2,b) -> (n,a,b); faster than batched matmul."""
    return A[:, 0, :, None] * B[:, 0, None, :] + A[:, 1, :, None] * B[:, 1, None, :]


def _group_sum(values: np.ndarray, idx: np.ndarray, n: int) -> np.ndarray:
    """Sums of `values` (k, ...) over equal `idx` into (n, ...), via a sparse indicator product."""
    G = sp.csr_matrix((np.ones(len(idx)), (idx, np.arange(len(idx)))), shape=(n, len(idx)))
    return np.asarray(G @ values.reshape(len(idx), -1)).reshape((n,) + values.shape[1:])


def _plane_frame(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Centroid, rotation field->plane (rows = plane axes) and whether the points are (nearly) planar."""
    c = xyz.mean(axis=0)
    _, s, Vt = np.linalg.svd(xyz - c, full_matrices=False)
    if np.linalg.det(Vt) < 0:
        Vt[2] *= -1
    planar = s[2] <= 1e-3 * s[0]
    return c, Vt, bool(planar)


def _pnp(obj: np.ndarray, img: np.ndarray, K: np.ndarray, planar: bool, thresh_px: float):
    """Pose (R_obj_to_cam, t) and inlier mask of one image by RANSAC PnP with a distortion-free K."""
    import cv2
    obj32 = np.ascontiguousarray(obj, np.float64)
    img32 = np.ascontiguousarray(img, np.float64)
    flags = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_EPNP
    try:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(obj32, img32, K, None, iterationsCount=200,
                                                 reprojectionError=thresh_px, confidence=0.999, flags=flags)
    except cv2.error:
        ok = False
    if not ok or inl is None or len(inl) < 6:
        return None
    mask = np.zeros(len(obj), bool)
    mask[inl.ravel()] = True
    ok, rvec, tvec = cv2.solvePnP(obj32[mask], img32[mask], K, None, rvec, tvec, True, cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return None
    R = cv2.Rodrigues(rvec)[0]
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(tvec))):
        return None
    if np.median((obj[mask] @ R.T + tvec.ravel())[:, 2]) <= 0:
        return None
    return R, tvec.ravel(), mask


def _focal_guess(groups, xyz, image_size, planar, plane_xyz) -> float:
    """Initial focal length (px): OpenCV's homography estimate for planar fields, else a PnP focal sweep."""
    import cv2
    w, h = image_size
    if planar:
        try:
            objs = [plane_xyz[j].astype(np.float32) for _, j, _ in groups[:40]]
            imgs = [uv.astype(np.float32) for _, _, uv in groups[:40]]
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
            R, t, _ = pose
            Xc = xyz[j] @ R.T + t
            proj = Xc[:, :2] / Xc[:, 2:3] * f + K[:2, 2]
            errs.append(np.median(np.linalg.norm(proj - uv, axis=1)))
        score = np.median(errs)
        if score < best[0]:
            best = (score, float(f))
    return best[1]


# ---------------------------------------------------------------------------------------------
class _Problem:
    """The adjustment's state and its linearisation."""

    def __init__(self, camera, free_cam, R, t, X, X0, pt_prior_w, pt_free, img, pt, xy, sig):
        self.camera, self.free_cam = camera, free_cam
        self.R, self.t, self.X = R, t, X
        self.X0, self.pt_prior_w, self.pt_free = X0, pt_prior_w, pt_free   # (N,3) prior weights 1/sigma, free mask
        self.img, self.pt, self.xy, self.sig = img, pt, xy, sig
        self.refine = bool(pt_free.any())

    def residuals(self, active, camera=None, R=None, t=None, X=None):
        camera = self.camera if camera is None else camera
        R, t, X = (self.R if R is None else R), (self.t if t is None else t), (self.X if X is None else X)
        i, j = self.img[active], self.pt[active]
        Xc = np.einsum("nab,nb->na", R[i], X[j]) + t[i]
        r = (camera.project(Xc) - self.xy[active]) / self.sig[active]
        rp = ((X - self.X0) * self.pt_prior_w)[self.pt_free & (self.pt_prior_w > 0)] if self.refine else np.zeros(0)
        return r, rp, Xc

    def cost(self, active, **kw) -> float:
        r, rp, Xc = self.residuals(active, **kw)
        if np.any(Xc[:, 2] <= 0) or not np.all(np.isfinite(r)):
            return np.inf
        return float(np.sum(r * r) + np.sum(rp * rp))

    def normal_equations(self, active, M, N) -> "_Normals":
        """Blocks of J^T J and J^T r: camera, per-image pose blocks, camera-pose coupling, and the targets."""
        i, j = self.img[active], self.pt[active]
        Xr = np.einsum("nab,nb->na", self.R[i], self.X[j])
        Xc = Xr + self.t[i]
        uv, Jp, JX = self.camera.project_with_jacobians(Xc)
        w = 1.0 / self.sig[active]
        r = (uv - self.xy[active]) * w                                    # (n,2)
        JX = JX * w[:, :, None]
        Jc = (Jp * w[:, :, None])[:, :, self.free_cam]                    # (n,2,P)
        Jpose = np.concatenate([-JX @ _skew_batch(Xr), JX], axis=2)       # (n,2,6)
        P = Jc.shape[2]
        ne = _Normals(P=P, M=M, N=N)
        Jc2 = Jc.reshape(-1, P)
        ne.Acc = Jc2.T @ Jc2
        ne.gc = Jc2.T @ r.reshape(-1)
        # per-image blocks by one BLAS product per image (observations sorted by image)
        perm = np.argsort(i, kind="stable")
        bounds = np.searchsorted(i[perm], np.arange(M + 1))
        ne.U = np.zeros((M, 6, 6))
        ne.W = np.zeros((M, P, 6))
        ne.gpose = np.zeros((M, 6))
        for m in range(M):
            rows = perm[bounds[m]:bounds[m + 1]]
            if len(rows) == 0:
                continue
            Jp_m = Jpose[rows].reshape(-1, 6)
            ne.U[m] = Jp_m.T @ Jp_m
            ne.W[m] = Jc[rows].reshape(-1, P).T @ Jp_m
            ne.gpose[m] = Jp_m.T @ r[rows].reshape(-1)
        ne.cost = float(np.sum(r * r))
        if not self.refine:
            return ne
        Jx = (JX @ self.R[i]) * self.pt_free[j][:, None, :]               # (n,2,3)
        nu = P + 6 * M
        # coupling (camera + poses) x targets as a dense (nu, N, 3) array: camera rows are full anyway
        Bd = np.zeros((nu, N, 3))
        Bd[:P] = _group_sum(_tdot(Jc, Jx), j, N).transpose(1, 0, 2)
        Bd[P + 6 * i[:, None] + np.arange(6), j[:, None], :] = _tdot(Jpose, Jx)
        ne.B = Bd.reshape(nu, 3 * N)
        ne.V = _group_sum(_tdot(Jx, Jx), j, N)
        gp = _group_sum(Jx[:, 0] * r[:, :1] + Jx[:, 1] * r[:, 1:], j, N)
        wp = np.where(self.pt_free, self.pt_prior_w, 0.0)
        ne.V[:, [0, 1, 2], [0, 1, 2]] += wp**2
        gp += wp**2 * (self.X - self.X0)
        # held coordinates: a unit diagonal keeps the blocks invertible, their zero gradient keeps them still
        ne.V[:, [0, 1, 2], [0, 1, 2]] += (~self.pt_free).astype(float)
        dV = np.einsum("naa->na", ne.V)
        dV[dV <= 0] = 1.0  # a free target whose observations were all rejected stays still
        ne.gp = gp.reshape(-1)
        ne.cost += float(np.sum(((self.X - self.X0) * wp) ** 2))
        return ne

    def apply(self, du, dp, M, N):
        """The state moved by a step (camera, R, t, X) without changing self."""
        P = int(self.free_cam.sum())
        cam = self.camera.copy()
        cam.params[self.free_cam] += du[:P]
        dpose = du[P:].reshape(M, 6)
        R = Rotation.from_rotvec(dpose[:, :3]).as_matrix() @ self.R
        t = self.t + dpose[:, 3:]
        X = self.X + (dp.reshape(N, 3) if dp is not None else 0.0)
        return cam, R, t, X


@dataclass
class _Normals:
    """Normal equations in blocks: camera (P), M poses (6 each), N targets (3 each, only when refined)."""

    P: int
    M: int
    N: int
    Acc: np.ndarray = None
    gc: np.ndarray = None
    U: np.ndarray = None        # (M,6,6) pose blocks
    W: np.ndarray = None        # (M,P,6) camera-pose coupling
    gpose: np.ndarray = None    # (M,6)
    B: np.ndarray = None        # (P+6M, 3N) coupling to targets (dense)
    V: np.ndarray = None        # (N,3,3) target blocks
    gp: np.ndarray = None       # (3N,)
    cost: float = 0.0

    def dense_u(self):
        """The (camera + poses) block as one dense matrix and its gradient."""
        P, M = self.P, self.M
        A = np.zeros((P + 6 * M, P + 6 * M))
        A[:P, :P] = self.Acc
        A[:P, P:] = self.W.transpose(1, 0, 2).reshape(P, 6 * M)
        A[P:, :P] = A[:P, P:].T
        idx = P + 6 * np.arange(M)[:, None] + np.arange(6)
        A[idx[:, :, None], idx[:, None, :]] = self.U
        return A, np.concatenate([self.gc, self.gpose.ravel()])


def _damped(A: np.ndarray, lam: float) -> np.ndarray:
    """A + lam diag(A) over the last two axes; empty rows (unused poses/targets) get a unit diagonal."""
    Ad = A.copy()
    d = np.einsum("...ii->...i", Ad)
    zero = d <= 0
    d += lam * d + zero
    return Ad


def _scaled_solve(S, rhs):
    s = np.sqrt(np.maximum(np.diag(S), 1e-300))
    return np.linalg.solve(S / s[:, None] / s[None, :], rhs / s) / s


def _scaled_inv(S):
    s = np.sqrt(np.maximum(np.diag(S), 1e-300))
    Sn = S / s[:, None] / s[None, :]
    try:
        inv = np.linalg.inv(Sn)
    except np.linalg.LinAlgError:
        inv = np.linalg.pinv(Sn, rcond=1e-14, hermitian=True)
    return inv / s[:, None] / s[None, :]


def _solve_step(ne: _Normals, lam: float, covariance: bool = False):
    """Damped Gauss-Newton step (camera+poses du, targets dp) by Schur complements; with covariance=True
    (lam=0) instead (camera covariance, pose 6x6 covariances, target 3x3 covariances) in units of sigma0^2."""
    P, M = ne.P, ne.M
    if ne.B is None:
        # targets held: eliminate the 6x6 pose blocks, leaving a P x P camera system
        Uinv = np.linalg.inv(_damped(ne.U, lam))
        WU = ne.W @ Uinv                                                   # (M,P,6)
        S = _damped(ne.Acc, lam) - np.einsum("mpa,mqa->pq", WU, ne.W)
        if covariance:
            Scc = _scaled_inv(S) if P else np.zeros((0, 0))
            T = np.einsum("mpa,pq->mqa", WU, Scc) if P else 0
            cov_pose = Uinv + (np.einsum("mpa,mpb->mab", WU, T) if P else 0)
            return Scc, cov_pose, None
        rhs = -ne.gc + np.einsum("mpa,ma->p", WU, ne.gpose)
        dc = _scaled_solve(S, rhs) if P else np.zeros(0)
        dpose = np.einsum("mab,mb->ma", Uinv, -ne.gpose - np.einsum("mpa,p->ma", ne.W, dc))
        return np.concatenate([dc, dpose.ravel()]), None
    A, gu = ne.dense_u()
    Vinv = np.linalg.inv(_damped(ne.V, lam))
    nu = A.shape[0]
    Y = (ne.B.reshape(nu, ne.N, 3).transpose(1, 0, 2) @ Vinv).transpose(1, 0, 2).reshape(nu, 3 * ne.N)
    S = _damped(A, lam) - Y @ ne.B.T
    if covariance:
        Sinv = _scaled_inv(S)
        idx = P + 6 * np.arange(M)[:, None] + np.arange(6)
        cov_pose = Sinv[idx[:, :, None], idx[:, None, :]]
        Z = Sinv @ Y
        cov_pts = Vinv + np.einsum("kna,knb->nab", Y.reshape(-1, ne.N, 3), Z.reshape(-1, ne.N, 3))
        return Sinv[:P, :P], cov_pose, cov_pts
    du = _scaled_solve(S, -gu + Y @ ne.gp)
    dp = np.einsum("nab,nb->na", Vinv, (-ne.gp - ne.B.T @ du).reshape(-1, 3)).reshape(-1)
    return du, dp


def _lm(prob: _Problem, active, M, N, max_iter=100, tol_chi2=0.01):
    """Levenberg-Marquardt to convergence on the active observations; returns (iterations, converged).

    Converged when a step lowers chi^2 (cost / sigma0^2) by less than `tol_chi2`: the parameters are then
    within a small fraction of their sigmas of the minimum (ill-conditioned models such as the rational one
    otherwise crawl along a flat valley with negligible gains)."""
    lam = 1e-4
    cost = prob.cost(active)
    dof = max(2 * int(active.sum()) - 6 * M, 1)
    for it in range(1, max_iter + 1):
        ne = prob.normal_equations(active, M, N)
        improved = False
        for _ in range(12):
            try:
                du, dp = _solve_step(ne, lam)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            cam, R, t, X = prob.apply(du, dp, M, N)
            new = prob.cost(active, camera=cam, R=R, t=t, X=X)
            if new < cost:
                prob.camera, prob.R, prob.t, prob.X = cam, R, t, X
                gain_chi2 = (cost - new) / max(new / dof, 1e-300)
                cost = new
                lam = max(lam / 10, 1e-12)
                improved = True
                break
            lam *= 10
        if not improved or gain_chi2 < tol_chi2:
            return it, True
    return max_iter, False


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

    refine_targets: 'none' (targets fixed), 'free' (free network, minimal datum of 7 held coordinates)
    or 'weighted' (targets with their CSV sigmas `field_sigma` (m) as priors; NaN sigma = held).
    fixed: names of camera parameters held at their initial values. meas_sigma (px) are relative weights.
    """
    try:
        from threadpoolctl import threadpool_limits
        limiter = threadpool_limits(limits=1)
    except ImportError:
        limiter = contextlib.nullcontext()
    # the dense blocks are small (<= ~1000): BLAS threads cost more than they give, and much more on a
    # busy machine (a 190x190 solve took 170 ms with threads competing, 1 ms on one)
    with limiter:
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
    field_ids = np.asarray(field_ids).astype(str)
    field_xyz = np.asarray(field_xyz, float)
    pid = {k: i for i, k in enumerate(field_ids)}
    meas_image = np.asarray(meas_image).astype(str)
    meas_id = np.asarray(meas_id).astype(str)
    meas_xy = np.asarray(meas_xy, float)
    n = len(meas_id)
    sig = np.ones((n, 2)) if meas_sigma is None else np.asarray(meas_sigma, float).copy()
    sig[~np.isfinite(sig)] = 1.0
    unknown = [k for k in dict.fromkeys(meas_id) if k not in pid]
    if unknown:
        raise InputError(f"target id(s) not in the field: {', '.join(unknown[:5])}", field="id")
    bad = [k for k in fixed if k not in cls.PARAMS]
    if bad:
        raise InputError(f"unknown parameter(s) to fix {bad}; {model} has {', '.join(cls.PARAMS)}", field="fixed")
    if refine_targets not in ("none", "free", "weighted"):
        raise InputError(f"refine_targets must be none, free or weighted, got {refine_targets!r}")

    image_names = list(dict.fromkeys(meas_image.tolist()))
    img_index = {k: i for i, k in enumerate(image_names)}
    obs_img = np.array([img_index[k] for k in meas_image], int)
    obs_pt = np.array([pid[k] for k in meas_id], int)
    M, N = len(image_names), len(field_ids)

    c0, R_field_to_plane, planar = _plane_frame(field_xyz[np.unique(obs_pt)])
    plane_xyz = (field_xyz - c0) @ R_field_to_plane.T
    if planar:
        plane_xyz[:, 2] = 0.0
    groups = [(i, obs_pt[obs_img == i], meas_xy[obs_img == i]) for i in range(M)]
    groups_ok = [g for g in groups if len(g[1]) >= min_points_per_image]
    if len(groups_ok) < 3:
        raise InputError(f"only {len(groups_ok)} image(s) with at least {min_points_per_image} target "
                         f"measurements; need 3 or more")

    # --- initial values ----------------------------------------------------------------------
    if initial is not None:
        if isinstance(initial, cls):
            cam = cls((w, h), initial.params)
        else:  # another model: its closest equivalent (exact where one model contains the other)
            from dgcal.calib.camera.conversions import convert_model
            cam = convert_model(initial, model)[0]
            cam = cls((w, h), cam.params)
        f0 = float(cam.pinhole_K()[0, 0])
    else:
        f0 = _focal_guess(groups_ok, field_xyz if not planar else plane_xyz, (w, h), planar, plane_xyz)
        values = {"f": f0, "fx": f0, "fy": f0, "cx": (w - 1) / 2, "cy": (h - 1) / 2}
        cam = cls.from_dict((w, h), values)
    K0 = cam.pinhole_K()
    R = np.tile(np.eye(3), (M, 1, 1))
    t = np.zeros((M, 3))
    active = np.ones(n, bool)
    dropped: list[str] = []
    rejected_reason = np.array([""] * n, dtype=object)
    iterator = range(M) if progress is None else progress(range(M))
    for i in iterator:
        m = obs_img == i
        if m.sum() < min_points_per_image:
            dropped.append(image_names[i])
            active[m] = False
            rejected_reason[m] = "image dropped: too few targets"
            continue
        obj = plane_xyz[obs_pt[m]]
        uv = meas_xy[m]
        pose = _pnp(obj, uv, K0, planar, 0.02 * max(w, h))
        if initial is not None:
            # with a start camera: PnP on undistorted pixels too, keep whichever pose the camera fits better
            with np.errstate(all="ignore"):
                xy_n = cam.undistort_normalized(uv)
                ok = np.all(np.isfinite(xy_n), axis=1) & np.all(np.abs(xy_n) < 100, axis=1)
            cands = [] if pose is None else [pose]
            if ok.sum() >= min_points_per_image:
                alt = _pnp(obj[ok], xy_n[ok] @ K0[:2, :2].T + K0[:2, 2], K0, planar, 0.02 * max(w, h))
                if alt is not None:
                    cands.append(alt)
            best = np.inf
            pose = None
            for Rc, tc, _ in cands:
                with np.errstate(all="ignore"):
                    e = np.linalg.norm(cam.project(obj @ Rc.T + tc) - uv, axis=1)
                if np.nanmedian(e) < best:
                    best = float(np.nanmedian(e))
                    pose = (Rc, tc, np.nan_to_num(e, nan=np.inf) < max(0.02 * max(w, h), 3 * best))
        if pose is None:
            dropped.append(image_names[i])
            active[m] = False
            rejected_reason[m] = "image dropped: no pose"
            continue
        Rp, tp, inl = pose
        R[i] = Rp @ R_field_to_plane
        t[i] = tp - Rp @ R_field_to_plane @ c0
        sub = np.flatnonzero(m)
        active[sub[~inl]] = False
    if M - len(dropped) < 3:
        raise InputError(f"only {M - len(dropped)} usable image(s) (no pose for {', '.join(dropped[:5])}); need 3 or more")

    # --- targets as unknowns -----------------------------------------------------------------
    X0 = field_xyz.copy()
    pt_free = np.zeros((N, 3), bool)
    pt_prior_w = np.zeros((N, 3))
    if refine_targets != "none":
        img_count = np.bincount(obs_pt[active], minlength=N)  # each image measures a target once
        seen = img_count >= 2
        pt_free[seen] = True
        if refine_targets == "free":
            a, b, c, axis = _datum_points(field_xyz, seen)
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
    prob = _Problem(cam, np.ones(len(cls.PARAMS), bool), R, t, X0.copy(), X0, pt_prior_w, pt_free,
                    obs_img, obs_pt, meas_xy, sig)

    # --- all requested parameters at once (staging focal length/K1 first converged slower in tests) ----
    names = cls.PARAMS
    prob.free_cam = np.array([k not in fixed for k in names])
    total_it, _ = _lm(prob, active, M, N)

    # --- outlier rejection: solve, reject |v|/sigma > k sigma_robust over all observations, repeat ----
    usable = ~np.isin(obs_img, [img_index[d] for d in dropped])
    settled = False
    for _ in range(max_rounds):
        r, _, _ = prob.residuals(usable)
        norm = np.full(n, np.inf)
        norm[usable] = np.linalg.norm(r, axis=1)
        s_rob = np.median(norm[usable]) / _CHI2_MEDIAN  # over all: a median of survivors would creep
        new_active = usable & (norm <= reject_k * s_rob)
        # keep every usable image solvable
        counts = np.bincount(obs_img[new_active], minlength=M)
        for i in np.flatnonzero((counts < min_points_per_image) & (np.bincount(obs_img[usable], minlength=M) > 0)):
            dropped.append(image_names[i])
            usable &= obs_img != i
            new_active &= obs_img != i
            rejected_reason[obs_img == i] = "image dropped: too few inliers"
        changed = int(np.sum(new_active != active))
        if changed <= 5e-3 * usable.sum():  # later rounds only trade a few borderline points
            settled = True
            active = new_active
            break
        active = new_active
        it, _ = _lm(prob, active, M, N)
        total_it += it
    if M - len(dropped) < 3:
        raise InputError(f"only {M - len(dropped)} usable image(s) after outlier rejection; need 3 or more")
    it, lm_conv = _lm(prob, active, M, N)
    total_it += it

    # --- statistics and covariance -----------------------------------------------------------
    ne = prob.normal_equations(active, M, N)
    P = int(prob.free_cam.sum())
    n_pt_unknowns = int(prob.pt_free.sum())
    n_prior = int((prob.pt_free & (prob.pt_prior_w > 0)).sum())
    keep_img = np.ones(M, bool)
    keep_img[[img_index[d] for d in dropped]] = False
    redundancy = 2 * int(active.sum()) + n_prior - P - 6 * int(keep_img.sum()) - n_pt_unknowns
    sigma0 = float(np.sqrt(ne.cost / max(redundancy, 1)))
    Scc, cov_pose, cov_pts = _solve_step(ne, 0.0, covariance=True)
    names = cls.PARAMS
    Pn = len(names)
    cov_cam = np.zeros((Pn, Pn))
    fi = np.flatnonzero(prob.free_cam)
    cov_cam[np.ix_(fi, fi)] = sigma0**2 * Scc
    sd = np.sqrt(np.maximum(np.diag(cov_cam), 0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_cam / np.outer(sd, sd)
    corr[~prob.free_cam, :] = np.nan
    corr[:, ~prob.free_cam] = np.nan
    pose_sigma = sigma0 * np.sqrt(np.maximum(np.einsum("mkk->mk", cov_pose), 0))
    pose_sigma[:, :3] = np.degrees(pose_sigma[:, :3])
    pose_sigma[~keep_img] = np.nan
    pose_cov = sigma0**2 * cov_pose
    pose_cov[~keep_img] = np.nan
    pts_sigma = np.zeros((N, 3))
    if cov_pts is not None:
        pts_sigma = sigma0 * np.sqrt(np.maximum(np.einsum("naa->na", cov_pts), 0)) * prob.pt_free

    camera = prob.camera.copy()
    camera.sigmas = sd
    r_all = np.full((n, 2), np.nan)
    if usable.any():
        i, j = obs_img[usable], obs_pt[usable]
        Xc = np.einsum("nab,nb->na", prob.R[i], prob.X[j]) + prob.t[i]
        r_all[usable] = camera.project(Xc) - meas_xy[usable]
    rms = float(np.sqrt(np.mean(np.sum(r_all[active] ** 2, axis=1))))
    rejected = []
    for k in np.flatnonzero(~active):
        rejected.append(RejectedObservation(meas_image[k], meas_id[k],
                                            float(np.linalg.norm(r_all[k])) if usable[k] else float("nan"),
                                            rejected_reason[k] or "outlier"))
    R_out, t_out = prob.R.copy(), prob.t.copy()
    R_out[~keep_img] = np.nan
    t_out[~keep_img] = np.nan
    return IntrinsicBAResult(
        camera=camera, free=prob.free_cam.copy(), cov_camera=cov_cam, correlation=corr,
        image_names=image_names, R_field_to_cam=R_out, t_cam=t_out, pose_sigma=pose_sigma, pose_cov=pose_cov,
        point_ids=list(field_ids), points_xyz=prob.X.copy(), points_sigma=pts_sigma, points_free=prob.pt_free.copy(),
        obs_image=obs_img, obs_point=obs_pt, obs_xy=meas_xy, obs_sigma=sig, residuals=r_all, used=active,
        sigma0=sigma0, rms_px=rms, rejected=rejected, dropped_images=list(dropped),
        refine_targets=refine_targets, iterations=total_it, converged=bool(lm_conv), rejection_settled=settled,
        redundancy=int(redundancy))
