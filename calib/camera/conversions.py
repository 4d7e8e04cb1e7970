"""Conversions between dgcal camera models and other software's conventions.

Every conversion returns the converted parameters and the largest projection difference in pixels
(`max_error_px`): 0 where the conversion is exact, otherwise the residual of a least-squares fit over a grid
spanning the frame or, given a `region` (dgcal.calib.camera.region.ValidRegion: where the source model is
monotonic and observed), only the part of the frame inside it: a model is not fitted through its own fold or
into corners no observation reached, and the error is measured there. See docs/camera_models.md for the equations and
the convention traps (P1/P2 swap, +0.5 px origin, centre-relative principal point, inverse models).

All pixel coordinates in this module are dgcal's (OpenCV's): origin at the centre of the top-left
pixel, so the centre of a W x H image is ((W-1)/2, (H-1)/2).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.optimize import least_squares

from dgcal.calib.camera.models import CameraModel, Fisheye, Fraser7, OpenCV8, model_class, parameter_index
from dgcal.fields.errors import InputError

OPENCV5_KEYS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
OPENCV8_KEYS = OPENCV5_KEYS + ("k4", "k5", "k6")
COLMAP_PARAMS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
}
MIN_FIT_POINTS = 60           # a region with fewer grid points is sampled more densely
COLMAP_PIXEL_SHIFT = 0.5      # COLMAP's origin is the top-left pixel's corner: its centre is (0.5, 0.5)
METASHAPE_PIXEL_SHIFT = 0.5   # Metashape's too: u = w/2 + cx + ... has the image centre at w/2
METASHAPE_KEYS = ("f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2", "p3", "p4")
EXACT_TOL_PX = 1e-9


# ---------------------------------------------------------------------------------------------
# generic tools
# ---------------------------------------------------------------------------------------------
def frame_grid(image_size: tuple[int, int], n: tuple[int, int] = (41, 29)) -> np.ndarray:
    """Pixels (N,2) on a regular grid spanning the whole frame, corners included."""
    w, h = image_size
    uu, vv = np.meshgrid(np.linspace(0.0, w - 1.0, n[0]), np.linspace(0.0, h - 1.0, n[1]))
    return np.column_stack([uu.ravel(), vv.ravel()])


def region_grid(image_size: tuple[int, int], n: tuple[int, int], region=None) -> np.ndarray:
    """Pixels of a frame grid (corners included), or, given `region`, pixels filling it (a grid over its bounding
    box and points along its border: `ValidRegion.sample`)."""
    if region is None:
        return frame_grid(image_size, n)
    uv = region.sample(n)
    if len(uv) < MIN_FIT_POINTS:
        uv = region.sample((3 * n[0], 3 * n[1]))
    return uv


def max_projection_difference(a, b, n: tuple[int, int] = (61, 41), region=None) -> float:
    """Largest pixel distance between two camera models' projections of the rays of `a` over the frame (or over
    the part of it inside `region`)."""
    uv = region_grid(a.image_size, n, region)
    with np.errstate(all="ignore"):
        d = np.linalg.norm(b.project(a.ray(uv)) - uv, axis=1)
    if not len(d):
        return float("inf") if region is not None else 0.0   # an empty region: nothing is known to fit
    return float(np.max(np.nan_to_num(d, nan=np.inf)))


def fit_camera(source, target: CameraModel, free: list[str] | None = None,
               grid: tuple[int, int] = (41, 29), region=None) -> tuple[CameraModel, float]:
    """Fit `target`'s parameters (those in `free`, default all) so that it projects the rays of `source`
    (anything with image_size, ray, project) where `source` does; returns (fitted copy, max error px).
    The error is measured on a denser grid than the fit's, over the whole frame or only inside `region`."""
    t = target.copy()
    t.sigmas = None
    idx = np.arange(len(t.PARAMS)) if free is None else np.array([t.PARAMS.index(k) for k in free])
    uv = region_grid(source.image_size, grid, region)
    with np.errstate(all="ignore"):
        rays = source.ray(uv)
    ok = np.all(np.isfinite(rays), axis=1)
    uv, rays = uv[ok], rays[ok]

    def residual(p):
        t.params[idx] = p
        return (t.project(rays) - uv).ravel()

    def jacobian(p):
        t.params[idx] = p
        return t.project_with_jacobians(rays)[1][:, :, idx].reshape(-1, len(idx))

    sol = least_squares(residual, t.params[idx].copy(), jac=jacobian, method="lm", x_scale="jac",
                        xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200)
    t.params[idx] = sol.x
    return t, max_projection_difference(source, t, region=region)


def conversion_jacobian(source: CameraModel, target: CameraModel, free: list[str] | None = None,
                        uv: np.ndarray | None = None, region=None) -> np.ndarray:
    """d(target params)/d(source params) (Pt, Ps) of a fitted conversion (`fit_camera` of `target` to `source` on
    the pixels `uv`, default the region's fit grid), by the implicit-function theorem on the Gauss-Newton
    normal equations: a change of the source's parameters moves its rays, the fit follows. Rows of held target
    parameters are 0."""
    uv = region_grid(source.image_size, (41, 29), region) if uv is None else np.asarray(uv, float)
    idx = np.arange(len(target.PARAMS)) if free is None else np.array([target.PARAMS.index(k) for k in free])
    xy = source.undistort_normalized(uv)
    X = np.column_stack([xy, np.ones(len(xy))])
    _, Js, JXs = source.project_with_jacobians(X)
    # source: project(ray) = uv  =>  J_xy dxy + J_s ds = 0
    dxy = -np.linalg.solve(JXs[:, :, :2], Js)                         # (N,2,Ps)
    _, Jt, JXt = target.project_with_jacobians(X)
    dr_ds = np.einsum("nij,njp->nip", JXt[:, :, :2], dxy).reshape(-1, Js.shape[2])
    A = Jt[:, :, idx].reshape(-1, len(idx))
    sol = -np.linalg.lstsq(A, dr_ds, rcond=None)[0]
    out = np.zeros((len(target.PARAMS), Js.shape[2]))
    out[idx] = sol
    return out


def _initial(source, cls: type[CameraModel]) -> CameraModel:
    K = source.pinhole_K()
    if cls is Fraser7:
        return Fraser7(source.image_size, [K[1, 1], K[0, 2], K[1, 2], 0, 0, 0, 0, 0, K[0, 0] - K[1, 1], 0])
    if cls is Fisheye:
        return Fisheye(source.image_size, [K[0, 0], K[1, 1], K[0, 2], K[1, 2]] + [0.0] * 4)
    return OpenCV8(source.image_size, [K[0, 0], K[1, 1], K[0, 2], K[1, 2]] + [0.0] * 8)


def convert_model(source, name: str, region=None) -> tuple[CameraModel, float]:
    """`source` as the dgcal model `name` ('fraser7', 'opencv8' or 'fisheye'): exact where one contains the other,
    else fitted (inside `region` when given); returns (model, max error px)."""
    cls = model_class(name)
    if isinstance(source, cls):
        return source.copy(), 0.0
    if isinstance(source, Fraser7) and cls is OpenCV8 and source["B2"] == 0.0:
        d, err = to_opencv(source)
        return OpenCV8.from_dict(source.image_size, d), err
    if isinstance(source, OpenCV8) and cls is Fraser7 and not np.any(source.params[9:]):
        return from_opencv(to_opencv(source)[0], source.image_size, "fraser7"), 0.0
    return fit_camera(source, _initial(source, cls), region=region)


class _NewtonRay:
    """ray() for models that only define project(): Newton iteration on normalised coordinates."""

    def ray(self, uv: np.ndarray) -> np.ndarray:
        """Unit viewing rays (N,3) in the camera frame for pixels (N,2)."""
        uv = np.atleast_2d(np.asarray(uv, float))
        K = self.pinhole_K()
        xy = (uv - K[:2, 2]) / np.diag(K)[:2]
        h = 1e-7
        for _ in range(30):
            f0 = self._project_xy(xy)
            J = np.empty((len(xy), 2, 2))
            for j in range(2):
                d = np.zeros(2)
                d[j] = h
                J[:, :, j] = (self._project_xy(xy + d) - self._project_xy(xy - d)) / (2 * h)
            step = np.linalg.solve(J, (f0 - uv)[..., None])[..., 0]
            xy = xy - step
            if np.max(np.abs(step), initial=0.0) < 1e-13:
                break
        d = np.column_stack([xy, np.ones(len(xy))])
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def project(self, X_cam: np.ndarray) -> np.ndarray:
        """Pixels (N,2) of camera-frame points (N,3)."""
        X = np.atleast_2d(np.asarray(X_cam, float))
        return self._project_xy(X[:, :2] / X[:, 2:3])


# ---------------------------------------------------------------------------------------------
# OpenCV
# ---------------------------------------------------------------------------------------------
def to_opencv(model: CameraModel, region=None) -> tuple[dict[str, float], float]:
    """OpenCV parameters {fx, fy, cx, cy, k1, k2, p1, p2, k3[, k4, k5, k6]} (px) and the max error (px):
    exact for opencv8 and for fraser7 with B2 = 0, else a fit over the frame (inside `region` when given):
    5 coefficients for fraser7, the rational 8 for fisheye."""
    if isinstance(model, OpenCV8):
        return {k: model[k] for k in OPENCV8_KEYS}, 0.0
    if isinstance(model, Fisheye):
        fit, err = fit_camera(model, _initial(model, OpenCV8), region=region)
        return {k: fit[k] for k in OPENCV8_KEYS}, err
    if not isinstance(model, Fraser7):
        raise InputError(f"no OpenCV conversion for camera model {model.NAME!r}", field="model")
    err = 0.0
    if model["B2"] != 0.0:
        # OpenCV has no skew term: fit a fraser7 with B2 = 0, which is exactly OpenCV's 5-coefficient model
        start = model.copy()
        start.params[9] = 0.0
        model, err = fit_camera(model, start, free=[k for k in Fraser7.PARAMS if k != "B2"], region=region)
    f, cx, cy, k1, k2, k3, p1, p2, b1, _ = model.params
    return {"fx": f + b1, "fy": f, "cx": cx, "cy": cy, "k1": k1, "k2": k2, "p1": p1, "p2": p2, "k3": k3}, err


def from_opencv(d: dict[str, float], image_size: tuple[int, int], name: str | None = None) -> CameraModel:
    """A dgcal model from OpenCV parameters (exact): opencv8 when k4..k6 are given and non-zero (or
    `name` says so), else fraser7 with f = fy, B1 = fx - fy, B2 = 0."""
    missing = [k for k in ("fx", "fy", "cx", "cy") if k not in d]
    if missing:
        raise InputError(f"OpenCV parameters lack {', '.join(missing)}", field=missing[0])
    rational = any(float(d.get(k, 0.0)) != 0.0 for k in ("k4", "k5", "k6"))
    if name is None:
        name = "opencv8" if rational else "fraser7"
    if name == "opencv8":
        return OpenCV8.from_dict(image_size, d)
    if rational:
        raise InputError("OpenCV parameters with k4..k6 cannot be held exactly by fraser7", field="k4")
    g = {k: float(d.get(k, 0.0)) for k in OPENCV5_KEYS}
    return Fraser7(image_size, [g["fy"], g["cx"], g["cy"], g["k1"], g["k2"], g["k3"], g["p1"], g["p2"],
                                g["fx"] - g["fy"], 0.0])


def opencv_K_dist(d: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """The camera matrix K (3x3) and distortion vector (5 or 8) of an OpenCV parameter dict."""
    K = np.array([[d["fx"], 0, d["cx"]], [0, d["fy"], d["cy"]], [0, 0, 1.0]])
    keys = OPENCV8_KEYS if "k4" in d else OPENCV5_KEYS
    return K, np.array([d.get(k, 0.0) for k in keys[4:]], float)


def opencv_from_K_dist(K: np.ndarray, dist: np.ndarray) -> dict[str, float]:
    """OpenCV parameter dict from K and a distortion vector of 4, 5, 8 (or more, zero-padded) terms."""
    K = np.asarray(K, float)
    dist = np.asarray(dist, float).ravel()
    if dist.size > 8 and np.any(dist[8:] != 0):
        raise InputError("thin-prism or tilt distortion terms (s1.., tau) are not supported",
                         field="distortion_coefficients")
    keys = OPENCV8_KEYS[4:] if dist.size > 5 else OPENCV5_KEYS[4:]
    vals = np.zeros(len(keys))
    vals[:min(dist.size, len(keys))] = dist[:len(keys)]
    d = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
    d.update({k: float(v) for k, v in zip(keys, vals)})
    return {k: float(v) for k, v in d.items()}


# ---------------------------------------------------------------------------------------------
# COLMAP
# ---------------------------------------------------------------------------------------------
def to_colmap(model: CameraModel, region=None) -> tuple[str, list[float], float]:
    """COLMAP camera model name, its params (pixel origin at the top-left corner: cx, cy + 0.5) and the
    max error (px): OPENCV when K3 = 0, else FULL_OPENCV (OPENCV_FISHEYE for fisheye); exact unless fraser7 has
    B2 != 0 (then fitted inside `region` when given)."""
    if isinstance(model, Fisheye):
        d = model.as_dict()
        d = dict(d, cx=d["cx"] + COLMAP_PIXEL_SHIFT, cy=d["cy"] + COLMAP_PIXEL_SHIFT)
        return "OPENCV_FISHEYE", [float(d[k]) for k in COLMAP_PARAMS["OPENCV_FISHEYE"]], 0.0
    d, err = to_opencv(model, region)
    d = dict(d, cx=d["cx"] + COLMAP_PIXEL_SHIFT, cy=d["cy"] + COLMAP_PIXEL_SHIFT)
    name = "OPENCV" if d.get("k3", 0.0) == 0.0 and not any(d.get(k, 0.0) for k in ("k4", "k5", "k6")) \
        else "FULL_OPENCV"
    return name, [float(d.get(k, 0.0)) for k in COLMAP_PARAMS[name]], err


def from_colmap(name: str, width: int, height: int, params, model: str | None = None) -> CameraModel:
    """A dgcal model from a COLMAP camera (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV,
    FULL_OPENCV), exact: cx, cy - 0.5 into dgcal's pixel-centre origin."""
    if name not in COLMAP_PARAMS:
        raise InputError(f"COLMAP camera model {name!r} is not supported (use one of {', '.join(COLMAP_PARAMS)})",
                         field="model")
    keys = COLMAP_PARAMS[name]
    params = [float(p) for p in params]
    if len(params) != len(keys):
        raise InputError(f"COLMAP {name} needs {len(keys)} params ({' '.join(keys)}), got {len(params)}",
                         field="params")
    d = dict(zip(keys, params))
    if "f" in d:
        d["fx"] = d["fy"] = d.pop("f")
    d["cx"] -= COLMAP_PIXEL_SHIFT
    d["cy"] -= COLMAP_PIXEL_SHIFT
    if name == "OPENCV_FISHEYE":
        cam = Fisheye.from_dict((width, height), d)
        return cam if model in (None, "fisheye") else convert_model(cam, model)[0]
    return from_opencv(d, (width, height), model)


# ---------------------------------------------------------------------------------------------
# Metashape
# ---------------------------------------------------------------------------------------------
def _metashape_centre(image_size) -> np.ndarray:
    """dgcal pixel coordinates of the point Metashape calls (w/2, h/2)."""
    return np.array(image_size, float) / 2.0 - METASHAPE_PIXEL_SHIFT


def to_metashape(model: CameraModel, region=None) -> tuple[dict[str, float], float]:
    """Metashape frame-camera calibration {f, cx, cy, b1, b2, k1..k4, p1..p4} and the max error (px).
    Exact for fraser7: cx, cy relative to the image centre, Metashape's p1 = our P2 and p2 = our P1; other models
    through a fraser7 fit (inside `region` when given)."""
    err = 0.0
    if not isinstance(model, Fraser7):
        model, err = convert_model(model, "fraser7", region)
    f, cx, cy, k1, k2, k3, p1, p2, b1, b2 = model.params
    c = _metashape_centre(model.image_size)
    return {"f": f, "cx": cx - c[0], "cy": cy - c[1], "b1": b1, "b2": b2, "k1": k1, "k2": k2, "k3": k3,
            "k4": 0.0, "p1": p2, "p2": p1, "p3": 0.0, "p4": 0.0}, err


@dataclass
class MetashapeFrame(_NewtonRay):
    """Metashape's full frame-camera model (k4, p3, p4 too), in Metashape's parameter names."""

    image_size: tuple[int, int]
    values: dict[str, float]

    def pinhole_K(self) -> np.ndarray:
        g = self.values
        c = _metashape_centre(self.image_size)
        return np.array([[g["f"] + g["b1"], 0, c[0] + g["cx"]], [0, g["f"], c[1] + g["cy"]], [0, 0, 1.0]])

    def _project_xy(self, xy):
        g = self.values
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        rad = 1 + r2 * (g["k1"] + r2 * (g["k2"] + r2 * (g["k3"] + r2 * g["k4"])))
        tscale = 1 + r2 * (g["p3"] + r2 * g["p4"])
        xd = x * rad + (g["p1"] * (r2 + 2 * x * x) + 2 * g["p2"] * x * y) * tscale
        yd = y * rad + (g["p2"] * (r2 + 2 * y * y) + 2 * g["p1"] * x * y) * tscale
        c = _metashape_centre(self.image_size)
        return np.column_stack([c[0] + g["cx"] + xd * (g["f"] + g["b1"]) + yd * g["b2"],
                                c[1] + g["cy"] + yd * g["f"]])


def from_metashape(values: dict[str, float], image_size: tuple[int, int],
                   name: str = "fraser7") -> tuple[CameraModel, float]:
    """A dgcal model from a Metashape calibration dict; exact to fraser7 when k4 = p3 = p4 = 0, else fitted."""
    if "f" not in values:
        raise InputError("Metashape calibration has no focal length f", field="f")
    g = {k: float(values.get(k, 0.0)) for k in METASHAPE_KEYS}
    c = _metashape_centre(image_size)
    cam = Fraser7(image_size, [g["f"], c[0] + g["cx"], c[1] + g["cy"], g["k1"], g["k2"], g["k3"],
                               g["p2"], g["p1"], g["b1"], g["b2"]])
    if g["k4"] == 0 and g["p3"] == 0 and g["p4"] == 0:
        return convert_model(cam, name) if name != "fraser7" else (cam, 0.0)
    src = MetashapeFrame(image_size, g)
    return fit_camera(src, cam if name == "fraser7" else _initial(cam, model_class(name)))


# ---------------------------------------------------------------------------------------------
# Australis / Fraser correction model (inverse form: measured -> ideal)
# ---------------------------------------------------------------------------------------------
AUSTRALIS_PARAMS = ("c", "xp", "yp", "K1", "K2", "K3", "P1", "P2", "B1", "B2")


@dataclass
class AustralisModel(_NewtonRay):
    """The Fraser (1997) / Australis correction model, photogrammetric image frame (x right, y UP,
    origin at the image centre), in mm when `pixel_size_mm` is set, else in pixels::

        x = (u - (W-1)/2) * ps - xp,   y = -(v - (H-1)/2) * ps - yp,   r^2 = x^2 + y^2
        dx = x (K1 r^2 + K2 r^4 + K3 r^6) + P1 (r^2 + 2x^2) + 2 P2 x y + B1 x + B2 y
        dy = y (K1 r^2 + K2 r^4 + K3 r^6) + P2 (r^2 + 2y^2) + 2 P1 x y
        x + dx = c X/Z,   y + dy = -c Y/Z       (X, Y, Z: camera frame, x right, y down, z forward)
    """

    image_size: tuple[int, int]
    params: np.ndarray
    pixel_size_mm: float | None = None
    PARAMS: ClassVar[tuple[str, ...]] = AUSTRALIS_PARAMS

    def __post_init__(self):
        self.params = np.asarray(self.params, float).copy()
        if self.params.shape != (10,):
            raise InputError(f"Australis model needs 10 parameters {AUSTRALIS_PARAMS}", field="params")

    def __getitem__(self, name: str) -> float:
        return float(self.params[parameter_index(name, "Australis", AUSTRALIS_PARAMS)])

    def as_dict(self) -> dict[str, float]:
        """Parameters by name (mm-based units when pixel_size_mm is set)."""
        return {k: float(v) for k, v in zip(AUSTRALIS_PARAMS, self.params)}

    @property
    def _ps(self) -> float:
        return 1.0 if self.pixel_size_mm is None else float(self.pixel_size_mm)

    def correct(self, uv: np.ndarray) -> np.ndarray:
        """Ideal normalised camera-frame coordinates (N,2) of measured pixels (N,2)."""
        c, xp, yp, k1, k2, k3, p1, p2, b1, b2 = self.params
        uv = np.atleast_2d(np.asarray(uv, float))
        ctr = (np.array(self.image_size, float) - 1.0) / 2.0
        x = (uv[:, 0] - ctr[0]) * self._ps - xp
        y = -(uv[:, 1] - ctr[1]) * self._ps - yp
        r2 = x * x + y * y
        dr = r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = x * dr + p1 * (r2 + 2 * x * x) + 2 * p2 * x * y + b1 * x + b2 * y
        dy = y * dr + p2 * (r2 + 2 * y * y) + 2 * p1 * x * y
        return np.column_stack([(x + dx) / c, -(y + dy) / c])

    def ray(self, uv: np.ndarray) -> np.ndarray:
        """Unit viewing rays (N,3) in the camera frame (the correction model is explicit this way)."""
        xy = self.correct(uv)
        d = np.column_stack([xy, np.ones(len(xy))])
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def pinhole_K(self) -> np.ndarray:
        c, xp, yp = self.params[:3] / self._ps
        ctr = (np.array(self.image_size, float) - 1.0) / 2.0
        return np.array([[c, 0, ctr[0] + xp], [0, c, ctr[1] - yp], [0, 0, 1.0]])

    def project(self, X_cam: np.ndarray) -> np.ndarray:
        """Pixels (N,2) of camera-frame points: inverts `correct` by Newton iteration."""
        X = np.atleast_2d(np.asarray(X_cam, float))
        target = X[:, :2] / X[:, 2:3]
        K = self.pinhole_K()
        uv = target * np.diag(K)[:2] + K[:2, 2]
        h = 1e-4
        f0 = self.correct(uv) - target
        for _ in range(60):
            J = np.empty((len(uv), 2, 2))
            for j in range(2):
                d = np.zeros(2)
                d[j] = h
                J[:, :, j] = (self.correct(uv + d) - self.correct(uv - d)) / (2 * h)
            step = np.linalg.solve(J, f0[..., None])[..., 0]
            # backtracking per point: strong wide-angle polynomials fold over far out, plain Newton jumps
            t = np.ones(len(uv))
            for _ in range(12):
                f1 = self.correct(uv - t[:, None] * step) - target
                worse = np.sum(f1 * f1, axis=1) > np.sum(f0 * f0, axis=1)
                if not worse.any():
                    break
                t[worse] *= 0.5
            uv = uv - t[:, None] * step
            f0 = f1
            if np.max(np.abs(t[:, None] * step), initial=0.0) < 1e-10:
                break
        return uv

    def with_pixel_size(self, pixel_size_mm: float | None) -> "AustralisModel":
        """The same model expressed in mm (pixel size given) or pixels (None)."""
        s = (1.0 if pixel_size_mm is None else float(pixel_size_mm)) / self._ps  # new units per old unit
        c, xp, yp, k1, k2, k3, p1, p2, b1, b2 = self.params
        return AustralisModel(self.image_size, [c * s, xp * s, yp * s, k1 / s**2, k2 / s**4, k3 / s**6,
                                                p1 / s, p2 / s, b1, b2], pixel_size_mm)


def to_australis(model, pixel_size_mm: float | None = None,
                 grid: tuple[int, int] = (41, 29)) -> tuple[AustralisModel, float]:
    """The Australis correction model fitted to `model` (any model with ray/project/pinhole_K) over the
    frame, in mm if `pixel_size_mm` is given; returns (model, max image error px)."""
    K = model.pinhole_K()
    ctr = (np.array(model.image_size, float) - 1.0) / 2.0
    aus = AustralisModel(model.image_size, [K[1, 1], K[0, 2] - ctr[0], -(K[1, 2] - ctr[1]),
                                            0, 0, 0, 0, 0, 0, 0])
    uv = frame_grid(model.image_size, grid)
    rays = model.ray(uv)
    xy = rays[:, :2] / rays[:, 2:3]
    f = K[1, 1]
    # the correction is linear in K1..B2 once c, xp, yp are fixed: a linear solve gives LM a good start
    lin = np.empty((2 * len(uv), 7))
    for j in range(7):
        probe = aus.params.copy()
        probe[3:] = 0.0
        probe[3 + j] = 1.0
        aus.params[:] = probe
        base = aus.params.copy()
        base[3:] = 0.0
        lin[:, j] = (aus.correct(uv) - AustralisModel(model.image_size, base).correct(uv)).ravel()
    aus.params[3:] = 0.0
    aus.params[3:] = np.linalg.lstsq(lin, (xy - aus.correct(uv)).ravel(), rcond=None)[0]

    def residual(p):
        aus.params[:] = p
        return ((aus.correct(uv) - xy) * f).ravel()

    sol = least_squares(residual, aus.params.copy(), method="lm", x_scale="jac",
                        xtol=1e-15, ftol=1e-15, gtol=1e-15)
    aus.params[:] = sol.x
    err = max_projection_difference(model, aus)
    return (aus if pixel_size_mm is None else aus.with_pixel_size(pixel_size_mm)), err


def from_australis(aus: AustralisModel, name: str = "fraser7") -> tuple[CameraModel, float]:
    """A dgcal model fitted to an Australis correction model over the frame; (model, max error px)."""
    return fit_camera(aus, _initial(aus, model_class(name)))


# ---------------------------------------------------------------------------------------------
# MicMac
# ---------------------------------------------------------------------------------------------
@dataclass
class MicMacV1(_NewtonRay):
    """MicMac V1 `CalibrationInternConique` with distortion world -> camera (eConvApero_DistM2C), the
    radial model `ModRad` and the photogrammetric `ModPhgrStd` (Fraser) model, all in pixels::

        (i, j) = PP + F (X/Z, Y/Z)                         ideal pixels
        d = (i, j) - CDist,  r^2 = |d|^2
        dr = d (1 + c1 r^2 + c2 r^4 + ...)                 ModRad
        ModPhgrStd adds  P1 (r^2 + 2dx^2) + 2 P2 dx dy + b1 dx + b2 dy,  P2 (r^2 + 2dy^2) + 2 P1 dx dy
        distorted = CDist + dr (+ those terms)
    """

    image_size: tuple[int, int]
    F: float
    PP: np.ndarray
    cdist: np.ndarray
    coeffs: np.ndarray
    P1: float = 0.0
    P2: float = 0.0
    b1: float = 0.0
    b2: float = 0.0

    def pinhole_K(self) -> np.ndarray:
        return np.array([[self.F, 0, self.PP[0]], [0, self.F, self.PP[1]], [0, 0, 1.0]])

    def _project_xy(self, xy):
        d = self.PP + self.F * xy - self.cdist
        r2 = np.sum(d * d, axis=1)
        fac = np.ones_like(r2)
        rp = np.ones_like(r2)
        for c in self.coeffs:
            rp = rp * r2
            fac = fac + c * rp
        dx, dy = d[:, 0], d[:, 1]
        out = d * fac[:, None]
        out[:, 0] += self.P1 * (r2 + 2 * dx * dx) + 2 * self.P2 * dx * dy + self.b1 * dx + self.b2 * dy
        out[:, 1] += self.P2 * (r2 + 2 * dy * dy) + 2 * self.P1 * dx * dy
        return self.cdist + out


@dataclass
class MicMacMMVII(_NewtonRay):
    """MMVII `PerspCentral` calibration with a `Stenope` projection, distortion on normalised
    coordinates (p = (X/Z, Y/Z), r^2 = |p|^2), then pixels = PP + F dist(p)::

        dist(p) = p (1 + K1 r^2 + K2 r^4 + ...) + p1 (3x^2 + y^2, 2xy) + p2 (2xy, x^2 + 3y^2)
                  + b1 (x, 0) + b2 (y, 0)
    """

    image_size: tuple[int, int]
    F: float
    PP: np.ndarray
    K: np.ndarray
    p1: float = 0.0
    p2: float = 0.0
    b1: float = 0.0
    b2: float = 0.0

    def pinhole_K(self) -> np.ndarray:
        return np.array([[self.F, 0, self.PP[0]], [0, self.F, self.PP[1]], [0, 0, 1.0]])

    def _project_xy(self, xy):
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        fac = np.ones_like(r2)
        rp = np.ones_like(r2)
        for k in self.K:
            rp = rp * r2
            fac = fac + k * rp
        xd = x * fac + self.p1 * (3 * x * x + y * y) + self.p2 * 2 * x * y + self.b1 * x + self.b2 * y
        yd = y * fac + self.p1 * 2 * x * y + self.p2 * (x * x + 3 * y * y)
        return self.PP + self.F * np.column_stack([xd, yd])


def from_micmac(mm, name: str = "fraser7") -> tuple[CameraModel, float]:
    """The dgcal model closest to a MicMac calibration (fitted over the frame); (model, max error px)."""
    return fit_camera(mm, _initial(mm, model_class(name)))
