"""Bundle adjustment with ground control: sparse Levenberg-Marquardt with a Schur complement on the points.

Why not pycolmap's Ceres bundle adjuster: pycolmap 4.2.1 has no fraser7 camera (B1/B2 affinity), and it
cannot express a weighted observation of a 3-D point (a GCP with sigmas) without custom Ceres cost
functions (pyceres is not part of the stack). The problem is small and block-sparse, so a direct solver
is exact and fast: the reduced camera system is dense (6 per image + refined intrinsics), the points are
3x3 blocks eliminated in closed form, and the same matrices give the covariance.

Frames: `world` is a local Cartesian frame (metres; dgcal uses ENU at the field centre). Each image holds
`R_world_to_cam` (world vectors into the OpenCV camera frame: x right, y down, z forward) and its
projection centre `C_world`. A camera-frame point is `X_cam = R_world_to_cam (X_world - C_world)`.
Pose updates are left perturbations `R <- Exp(d_theta) R` (d_theta in the camera frame, radians), so a
pose covariance is ordered [C_world (3, m), d_theta (3, rad)].
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cho_factor, cho_solve
from scipy.spatial.transform import Rotation

from dgcal.calib.camera.models import CameraModel
from dgcal.fields.frames import skew

FIXED_SIGMA = 1e-6   # sigma (m) that stands for "fixed" coordinates: keeps one code path for weighted and fixed


@dataclass
class BundleInput:
    """Everything the adjustment needs; indices tie observations to images and points."""

    camera: CameraModel
    images: list[str]
    R_world_to_cam: np.ndarray          # (n,3,3) initial rotations
    C_world: np.ndarray                # (n,3) initial projection centres, m
    point_ids: list[str]
    X_world: np.ndarray                # (m,3) initial points, m
    obs_image: np.ndarray              # (k,) image index
    obs_point: np.ndarray              # (k,) point index
    obs_uv: np.ndarray                 # (k,2) measured pixels (OpenCV convention)
    obs_sigma: np.ndarray              # (k,2) px
    point_prior: np.ndarray | None = None         # (m,3) observed coordinates (NaN = tie point)
    point_prior_sigma: np.ndarray | None = None   # (m,3) m; 0 = fixed
    center_prior: np.ndarray | None = None        # (n,3) GNSS centres (NaN = none)
    center_prior_sigma: np.ndarray | None = None  # (n,3) m
    refine: tuple[str, ...] = ()                  # camera parameters to refine
    intrinsic_prior_sigma: dict[str, float] = field(default_factory=dict)  # optional soft constraints


@dataclass
class BundleOptions:
    """Solver settings: robust loss on pixel residuals (in sigma units), iterations, sigma scaling."""

    loss: str = "huber"            # "none", "huber" or "cauchy"
    loss_scale: float = 3.0        # whitened residual norm where the loss turns robust
    max_iterations: int = 60
    tolerance: float = 1e-8        # relative cost decrease that stops the iterations
    aposteriori: bool = True       # scale covariances by max(sigma0^2, 1): inflate when the fit is worse than
                                   # the stated sigmas, never shrink (precise tie points must not make the
                                   # GCP-driven datum look better than its own sigmas say)
    verbose: bool = False


@dataclass
class BundleResult:
    """Adjusted orientation, points and camera with covariances, residuals and quality figures."""

    camera: CameraModel
    R_world_to_cam: np.ndarray
    C_world: np.ndarray
    X_world: np.ndarray
    cov_pose: np.ndarray               # (n,6,6) [C (m), d_theta (rad, camera frame)]
    cov_intrinsics: np.ndarray         # (p,p) in the order of `refine`
    refine: tuple[str, ...]
    sigma0: float                      # a-posteriori sigma of unit weight
    redundancy: int
    residuals_px: np.ndarray           # (k,2) projected - measured
    weights: np.ndarray                # (k,) robust weights of the final iteration
    iterations: int
    converged: bool
    cost_history: list[float]
    _cofactor_cc: np.ndarray = field(repr=False, default=None)
    _inp: BundleInput = field(repr=False, default=None)
    _cache: dict = field(repr=False, default_factory=dict)

    @property
    def obs_image(self) -> np.ndarray:
        """(k,) image index of each observation of the adjustment."""
        return self._inp.obs_image

    @property
    def obs_point(self) -> np.ndarray:
        """(k,) point index of each observation of the adjustment."""
        return self._inp.obs_point

    @property
    def scale2(self) -> float:
        return max(self.sigma0 ** 2, 1.0) if self._cache.get("aposteriori", True) else 1.0

    def point_covariance(self, idx) -> np.ndarray:
        """Covariances (len(idx),3,3) of adjusted points (m^2), scaled like the pose covariances."""
        return np.array([self._point_blocks(int(p))[2] for p in np.atleast_1d(idx)]) * self.scale2

    def _point_blocks(self, p: int):
        """Cofactor blocks of point p: (column indices of W_p, Sigma_pc (3,n_c), Sigma_pp (3,3))."""
        if p in self._cache.setdefault("pt", {}):
            return self._cache["pt"][p]
        lin = self._cache["lin"]
        Vinv_p = lin["Vinv"][p]
        Wp = lin["W"][:, 3 * p:3 * p + 3]                      # (n_c,3) sparse: the images seeing p
        nz = np.unique(Wp.indices)
        Wd = Wp[nz].toarray()
        S_pc = -Vinv_p @ Wd.T @ self._cofactor_cc[nz]           # (3,n_c)
        S_pp = Vinv_p - S_pc[:, nz] @ Wd @ Vinv_p
        self._cache["pt"][p] = (None, S_pc, S_pp)
        return self._cache["pt"][p]

    def redundancy_numbers(self, obs_idx) -> np.ndarray:
        """Redundancy numbers (len,2) of pixel observations (1 - leverage of the whitened, weighted obs)."""
        lin = self._cache["lin"]
        Jc = lin["Jc"]
        out = np.empty((len(np.atleast_1d(obs_idx)), 2))
        for n, k in enumerate(np.atleast_1d(obs_idx)):
            p = int(self._inp.obs_point[k])
            _, S_pc, S_pp = self._point_blocks(p)
            rows = Jc[2 * k:2 * k + 2]
            cols = np.unique(rows.indices)                     # the image's 6 columns and the intrinsics
            a_c = rows[:, cols].toarray()                       # (2,c) whitened
            a_p = lin["Jp_blocks"][k]                           # (2,3)
            q = (np.einsum("ij,jk,ik->i", a_c, self._cofactor_cc[np.ix_(cols, cols)], a_c)
                 + 2 * np.einsum("ij,jk,ik->i", a_p, S_pc[:, cols], a_c)
                 + np.einsum("ij,jk,ik->i", a_p, S_pp, a_p))
            out[n] = 1.0 - q
        return np.clip(out, 1e-9, 1.0)

    def standardized_residuals(self, obs_idx) -> np.ndarray:
        """Baarda's standardised residuals (len,2) of pixel observations (a-priori sigma)."""
        k = np.atleast_1d(obs_idx)
        lin = self._cache["lin"]
        r_white = lin["r_obs"][k]                               # weighted, whitened residuals
        return r_white / np.sqrt(self.redundancy_numbers(k))


# ---------------------------------------------------------------------------------------------
def _robust(loss: str, scale: float, e2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Robust cost rho(e^2) and weight rho'(e^2) per observation (e = whitened residual norm)."""
    if loss == "none":
        return e2, np.ones_like(e2)
    c2 = scale * scale
    if loss == "huber":
        e = np.sqrt(e2)
        inl = e2 <= c2
        rho = np.where(inl, e2, 2 * scale * e - c2)
        w = np.where(inl, 1.0, scale / np.maximum(e, 1e-300))
        return rho, w
    if loss == "cauchy":
        return c2 * np.log1p(e2 / c2), 1.0 / (1.0 + e2 / c2)
    raise ValueError(f"unknown loss {loss!r}")


class _Problem:
    def __init__(self, inp: BundleInput, opt: BundleOptions):
        self.inp, self.opt = inp, opt
        self.n = len(inp.images)
        self.m = len(inp.point_ids)
        cam = inp.camera
        self.ref_idx = np.array([cam.PARAMS.index(p) for p in inp.refine], int)
        self.ni = len(self.ref_idx)
        self.nc = 6 * self.n + self.ni
        m = self.m
        pp = np.full((m, 3), np.nan) if inp.point_prior is None else np.asarray(inp.point_prior, float)
        ps = np.full((m, 3), np.nan) if inp.point_prior_sigma is None else np.asarray(inp.point_prior_sigma, float)
        ps = np.where(np.isfinite(pp) & ~(ps > FIXED_SIGMA), FIXED_SIGMA, ps)
        self.pp, self.ps = pp, np.where(np.isfinite(pp), ps, np.nan)
        n = self.n
        cp = np.full((n, 3), np.nan) if inp.center_prior is None else np.asarray(inp.center_prior, float)
        cs = np.full((n, 3), np.nan) if inp.center_prior_sigma is None else np.asarray(inp.center_prior_sigma, float)
        self.cp, self.cs = cp, np.where(np.isfinite(cp), cs, np.nan)
        self.ip0 = cam.params[self.ref_idx].copy()
        self.ips = np.array([inp.intrinsic_prior_sigma.get(p, np.nan) for p in inp.refine], float)
        k = len(inp.obs_image)
        self.k = k
        self.oi = np.asarray(inp.obs_image, int)
        self.op = np.asarray(inp.obs_point, int)
        self.uv = np.asarray(inp.obs_uv, float)
        self.sig = np.asarray(inp.obs_sigma, float)
        # sparsity pattern of the camera-side Jacobian rows of each observation
        cols = np.concatenate([6 * self.oi[:, None] + np.arange(6)[None], 6 * n + np.tile(np.arange(self.ni), (k, 1))], 1)
        self.jc_rows = np.repeat(np.arange(2 * k), cols.shape[1])
        self.jc_cols = np.repeat(cols, 2, axis=0).ravel()
        self.jp_rows = np.repeat(np.arange(2 * k), 3)
        self.jp_cols = np.repeat(3 * self.op[:, None] + np.arange(3)[None], 2, axis=0).ravel()

    # --- model ------------------------------------------------------------------------------
    def camera_at(self, ip) -> CameraModel:
        cam = self.inp.camera.copy()
        cam.params[self.ref_idx] = ip
        cam.sigmas = None
        return cam

    def project(self, R, C, X, ip, jac: bool):
        cam = self.camera_at(ip)
        Ri = R[self.oi]
        Xc = np.einsum("kij,kj->ki", Ri, X[self.op] - C[self.oi])
        if not jac:
            return cam.project(Xc), Xc
        uv, Jint, JX = cam.project_with_jacobians(Xc)
        J_C = -JX @ Ri
        J_rot = -JX @ skew(Xc)
        J_X = JX @ Ri
        return uv, Xc, np.concatenate([J_C, J_rot, Jint[:, :, self.ref_idx]], 2), J_X

    def cost(self, state) -> tuple[float, np.ndarray]:
        R, C, X, ip = state
        uv, Xc = self.project(R, C, X, ip, jac=False)
        r = (uv - self.uv) / self.sig
        e2 = np.sum(r * r, 1)
        e2 = np.where(Xc[:, 2] > 0, e2, 1e12)   # a point behind the camera is as bad as it gets
        rho, _ = _robust(self.opt.loss, self.opt.loss_scale, e2)
        c = float(np.sum(rho))
        c += float(np.nansum(((X - self.pp) / self.ps) ** 2))
        c += float(np.nansum(((C - self.cp) / self.cs) ** 2))
        c += float(np.nansum(((ip - self.ip0) / self.ips) ** 2))
        return c, r

    def linearise(self, state) -> dict:
        R, C, X, ip = state
        uv, Xc, Jc_o, Jp_o = self.project(R, C, X, ip, jac=True)
        r = (uv - self.uv) / self.sig
        e2 = np.sum(r * r, 1)
        _, w = _robust(self.opt.loss, self.opt.loss_scale, e2)
        sw = np.sqrt(w)[:, None]
        scale = (sw / self.sig)[:, :, None]
        Jc_o = Jc_o * scale
        Jp_o = Jp_o * scale
        rw = r * sw
        Jc = sp.csr_matrix((Jc_o.ravel(), (self.jc_rows, self.jc_cols)), shape=(2 * self.k, self.nc))
        Jp = sp.csr_matrix((Jp_o.ravel(), (self.jp_rows, self.jp_cols)), shape=(2 * self.k, 3 * self.m))
        rv = rw.ravel()
        U = (Jc.T @ Jc).toarray()
        gc = -(Jc.T @ rv)
        W = (Jc.T @ Jp).tocsc()
        V = np.zeros((self.m, 3, 3))
        np.add.at(V, self.op, np.einsum("kai,kaj->kij", Jp_o, Jp_o))
        gp = -np.zeros((self.m, 3))
        np.add.at(gp, self.op, -np.einsum("kai,ka->ki", Jp_o, rw))
        # priors: diagonal, whitened
        okp = np.isfinite(self.pp)
        wp = np.where(okp, 1.0 / np.where(okp, self.ps, 1.0) ** 2, 0.0)
        V[:, [0, 1, 2], [0, 1, 2]] += wp + 1e-10   # a 100 km prior: unobserved points stay invertible
        gp -= np.where(okp, (X - np.nan_to_num(self.pp)) * wp, 0.0)
        okc = np.isfinite(self.cp)
        wc = np.where(okc, 1.0 / np.where(okc, self.cs, 1.0) ** 2, 0.0)
        ic = (6 * np.arange(self.n)[:, None] + np.arange(3)[None]).ravel()
        U[ic, ic] += wc.ravel()
        gc[ic] -= np.where(okc, (C - np.nan_to_num(self.cp)) * wc, 0.0).ravel()
        if self.ni:
            oki = np.isfinite(self.ips)
            wi = np.where(oki, 1.0 / np.where(oki, self.ips, 1.0) ** 2, 0.0)
            ii = 6 * self.n + np.arange(self.ni)
            U[ii, ii] += wi
            gc[ii] -= np.where(oki, (ip - self.ip0) * wi, 0.0)
        return dict(U=U, gc=gc, W=W, V=V, gp=gp.ravel(), Jc=Jc, Jp_blocks=Jp_o, r_obs=rw, w=w, r=r)

    def solve(self, lin, lam: float):
        U = lin["U"].copy()
        d = np.diag(U).copy()
        U[np.diag_indices_from(U)] += lam * np.maximum(d, 1e-9)
        V = lin["V"].copy()
        dv = V[:, [0, 1, 2], [0, 1, 2]].copy()
        V[:, [0, 1, 2], [0, 1, 2]] += lam * np.maximum(dv, 1e-9)
        Vinv = np.linalg.inv(V)
        Vinv_sp = sp.bsr_matrix((Vinv, np.arange(self.m), np.arange(self.m + 1)),
                                shape=(3 * self.m, 3 * self.m)).tocsr()
        Y = lin["W"] @ Vinv_sp
        S = U - (Y @ lin["W"].T).toarray()
        rhs = lin["gc"] - Y @ lin["gp"]
        try:
            cf = cho_factor(S)
            dc = cho_solve(cf, rhs)
        except np.linalg.LinAlgError:
            dc = np.linalg.lstsq(S, rhs, rcond=None)[0]
            cf = None
        dp = (Vinv_sp @ (lin["gp"] - lin["W"].T @ dc))
        return dc, dp, S, cf, Vinv

    def apply(self, state, dc, dp):
        R, C, X, ip = state
        n = self.n
        blk = dc[:6 * n].reshape(n, 6)
        C2 = C + blk[:, :3]
        R2 = Rotation.from_rotvec(blk[:, 3:]).as_matrix() @ R
        X2 = X + dp.reshape(-1, 3)
        ip2 = ip + dc[6 * n:]
        return R2, C2, X2, ip2


def adjust(inp: BundleInput, options: BundleOptions | None = None) -> BundleResult:
    """Run the bundle adjustment (pixels, metres, radians inside) and return orientation with covariance."""
    opt = options or BundleOptions()
    pb = _Problem(inp, opt)
    state = (np.asarray(inp.R_world_to_cam, float).copy(), np.asarray(inp.C_world, float).copy(),
             np.asarray(inp.X_world, float).copy(), inp.camera.params[pb.ref_idx].copy())
    cost, _ = pb.cost(state)
    history = [cost]
    lam = 1e-4
    converged = False
    it = 0
    for it in range(1, opt.max_iterations + 1):
        lin = pb.linearise(state)
        improved = False
        for _ in range(12):
            dc, dp, *_ = pb.solve(lin, lam)
            cand = pb.apply(state, dc, dp)
            c2, _ = pb.cost(cand)
            if np.isfinite(c2) and c2 < cost:
                improved = True
                break
            lam *= 8.0
        if not improved:
            converged = True   # no step lowers the cost: at the minimum to machine precision
            break
        rel = (cost - c2) / max(cost, 1e-300)
        state, cost = cand, c2
        history.append(cost)
        lam = max(lam / 5.0, 1e-12)
        if opt.verbose:
            print(f"  BA it {it}: cost {cost:.6g} lambda {lam:.1e}")
        if rel < opt.tolerance:
            converged = True
            break
    # covariance from the undamped normal equations at the solution
    lin = pb.linearise(state)
    _, _, S, cf, Vinv = pb.solve(lin, 0.0)
    cof = cho_solve(cf, np.eye(pb.nc)) if cf is not None else np.linalg.pinv(S)
    lin["Vinv"] = Vinv
    n_res = 2 * pb.k + int(np.isfinite(pb.pp).sum() + np.isfinite(pb.cp).sum() + np.isfinite(pb.ips).sum())
    redundancy = int(n_res - pb.nc - 3 * pb.m)
    sigma0 = float(np.sqrt(cost / redundancy)) if redundancy > 0 else float("nan")
    s2 = max(sigma0 ** 2, 1.0) if (opt.aposteriori and redundancy > 0) else 1.0
    n = pb.n
    cov_pose = np.array([cof[6 * i:6 * i + 6, 6 * i:6 * i + 6] for i in range(n)]) * s2
    cov_int = cof[6 * n:, 6 * n:] * s2
    R, C, X, ip = state
    cam = pb.camera_at(ip)
    if pb.ni:
        sig = np.full(len(cam.PARAMS), np.nan) if cam.sigmas is None else np.array(cam.sigmas, float)
        sig[pb.ref_idx] = np.sqrt(np.diag(cov_int))
        cam.sigmas = sig
    uv, _ = pb.project(R, C, X, ip, jac=False)
    res = BundleResult(cam, R, C, X, cov_pose, cov_int, tuple(inp.refine), sigma0, redundancy, uv - pb.uv,
                       lin["w"], it, converged, history, cof, inp, {"lin": lin, "aposteriori": opt.aposteriori})
    return res
