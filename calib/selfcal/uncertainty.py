"""Projection uncertainty of a calibrated camera, as mrcal computes it: how well each part of the frame is known.

The calibration's covariance of the camera parameters and of every image's pose (sigma0^2 N^-1, the targets
eliminated: a refined field's uncertainty is in it) is propagated to the projection of a point:

1. a pixel q is unprojected with the calibrated model to the camera-frame point p = r ray(q) at range r (m), or
   only its direction for a point at infinity;
2. p is carried into the target field through every used image's pose, p_i = R_i^T p + C_i, and back into the
   camera through the *mean* of the poses: p' = (1/N) sum_i R_i (p_i - C_i) (the camera frame is tied to the
   field only through the poses, so a perturbed solution is compared through all of them, not through one);
3. q' = project(p'; camera parameters). Its 2x2 covariance is J S J^T with J = d q'/d(pose mean, parameters):
   p' moves by t + [p]x w for the mean pose perturbation (t = -(1/N) sum R_i dC_i, w = (1/N) sum dtheta_i),
   at infinity only the rotation w counts.

The reported sigma is the worst-direction standard deviation (the square root of the larger eigenvalue of the
2x2 covariance), in px, as mrcal reports it. The same propagation gives the uncertainty of a converted model
(e.g. the OpenCV block) through the Jacobian of the conversion (dgcal.calib.camera.conversions.conversion_jacobian).
Checked against the spread of re-calibrations over noise realisations (tests/calib/selfcal/test_camera_uncertainty.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgcal.calib.camera.conversions import conversion_jacobian
from dgcal.calib.camera.models import CameraModel
from dgcal.calib.selfcal.adjustment import IntrinsicBAResult
from dgcal.fields.frames import skew


def mean_pose_covariance(ba: IntrinsicBAResult) -> np.ndarray:
    """(6+P, 6+P) covariance of [t (m), w (rad)] of the mean pose perturbation and the camera parameters."""
    if ba.cov_camera_side is None:
        raise ValueError("the adjustment result carries no camera-side covariance")
    M = len(ba.image_names)
    P = len(ba.camera.PARAMS)
    used = np.isfinite(ba.poses.C_world[:, 0])
    used &= np.bincount(ba.obs_image[ba.used], minlength=M) > 0
    idx = np.flatnonzero(used)
    n = len(idx)
    L = np.zeros((6 + P, 6 * M + ba.n_globals))     # a board warp's two globals (after the camera's) not read
    R_world_to_cam = ba.poses.R_world_to_cam
    for i in idx:
        L[0:3, 6 * i:6 * i + 3] = -R_world_to_cam[i] / n
        L[3:6, 6 * i + 3:6 * i + 6] = np.eye(3) / n
    L[6:, 6 * M:6 * M + P] = np.eye(P)
    S = ba.cov_camera_side.sandwich(L)
    return 0.5 * (S + S.T)


def projection_jacobian(camera: CameraModel, uv: np.ndarray, range_m: float | None,
                        dparams: np.ndarray | None = None) -> np.ndarray:
    """(N,2,6+P) derivative of the projection of the points seen at pixels uv (N,2), at `range_m` (m; None = at
    infinity), with respect to [mean pose perturbation t (m), w (rad), calibrated parameters]. `camera` is the
    calibrated model or, with `dparams` = d(camera params)/d(calibrated params), a model converted from it."""
    uv = np.atleast_2d(np.asarray(uv, float))
    d = camera.ray(uv)
    p = d if range_m is None else d * float(range_m)
    _, Jp, JX = camera.project_with_jacobians(p)
    if dparams is not None:
        Jp = Jp @ dparams
    k = len(uv)
    Je = np.empty((k, 2, 6))
    Je[:, :, 3:] = JX @ skew(p)                            # dp = [p]x w  (X_cam x dtheta, as the engine)
    Je[:, :, :3] = 0.0 if range_m is None else JX
    return np.concatenate([Je, Jp], axis=2)


def projection_covariance(camera: CameraModel, S: np.ndarray, uv: np.ndarray, range_m: float | None,
                          dparams: np.ndarray | None = None) -> np.ndarray:
    """(N,2,2) covariance (px^2) of the projection of the points seen at pixels uv (N,2) at `range_m` (m; None =
    at infinity), for the covariance S of [mean pose, calibrated parameters] (`mean_pose_covariance`); see
    `projection_jacobian` for `camera` and `dparams`."""
    J = projection_jacobian(camera, uv, range_m, dparams)
    return np.einsum("kai,ij,kbj->kab", J, S, J)


def aligned_difference_expectation(results: list[IntrinsicBAResult], uv: np.ndarray) -> float:
    """Expected RMS (px) of the projection difference of independent calibrations (e.g. the halves of a
    cross-validation) at pixels uv after the best common rotation is removed (as
    dgcal.calib.selfcal.diagnostics.projection_difference does): sqrt(tr(P C P) / N), C the sum of their joint
    projection covariances at infinity, P the projector removing what a rotation explains."""
    uv = np.atleast_2d(uv)
    C = 0.0
    for r in results:
        J = projection_jacobian(r.camera, uv, None).reshape(2 * len(uv), -1)
        C = C + J @ mean_pose_covariance(r) @ J.T
    A = projection_jacobian(results[0].camera, uv, None)[:, :, 3:6].reshape(2 * len(uv), 3)
    Qa, _ = np.linalg.qr(A)
    PC = C - Qa @ (Qa.T @ C)
    PCP = PC - (PC @ Qa) @ Qa.T
    return float(np.sqrt(max(np.trace(PCP), 0.0) / len(uv)))


def worst_sigma(cov: np.ndarray) -> np.ndarray:
    """Worst-direction standard deviation (N,) px of 2x2 covariances (N,2,2)."""
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    lam = 0.5 * (a + c) + np.sqrt(np.maximum(0.25 * (a - c) ** 2 + b * b, 0.0))
    return np.sqrt(np.maximum(lam, 0.0))


def median_range(ba: IntrinsicBAResult) -> float:
    """Median camera-to-target distance (m) of the used observations."""
    R_world_to_cam, C_world = ba.poses.R_world_to_cam, ba.poses.C_world
    d = np.empty(int(ba.used.sum()))
    k = 0
    for a in range(0, len(ba.used), 100_000):            # 100 000 observations at a time
        u = ba.used[a:a + 100_000]
        i, j = ba.obs_image[a:a + 100_000][u], ba.obs_point[a:a + 100_000][u]
        X = np.einsum("kij,kj->ki", R_world_to_cam[i], ba.points_xyz[j] - C_world[i])
        d[k:k + len(X)] = np.linalg.norm(X, axis=1)
        k += len(X)
    return float(np.median(d))


@dataclass
class UncertaintyMap:
    """Worst-direction projection sigma (px) on a pixel grid: at `range_m` and at infinity."""

    u: np.ndarray                 # (nx,) px
    v: np.ndarray                 # (ny,) px
    range_m: float
    sigma_range: np.ndarray       # (ny,nx) px
    sigma_infinity: np.ndarray    # (ny,nx) px
    model: str

    def to_dict(self) -> dict:
        """JSON form."""
        def r(a):
            return np.round(a, 5).tolist()
        return {"model": self.model, "definition": "worst-direction standard deviation (px) of the projection of a "
                "point seen at each pixel, from the covariance of the intrinsics and the poses (mrcal's method)",
                "range_m": self.range_m, "u_px": r(self.u), "v_px": r(self.v),
                "sigma_px_at_range": r(self.sigma_range), "sigma_px_at_infinity": r(self.sigma_infinity)}

    def summary(self, region=None) -> str:
        """One line: the sigma inside the valid region and its largest value over the frame (px)."""
        txt = ""
        if region is not None:
            uv = region.grid((41, 29))
            if len(uv):
                s = self.at(uv, infinity=True)
                txt = f"median {np.median(s):.3g} px, max {np.max(s):.3g} px in the valid region, "
        return (f"worst-direction sigma at infinity {txt}up to {np.nanmax(self.sigma_infinity):.3g} px over the frame "
                f"({self.model})")

    def at(self, uv: np.ndarray, infinity: bool = False) -> np.ndarray:
        """Bilinearly interpolated sigma (px) at pixels (N,2)."""
        from scipy.interpolate import RegularGridInterpolator
        g = RegularGridInterpolator((self.v, self.u), self.sigma_infinity if infinity else self.sigma_range,
                                    bounds_error=False, fill_value=None)
        return g(np.atleast_2d(uv)[:, ::-1])


def uncertainty_map(ba: IntrinsicBAResult, range_m: float | None = None, nx: int = 32,
                    camera: CameraModel | None = None, dparams: np.ndarray | None = None,
                    S: np.ndarray | None = None) -> UncertaintyMap:
    """The projection sigma over the frame (nx columns, rows in proportion) at `range_m` (default: the median
    target distance of the calibration) and at infinity, of the calibrated camera or of `camera` converted from it
    (`dparams` = d(its params)/d(calibrated params))."""
    cam = ba.camera if camera is None else camera
    w, h = cam.image_size
    ny = max(2, int(round(nx * h / w)))
    u = np.linspace(0, w - 1, nx)
    v = np.linspace(0, h - 1, ny)
    uu, vv = np.meshgrid(u, v)
    uv = np.column_stack([uu.ravel(), vv.ravel()])
    S = mean_pose_covariance(ba) if S is None else S
    rng = median_range(ba) if range_m is None else float(range_m)
    with np.errstate(all="ignore"):
        sr = worst_sigma(projection_covariance(cam, S, uv, rng, dparams)).reshape(ny, nx)
        si = worst_sigma(projection_covariance(cam, S, uv, None, dparams)).reshape(ny, nx)
    return UncertaintyMap(u, v, rng, sr, si, cam.NAME)


def converted_uncertainty_map(ba: IntrinsicBAResult, converted: CameraModel, free: list[str] | None = None,
                              region=None, range_m: float | None = None, nx: int = 32) -> UncertaintyMap:
    """The projection sigma of a model converted (fitted) from the calibrated one: the calibration's covariance
    through the conversion's Jacobian (fitted inside `region`)."""
    G = conversion_jacobian(ba.camera, converted, free, region=region)
    return uncertainty_map(ba, range_m, nx, converted, G)
