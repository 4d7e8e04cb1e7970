"""Bundle adjustment with ground control on the least-squares engine (`dgcal.bundle.solver`).

Why not pycolmap's Ceres bundle adjuster: pycolmap 4.2.1 has no fraser7 camera (B1/B2 affinity), and it
cannot express a weighted observation of a 3-D point (a GCP with sigmas) without custom Ceres cost
functions (pyceres is not part of the stack).

Frames: `world` is the local Cartesian frame of the block (metres; dgcal uses ENU at the field centre).
Poses follow `dgcal.fields.pose`: `R_world_to_cam`, `C_world`, covariances [C_world (m), dtheta (rad)] with
dtheta a right perturbation of R_cam_to_world (camera axes).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from threadpoolctl import threadpool_limits

from dgcal.bundle.solver.blocks import CentrePriors, GlobalPriors, ImageObservations, PointPriors, State
from dgcal.bundle.solver.covariance import Covariance
from dgcal.bundle.solver.lm import LMOptions, minimise, normals_at
from dgcal.bundle.solver.normals import Normals, Problem
from dgcal.calib.camera.models import CameraModel
from dgcal.fields.pose import Poses

BLAS_THREADS_MIN_SIZE = 2000   # camera-side unknowns from which the adjustment lets BLAS use several threads
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
    antenna_offset_cam: np.ndarray | None = None  # (3,) m: the centres are of an antenna at C + R_cam_to_world a
    centre_flight: np.ndarray | None = None       # (n,) flight index per image: a shift of each flight's centres
                                                  # (3 unknowns per flight, world E, N, Up, m) is estimated
    refine: tuple[str, ...] = ()                  # camera parameters to refine
    intrinsic_prior_sigma: dict[str, float] = field(default_factory=dict)  # optional soft constraints
    held_images: tuple[int, ...] = ()             # images whose poses are held (known, or a gauge)


@dataclass
class BundleOptions:
    """Solver settings: robust loss on pixel residuals (in sigma units), iterations, sigma scaling."""

    loss: str = "huber"            # "none", "huber" or "cauchy"
    loss_scale: float = 3.0        # whitened residual norm where the loss turns robust
    max_iterations: int = 60
    tolerance: float = 1e-8        # relative cost decrease that stops the iterations
    tol_chi2: float = 1e-3         # ... or a chi^2 gain below this (parameters within ~0.03 sigma of the minimum:
                                   # a flat valley no longer crawls to the iteration limit)
    tol_step: float = 1e-2         # ... or a step that moves no pose or intrinsic by this much of its (conditional)
                                   # sigma: the camera side has converged while ill-determined tie points (two
                                   # near-parallel rays) still crawl in depth, gaining chi^2 without moving it
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
    refine: tuple[str, ...]
    sigma0: float                      # a-posteriori sigma of unit weight
    redundancy: int
    residuals_px: np.ndarray           # (k,2) projected - measured
    weights: np.ndarray                # (k,) robust weights of the final iteration
    iterations: int
    converged: bool
    cost_history: list[float]
    stop_reason: str = ""
    inputs: BundleInput = field(repr=False, default=None)
    problem: Problem = field(repr=False, default=None)
    normals: Normals = field(repr=False, default=None)    # undamped, at the solution
    aposteriori: bool = True
    globals_: np.ndarray = field(repr=False, default=None)   # the estimated globals: intrinsics, flight shifts

    @cached_property
    def covariance(self) -> Covariance:
        """Cofactors of the solution, computed on first use (the inverse of the reduced system: the most
        expensive part of a large block, which a run that wants only the orientation never pays)."""
        return Covariance.at(self.problem, self.normals)

    @cached_property
    def cov_pose(self) -> np.ndarray:
        """(n,6,6) pose covariances [C (m), dtheta (rad)] (dgcal.fields.pose), scaled by `scale2`."""
        return self.covariance.pose_cofactors() * self.scale2

    @cached_property
    def cov_intrinsics(self) -> np.ndarray:
        """(p,p) covariance of the refined intrinsics in the order of `refine`, scaled by `scale2`."""
        return self.covariance.global_cofactors(np.arange(len(self.refine))) * self.scale2

    @property
    def n_flights(self) -> int:
        """Flights whose centre shift was estimated (0: none)."""
        fl = self.inputs.centre_flight
        return 0 if fl is None or not len(fl) else int(np.max(fl)) + 1

    @property
    def flight_shift(self) -> np.ndarray:
        """(F,3) the estimated shift of each flight's centres (world E, N, Up, m)."""
        return self.globals_[len(self.refine):].reshape(-1, 3)

    @cached_property
    def cov_flight_shift(self) -> np.ndarray:
        """(F,3,3) covariance of each flight's centre shift (m^2), scaled by `scale2`."""
        F, p = self.n_flights, len(self.refine)
        out = np.empty((F, 3, 3))
        for f in range(F):
            out[f] = self.covariance.global_cofactors(p + 3 * f + np.arange(3)) * self.scale2
        return out

    @property
    def poses(self) -> Poses:
        """The adjusted poses with their covariances."""
        return Poses(self.R_world_to_cam, self.C_world, self.cov_pose)

    @property
    def obs_image(self) -> np.ndarray:
        """(k,) image index of each observation of the adjustment."""
        return self.inputs.obs_image

    @property
    def obs_point(self) -> np.ndarray:
        """(k,) point index of each observation of the adjustment."""
        return self.inputs.obs_point

    @property
    def scale2(self) -> float:
        """Variance factor of the covariances: max(sigma0^2, 1) a posteriori, else 1."""
        if self.aposteriori and self.redundancy > 0 and np.isfinite(self.sigma0):
            return max(self.sigma0 ** 2, 1.0)
        return 1.0

    def point_covariance(self, idx) -> np.ndarray:
        """Covariances (len(idx),3,3) of adjusted points (m^2), scaled like the pose covariances."""
        return self.covariance.point_cofactors(np.atleast_1d(idx)) * self.scale2

    def redundancy_numbers(self, obs_idx) -> np.ndarray:
        """Redundancy numbers (len,2) of pixel observations (1 - leverage of the whitened, weighted obs)."""
        return np.clip(self.covariance.redundancy_numbers(0, np.atleast_1d(obs_idx)), 1e-9, 1.0)

    def standardized_residuals(self, obs_idx) -> np.ndarray:
        """Baarda's standardised residuals (len,2) of pixel observations (a-priori sigma)."""
        k = np.atleast_1d(obs_idx)
        r_white = self.normals.evals[0].r[k]                    # weighted, whitened residuals
        return r_white / np.sqrt(self.redundancy_numbers(k))


def problem_of(inp: BundleInput, opt: BundleOptions) -> tuple[Problem, State]:
    """The engine problem and start state of a bundle input: image observations, then the priors."""
    cam = inp.camera
    n, m = len(inp.images), len(inp.point_ids)
    blocks = [ImageObservations(cam, inp.obs_image, inp.obs_point, inp.obs_uv, inp.obs_sigma, inp.refine, 0,
                                opt.loss, opt.loss_scale)]
    if inp.point_prior is not None and np.isfinite(np.asarray(inp.point_prior, float)).any():
        pp = np.asarray(inp.point_prior, float)
        ps = np.full((m, 3), np.nan) if inp.point_prior_sigma is None else np.asarray(inp.point_prior_sigma, float)
        ps = np.where(np.isfinite(pp) & ~(ps > FIXED_SIGMA), FIXED_SIGMA, ps)
        blocks.append(PointPriors.from_arrays(pp, ps))
    n_shift = 0
    if inp.center_prior is not None and np.isfinite(np.asarray(inp.center_prior, float)).any():
        cs = np.asarray(inp.center_prior_sigma, float)
        fl = inp.centre_flight
        n_shift = 0 if fl is None or not len(fl) else 3 * (int(np.max(fl)) + 1)
        shift_glob = len(inp.refine) + np.arange(n_shift) if n_shift else None
        blocks.append(CentrePriors.from_arrays(inp.center_prior, cs, offset_cam=inp.antenna_offset_cam,
                                               flight=fl if n_shift else None, shift_glob=shift_glob))
    ips = np.array([inp.intrinsic_prior_sigma.get(p, np.nan) for p in inp.refine], float)
    if np.isfinite(ips).any():
        g = np.flatnonzero(np.isfinite(ips))
        ref_idx = [cam.PARAMS.index(p) for p in inp.refine]
        blocks.append(GlobalPriors(g, cam.params[ref_idx][g], ips[g]))
    prob = Problem(blocks, n, m, len(inp.refine) + n_shift)
    prob.pose_free[list(inp.held_images)] = False
    state = State(Poses(inp.R_world_to_cam, inp.C_world), np.asarray(inp.X_world, float).reshape(-1, 3).copy(),
                  np.r_[cam.params[[cam.PARAMS.index(p) for p in inp.refine]], np.zeros(n_shift)])
    return prob, state


def adjust(inp: BundleInput, options: BundleOptions | None = None) -> BundleResult:
    """Run the bundle adjustment (pixels, metres, radians inside) and return orientation with covariance."""
    opt = options or BundleOptions()
    prob, state = problem_of(inp, opt)
    # the dense products of a few hundred images are small: BLAS threads cost more than they give, and far more
    # on a busy machine (a 450 x 450 Cholesky 5x slower with two threads competing with other work)
    with threadpool_limits(limits=1 if prob.n_camera_side <= BLAS_THREADS_MIN_SIZE else None, user_api="blas"):
        sol = minimise(prob, state, LMOptions(max_iterations=opt.max_iterations, tol_rel=opt.tolerance,
                                              tol_chi2=opt.tol_chi2, tol_step=opt.tol_step, lambda_up=8.0,
                                              lambda_down=5.0, verbose=opt.verbose))
        nrm = normals_at(prob, sol)
    redundancy = int(nrm.redundancy)
    sigma0 = float(np.sqrt(nrm.cost / redundancy)) if redundancy > 0 else float("nan")
    res = BundleResult(inp.camera, sol.state.poses.R_world_to_cam, sol.state.poses.C_world, sol.state.points,
                       tuple(inp.refine), sigma0, redundancy, np.empty((0, 2)), nrm.weights[0], sol.iterations,
                       sol.converged, sol.history, sol.stop_reason, inp, prob, nrm, opt.aposteriori,
                       sol.state.globals.copy())
    img = prob.blocks[0]
    cam = img.camera_at(sol.state.globals)
    if len(inp.refine):
        sig = np.full(len(cam.PARAMS), np.nan) if inp.camera.sigmas is None else np.array(inp.camera.sigmas, float)
        sig[img.param_idx] = np.sqrt(np.diag(res.cov_intrinsics))
        cam.sigmas = sig
    res.camera = cam
    Xc = sol.state.poses.to_cam(sol.state.points[inp.obs_point], inp.obs_image)
    res.residuals_px = cam.project(Xc) - np.asarray(inp.obs_uv, float)
    return res
