"""Single-image georeferencing (seed 000 sec. 5.2, eq. 20-26, done rigorously): the ground point of a pixel
from one image, its camera pose and a height source, with the pose/height/pixel covariance propagated.

World frame: a map grid (E, N, h) — any projected CRS with ellipsoidal heights (`dgcal.fields.crs.MapGrid`) — or
any local Cartesian frame with z up (ENU). Over the few hundred metres of one image the grid is treated as
Cartesian (the scale-factor and curvature effects are millimetres at 100 m height).

Camera: a calibrated `dgcal.calib.camera.models.CameraModel`; `ray(uv)` gives the collinearity ray in the CV camera
frame, rotated into the world by `R_cam_to_world` from the centre `C_world`:
X = C_world + s R_cam_to_world d(u, v).
Height sources:
- a known ground height h:  s = (h - C_world_z) / d_z  (seed eq. 25 for the image centre);
- a DEM (`dgcal.calib.dg.dem.Dem`): Newton iteration on f(s) = C_world_z + s d_z - H(C_world_xy + s d_xy) with the
  DEM slope;
- a laser range rho to the image centre along `laser_dir_cam` (default the optical axis): the centre
  ground point is C_world + rho R_cam_to_world d_laser (seed eq. 26) and the ground is taken level through it.
Pose covariance: 6x6 [centre (m, world), rotation (rad, right perturbation in the camera frame,
R_cam_to_world <- R_cam_to_world Exp(dtheta))], the rule of `dgcal.fields.pose`. Propagation is by central
differences over all inputs.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dgcal.calib.camera.files import load_camera
from dgcal.calib.dg.dem import Dem, read_geotiff_dem
from dgcal.calib.dg.eop import dg_eop
from dgcal.calib.mounting.common import read_mounting_json
from dgcal.fields.crs import MapGrid, parse_crs
from dgcal.fields.errors import InputError
from dgcal.fields.frames import R_NED_TO_ENU, R_body_to_ned_from_rph, R_cam_to_map_from_opk
from dgcal.fields.io import validate
from dgcal.fields.io.csv_tables import read_table
from dgcal.fields.io.formats import read_eop, read_events, read_measurements, read_trajectory
from dgcal.fields.pose import Poses, so3_exp, so3_log


@dataclass
class GroundEstimate:
    """Ground points (N,3) world, their covariance (N,3,3) m^2, and per point whether the solution converged."""

    xyz: np.ndarray
    cov: np.ndarray
    ok: np.ndarray
    method: str

    @property
    def sigma(self) -> np.ndarray:
        """1-sigma E, N, h (m) (N,3)."""
        return np.sqrt(np.einsum("nii->ni", self.cov))


def camera_pose_from_body(r_imu_world: np.ndarray, R_body_to_world: np.ndarray, lever_arm_b: np.ndarray,
                          R_cam_to_body: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera centre (3,) (m, world) and R_cam_to_world (3,3) of the body pose (IMU position, attitude) and the
    mounting (`dgcal.fields.pose.Poses.mounted`)."""
    cam = Poses.from_body_to_world(R_body_to_world, r_imu_world).mounted(lever_arm_b, R_cam_to_body)
    return cam.C_world[0], cam.R_cam_to_world[0]


def R_body_to_world_from_rph(rph_deg, R_enu_to_world: np.ndarray | None = None) -> np.ndarray:
    """R_body_to_world for NED->body roll/pitch/heading (deg) in a z-up world (ENU, or grid via R_enu_to_world)."""
    R_body_to_enu = R_NED_TO_ENU @ R_body_to_ned_from_rph(*np.asarray(rph_deg, float))
    return R_body_to_enu if R_enu_to_world is None else np.asarray(R_enu_to_world, float) @ R_body_to_enu


def pose_covariance_from_rph(rph_deg, cov_rph_deg2, cov_pos_world, R_cam_to_body: np.ndarray,
                             R_enu_to_world: np.ndarray | None = None) -> np.ndarray:
    """6x6 pose covariance [centre m, camera-frame rotation rad] from the covariance of roll/pitch/heading
    (3x3 deg^2, or (3,) sigmas in deg) and of the world position (3x3 m^2, or (3,) sigmas in m), by
    differentiating R_cam_to_world with respect to the angles."""
    rph = np.asarray(rph_deg, float)
    Ca = np.asarray(cov_rph_deg2, float)
    Ca = np.diag(Ca ** 2) if Ca.ndim == 1 else Ca
    Cp = np.asarray(cov_pos_world, float)
    Cp = np.diag(Cp ** 2) if Cp.ndim == 1 else Cp
    R_cam_to_world = R_body_to_world_from_rph(rph, R_enu_to_world) @ R_cam_to_body
    J = np.empty((3, 3))
    eps = 1e-6
    for i in range(3):
        d = np.zeros(3)
        d[i] = eps
        R_cam_to_world_d = R_body_to_world_from_rph(rph + d, R_enu_to_world) @ R_cam_to_body
        J[:, i] = so3_log(R_cam_to_world.T @ R_cam_to_world_d) / eps
    P = np.zeros((6, 6))
    P[:3, :3] = Cp
    P[3:, 3:] = J @ Ca @ J.T
    return P


def _intersect_height(C_world: np.ndarray, d: np.ndarray, h) -> tuple[np.ndarray, np.ndarray]:
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (np.asarray(h, float) - C_world[2]) / d[:, 2]
    return C_world + s[:, None] * d, s > 0


def intersect_dem(C_world: np.ndarray, d: np.ndarray, dem, dh: float, max_iter: int, tol: float):
    """Ground points (N,3) of rays from C_world (3,) along d (N,3) on a DEM raised by dh (m), by Newton along each
    ray; and ok (N,)."""
    # start on the level surface through the DEM height below the camera (or the DEM mean)
    h0 = dem.height(C_world[0], C_world[1])
    h0 = float(np.nanmean(dem.heights)) if not np.isfinite(h0) else float(h0)
    X, ok = _intersect_height(C_world, d, h0 + dh)
    s = (X[:, 2] - C_world[2]) / d[:, 2]
    done = np.zeros(len(d), bool)
    for _ in range(max_iter):
        X = C_world + s[:, None] * d
        H = dem.height(X[:, 0], X[:, 1]) + dh
        g = dem.gradient(X[:, 0], X[:, 1])
        f = X[:, 2] - H
        fp = d[:, 2] - g[:, 0] * d[:, 0] - g[:, 1] * d[:, 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            step = f / fp
        step = np.where(np.isfinite(step), step, 0.0)
        s = s - step
        done = np.abs(step * np.linalg.norm(d, axis=1)) < tol
        if np.all(done | ~np.isfinite(H)):
            break
    X = C_world + s[:, None] * d
    H = dem.height(X[:, 0], X[:, 1]) + dh
    ok = ok & done & np.isfinite(H) & (s > 0)
    return X, ok


def _solve(camera, uv: np.ndarray, C_world: np.ndarray, R_cam_to_world: np.ndarray, source: str, value,
           laser_dir_cam, max_iter: int = 30, tol: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    d = camera.ray(uv) @ R_cam_to_world.T
    if source == "height":
        return _intersect_height(C_world, d, value)
    if source == "dem":
        dem, dh = value
        return intersect_dem(C_world, d, dem, dh, max_iter, tol)
    if source == "range":
        dl = R_cam_to_world @ (np.asarray(laser_dir_cam, float) / np.linalg.norm(laser_dir_cam))
        h_c = C_world[2] + float(value) * dl[2]
        return _intersect_height(C_world, d, h_c)
    raise ValueError(f"unknown height source {source!r}")


def georeference(camera, uv, C_world, R_cam_to_world, *, height=None, dem=None, range_m=None,
                 laser_dir_cam=(0.0, 0.0, 1.0), pose_cov: np.ndarray | None = None, sigma_px: float = 0.5,
                 sigma_height: float = 0.0, sigma_range: float = 0.0) -> GroundEstimate:
    """Ground points (world) of pixels `uv` (N,2) in one image, with covariance from the pose covariance
    (6x6, see module docstring), pixel sigma (px), and the height / DEM / range sigma (m).

    Give exactly one of `height` (m, scalar or (N,)), `dem` (`dgcal.calib.dg.dem.Dem` in the world's map frame) or
    `range_m` (laser range to the image centre along `laser_dir_cam`, CV camera frame)."""
    given = [x is not None for x in (height, dem, range_m)]
    if sum(given) != 1:
        raise ValueError("give exactly one of height, dem or range_m")
    uv = np.atleast_2d(np.asarray(uv, float))
    C_world = np.asarray(C_world, float).ravel()
    R_cam_to_world = np.asarray(R_cam_to_world, float)
    if height is not None:
        source, val, s_val, method = "height", np.broadcast_to(np.asarray(height, float), (len(uv),)), \
            sigma_height, "known height"
    elif dem is not None:
        source, val, s_val, method = "dem", (dem, 0.0), sigma_height, "DEM"
    else:
        source, val, s_val, method = "range", float(range_m), sigma_range, "laser range"
    X, ok = _solve(camera, uv, C_world, R_cam_to_world, source, val, laser_dir_cam)
    # central differences over [centre (3), rotation (3), pixel (2), height/range (1)]
    P = np.zeros((9, 9))
    if pose_cov is not None:
        P[:6, :6] = np.asarray(pose_cov, float)
    P[6:8, 6:8] = np.eye(2) * sigma_px ** 2
    P[8, 8] = s_val ** 2
    steps = np.r_[[0.01] * 3, [1e-5] * 3, [0.1] * 2, [0.01]]
    J = np.zeros((len(uv), 3, 9))
    for i in range(9):
        if P[i, i] == 0:
            continue
        cols = []
        for sgn in (1.0, -1.0):
            e = sgn * steps[i]
            C_d, R_d, u, v = C_world, R_cam_to_world, uv, val   # the inputs moved by one step
            if i < 3:
                C_d = C_world.copy()
                C_d[i] += e
            elif i < 6:
                w = np.zeros(3)
                w[i - 3] = e
                R_d = R_cam_to_world @ so3_exp(w)
            elif i < 8:
                u = uv.copy()
                u[:, i - 6] += e
            elif source == "dem":
                v = (val[0], val[1] + e)
            else:
                v = val + e
            cols.append(_solve(camera, u, C_d, R_d, source, v, laser_dir_cam)[0])
        J[:, :, i] = (cols[0] - cols[1]) / (2 * steps[i])
    cov = J @ P @ np.swapaxes(J, 1, 2)
    return GroundEstimate(X, cov, ok, method)


@dataclass
class AveragedPoint:
    """Average of several single-image estimates of one ground point (seed Fig. 19)."""

    mean: np.ndarray          # plain average (the seed's), (d,)
    weighted: np.ndarray      # covariance-weighted average, (d,)
    cov_weighted: np.ndarray  # its covariance (d,d) assuming independent images
    cov_mean: np.ndarray      # covariance of the plain average from the inputs' covariances
    scatter_cov: np.ndarray   # empirical covariance of the plain average (sample scatter / M)
    chi2_dof: float           # consistency of the estimates with their covariances
    n: int
    cov_with_common: np.ndarray  # cov_weighted plus the error common to all images (not reduced by averaging)


def average_estimates(xy: np.ndarray, cov: np.ndarray, common_cov: np.ndarray | None = None) -> AveragedPoint:
    """Average M estimates (M,d) of one point with covariances (M,d,d): plain and information-weighted.

    `common_cov` (d,d): the part of each image's error shared by all of them (a GNSS error correlated over
    the pass, a boresight error); averaging does not reduce it, so it is added to the average's covariance."""
    x = np.asarray(xy, float)
    C = np.asarray(cov, float)
    M, d = x.shape
    W = np.linalg.inv(C)
    cov_w = np.linalg.inv(W.sum(axis=0))
    xw = cov_w @ np.einsum("mij,mj->i", W, x)
    r = x - xw
    chi2 = float(np.einsum("mi,mij,mj->", r, W, r)) / max(d * (M - 1), 1)
    xm = x.mean(axis=0)
    sc = np.cov(x.T).reshape(d, d) / M if M > 1 else np.full((d, d), np.nan)
    common = np.zeros((d, d)) if common_cov is None else np.asarray(common_cov, float)
    return AveragedPoint(xm, xw, cov_w, C.sum(axis=0) / M ** 2, sc, chi2, M, cov_w + common)


def pose_covariance_from_opk(opk_deg, cov_eop: np.ndarray) -> np.ndarray:
    """6x6 pose covariance [centre m, camera-frame rotation rad] from an EOP covariance [X, Y, Z (m),
    omega, phi, kappa (deg)] (6x6, or (6,) sigmas), PATB angles (`dgcal.fields.frames.R_cam_to_map_from_opk`)."""
    C = np.asarray(cov_eop, float)
    C = np.diag(C ** 2) if C.ndim == 1 else C
    opk = np.asarray(opk_deg, float)
    R_cam_to_map = R_cam_to_map_from_opk(*opk)
    J = np.empty((3, 3))
    eps = 1e-6
    for i in range(3):
        d = np.zeros(3)
        d[i] = eps
        J[:, i] = so3_log(R_cam_to_map.T @ R_cam_to_map_from_opk(*(opk + d))) / eps
    H = np.zeros((6, 6))
    H[:3, :3] = np.eye(3)
    H[3:, 3:] = J
    return H @ C @ H.T


@dataclass
class ImageGeoref:
    """Per-measurement ground points of `georeference_images` and the per-point averages."""

    image: np.ndarray
    id: np.ndarray
    xyz: np.ndarray
    cov: np.ndarray
    ok: np.ndarray
    averages: dict  # id -> AveragedPoint of (E, N) plus mean height
    rejected: list = field(default_factory=list)   # (image, id) of estimates screened out as gross errors


def georeference_images(camera, meas, eop, *, height: float | None = None, dem=None, ranges: dict | None = None,
                        sigma_px: float = 0.5, sigma_height: float = 0.0, sigma_range: float = 0.5,
                        laser_dir_cam=(0.0, 0.0, 1.0)) -> ImageGeoref:
    """Single-image ground points of every measurement (`dgcal.fields.io.formats.Measurements`) of an image that has an
    EOP (`dgcal.fields.io.formats.EOP`, map CRS, PATB), with covariances from the EOP covariance/sigmas, and per point
    id the covariance-weighted average over its images. Height source: `height` (m), `dem` or `ranges`
    (image -> (range m, sigma m or NaN)). Measurement sigmas (sx, sy) override `sigma_px`."""
    idx = {str(k): j for j, k in enumerate(eop.image)}
    rows_img, rows_id, X, Cv, OK = [], [], [], [], []
    for img in dict.fromkeys(str(x) for x in meas.image):
        if img not in idx:
            continue
        j = idx[img]
        sel = np.flatnonzero(meas.image.astype(str) == img)
        C_map = eop.xyz[j]   # the map grid is this georeferencing's world
        R_cam_to_map = R_cam_to_map_from_opk(*eop.opk[j])
        if eop.cov is not None:
            P = pose_covariance_from_opk(eop.opk[j], eop.cov[j])
        elif eop.sigma is not None and np.all(np.isfinite(eop.sigma[j])):
            P = pose_covariance_from_opk(eop.opk[j], eop.sigma[j])
        else:
            P = None
        kw = {}
        if ranges is not None:
            if img not in ranges:
                raise InputError(f"no laser range for image {img!r}", field="image")
            rho, s_r = ranges[img]
            kw = dict(range_m=rho, sigma_range=s_r if np.isfinite(s_r) else sigma_range, laser_dir_cam=laser_dir_cam)
        elif dem is not None:
            kw = dict(dem=dem, sigma_height=sigma_height)
        else:
            kw = dict(height=height, sigma_height=sigma_height)
        for k in sel:
            s = meas.sigma[k]
            spx = float(np.nanmean(s)) if np.any(np.isfinite(s)) else sigma_px
            e = georeference(camera, meas.xy[k][None], C_map, R_cam_to_map, pose_cov=P, sigma_px=spx, **kw)
            rows_img.append(img)
            rows_id.append(str(meas.id[k]))
            X.append(e.xyz[0])
            Cv.append(e.cov[0])
            OK.append(bool(e.ok[0]))
    if not X:
        raise InputError("no measurement belongs to an image with an exterior orientation", field="image")
    X, Cv, OK = np.array(X), np.array(Cv), np.array(OK)
    ids = np.array(rows_id)
    imgs = np.array(rows_img)
    averages, rejected = {}, []
    for pid in dict.fromkeys(rows_id):
        m = (ids == pid) & OK
        for k in screen_estimates(X[:, :2], Cv[:, :2, :2], np.flatnonzero(m)):
            OK[k] = False
            rejected.append((str(imgs[k]), pid))
        m = (ids == pid) & OK
        if m.sum() == 0:
            continue
        cov2 = Cv[m][:, :2, :2] + np.eye(2) * 1e-12
        # the pose errors of one pass (GNSS/INS, mounting, the bundle's datum) are shared by the images of a point:
        # averaging does not reduce them; counting them as independent made the sigmas 2.75-4x too small
        av = average_estimates(X[m][:, :2], cov2)
        common = _psd(np.mean(cov2, axis=0) - av.cov_weighted)
        averages[pid] = (average_estimates(X[m][:, :2], cov2, common_cov=common), float(np.mean(X[m][:, 2])))
    return ImageGeoref(imgs, ids, X, Cv, OK, averages, rejected)


SCREEN_CHI2 = 13.8      # chi-square (2 dof) 0.999 point: an estimate beyond it from the others' mean is a gross error


def screen_estimates(xy: np.ndarray, cov: np.ndarray, rows: np.ndarray) -> list[int]:
    """Rows (of `rows`) whose horizontal estimate (E, N m) is a gross error: outside the largest set of estimates
    that agree with one another (pairwise within `SCREEN_CHI2` of their summed covariances), when that set holds at
    least half of them and two or more (robust to several gross errors; no majority: all kept)."""
    rows = np.asarray(rows, int)
    n = len(rows)
    if n < 3:
        return []
    d = xy[rows][:, None, :] - xy[rows][None, :, :]                       # (n,n,2)
    S = cov[rows][:, None] + cov[rows][None, :] + np.eye(2) * 1e-12
    chi2 = np.einsum("abi,abi->ab", d, np.linalg.solve(S, d[..., None])[..., 0])
    agree = chi2 <= SCREEN_CHI2
    best = int(np.argmax(agree.sum(axis=1)))
    keep = agree[best]
    if keep.sum() < max(2, (n + 1) // 2) or keep.all():
        return []
    return [int(k) for k in rows[~keep]]


def _psd(C: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh((C + C.T) / 2)
    return (V * np.clip(w, 0, None)) @ V.T


@dataclass
class GeorefOptions:
    """Inputs and settings of `dgcal georef`: camera, pixels, map CRS, the images' orientation (an EOP file,
    or trajectory + events + mounting for DG) and one height source (known height m, GeoTIFF DEM in `crs`,
    or laser ranges CSV image,range_m[,s_range_m]); sigmas in px and m."""

    camera: Path
    measurements: Path
    crs: str
    eop: Path | None = None
    trajectory: Path | None = None
    events: Path | None = None
    mounting: Path | None = None
    height: float | None = None
    dem: Path | None = None
    ranges: Path | None = None
    sigma_px: float = 0.5
    sigma_height: float = 0.0
    sigma_range: float = 0.5

    def height_source(self) -> str:
        """dem, ranges or height: where the ground height comes from."""
        return "dem" if self.dem is not None else "ranges" if self.ranges is not None else "height"


@dataclass
class GeorefRun:
    """`georeference_files`' result: the per-pixel ground points and averages, with the options used."""

    result: ImageGeoref
    options: GeorefOptions


def read_laser_ranges(path: Path) -> dict:
    """Laser ranges CSV image,range_m[,s_range_m] (m) -> {image: (range m, sigma m or NaN)}."""
    tab = read_table(path, ("image", "range_m"), ("s_range_m",))
    r = np.asarray(tab["range_m"], float)
    bad = np.flatnonzero(~np.isfinite(r) | (r <= 0))
    if len(bad):
        raise InputError("range must be a positive number", path, line=int(tab.lines[bad[0]]), field="range_m")
    validate.values_in_range(r, 0.0, validate.MAX_HEIGHT_M, path, "range_m", tab.lines, unit="m")
    s = np.asarray(tab["s_range_m"], float) if "s_range_m" in tab else np.full(len(r), np.nan)
    validate.positive_values(s, path, "s_range_m", tab.lines, allow_nan=True, hi=validate.MAX_HEIGHT_M, what="sigma")
    return {str(k): (float(a), float(b)) for k, a, b in zip(tab["image"], r, s)}


def georeference_files(opts: GeorefOptions) -> GeorefRun:
    """`dgcal georef`: read the files of `opts`, take the EOPs from the EOP file or by DG (POS + mounting),
    and run `georeference_images` with the chosen height source."""
    grid = MapGrid(opts.crs)
    camera = load_camera(opts.camera)
    meas = read_measurements(opts.measurements)
    if opts.eop is not None:
        eop = read_eop(opts.eop)
    elif opts.trajectory and opts.events and opts.mounting:
        eop = dg_eop(grid, read_trajectory(opts.trajectory), read_events(opts.events),
                     read_mounting_json(opts.mounting))[0]
    else:
        raise InputError("give --eop, or --trajectory with --events and --mounting", field="eop")
    dem: Dem | None = None
    ranges = None
    if opts.dem is not None:
        dem = read_geotiff_dem(opts.dem)
        if dem.crs is not None and parse_crs(dem.crs, str(opts.dem)) != grid.crs:
            raise InputError(f"DEM CRS {dem.crs} differs from --crs {opts.crs}", opts.dem, field="CRS")
    if opts.ranges is not None:
        ranges = read_laser_ranges(opts.ranges)
    res = georeference_images(camera, meas, eop, height=opts.height, dem=dem, ranges=ranges, sigma_px=opts.sigma_px,
                              sigma_height=opts.sigma_height, sigma_range=opts.sigma_range)
    return GeorefRun(res, opts)
