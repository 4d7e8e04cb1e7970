"""Camera models: `fraser7` (f, cx, cy, K1-K3, P1, P2, B1, B2), `opencv8` (OpenCV rational), `fisheye` (Kannala-Brandt).

Pixel coordinates follow OpenCV: x right, y down, origin at the centre of the top-left pixel.
Camera frame: x right, y down, z forward. With normalised coordinates x = X/Z, y = Y/Z and
r^2 = x^2 + y^2, both models are forward models (ideal -> distorted):

fraser7 (Metashape's form, all parameters in pixels except the dimensionless K, P)::

    radial = 1 + K1 r^2 + K2 r^4 + K3 r^6
    xd = x radial + P1 2xy + P2 (r^2 + 2x^2)
    yd = y radial + P1 (r^2 + 2y^2) + P2 2xy
    u = cx + (f + B1) xd + B2 yd
    v = cy + f yd

P1, P2 here are OpenCV's p1, p2 (Metashape's XML swaps them; see dgcal.calib.camera.conversions), so
fraser7 equals OpenCV's 5-coefficient model exactly when B2 = 0 (fx = f + B1, fy = f).

opencv8 (OpenCV's rational model)::

    radial = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
    xd = x radial + 2 p1 xy + p2 (r^2 + 2x^2);  yd = y radial + p1 (r^2 + 2y^2) + 2 p2 xy
    u = fx xd + cx;  v = fy yd + cy

fisheye (Kannala-Brandt, OpenCV's cv::fisheye without skew, COLMAP OPENCV_FISHEYE)::

    theta = atan(r);  theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
    (xd, yd) = (x, y) theta_d / r;  u = fx xd + cx;  v = fy yd + cy
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import cv2
import numpy as np

from dgcal.fields.errors import InputError


class UnknownParameterError(KeyError):
    """A camera parameter the model does not have (`cam["fx"]` on fraser7): the message names the model's own."""

    def __init__(self, name: str, model: str, params: tuple[str, ...]):
        super().__init__(name)
        self.message = (f"camera model {model or 'camera'} has no parameter {name!r}; its parameters are "
                        f"{', '.join(params)}")

    def __str__(self) -> str:
        return self.message


def parameter_index(name: str, model: str, params: tuple[str, ...]) -> int:
    """Position of parameter `name` in `params`, or `UnknownParameterError` naming the model's parameters."""
    try:
        return params.index(name)
    except ValueError:
        raise UnknownParameterError(name, model, params) from None


@dataclass
class CameraModel:
    """Base class: a parameter vector in the order `PARAMS` and the image size [width, height] (px)."""

    image_size: tuple[int, int]
    params: np.ndarray
    NAME: ClassVar[str] = ""
    PARAMS: ClassVar[tuple[str, ...]] = ()
    sigmas: np.ndarray | None = field(default=None)

    def __post_init__(self):
        self.params = np.asarray(self.params, dtype=float).copy()
        if self.params.shape != (len(self.PARAMS),):
            raise InputError(f"{self.NAME} needs {len(self.PARAMS)} parameters {self.PARAMS}, got {self.params.shape}")
        self.image_size = (int(self.image_size[0]), int(self.image_size[1]))

    # --- parameter access -------------------------------------------------------------
    def as_dict(self) -> dict[str, float]:
        """Parameters by name."""
        return {k: float(v) for k, v in zip(self.PARAMS, self.params)}

    def __getitem__(self, name: str) -> float:
        """The parameter called `name` (px or dimensionless); `UnknownParameterError` (a KeyError) if the model
        has no such parameter."""
        return float(self.params[parameter_index(name, self.NAME, self.PARAMS)])

    @classmethod
    def from_dict(cls, image_size, values: dict[str, float]) -> "CameraModel":
        """A model from named parameters; missing distortion terms are 0."""
        return cls(image_size, np.array([float(values.get(k, 0.0)) for k in cls.PARAMS]))

    def copy(self) -> "CameraModel":
        return type(self)(self.image_size, self.params.copy(),
                          None if self.sigmas is None else np.array(self.sigmas, float).copy())

    # --- model ---------------------------------------------------------------------------
    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Distorted normalised coordinates from ideal ones, (N,2) -> (N,2)."""
        raise NotImplementedError

    def distort_jacobian(self, xy: np.ndarray) -> np.ndarray:
        """d(distorted)/d(ideal) for normalised coordinates, (N,2,2)."""
        raise NotImplementedError

    def to_pixels(self, xyd: np.ndarray) -> np.ndarray:
        """Pixels from distorted normalised coordinates."""
        raise NotImplementedError

    def from_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Distorted normalised coordinates from pixels."""
        raise NotImplementedError

    def project(self, X_cam: np.ndarray) -> np.ndarray:
        """Pixels (N,2) of points in the camera frame (N,3), x right, y down, z forward."""
        X = np.atleast_2d(np.asarray(X_cam, float))
        return self.to_pixels(self.distort(X[:, :2] / X[:, 2:3]))

    def undistort_normalized(self, uv: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Ideal normalised coordinates (N,2) of pixels (N,2), by Newton iteration on `distort`."""
        target = self.from_pixels(np.atleast_2d(np.asarray(uv, float)))
        xy = target.copy()
        for _ in range(iterations):
            res = self.distort(xy) - target
            J = self.distort_jacobian(xy)
            step = np.linalg.solve(J, res[..., None])[..., 0]
            xy -= step
            if np.max(np.abs(step), initial=0.0) < 1e-14:
                break
        return xy

    def ray(self, uv: np.ndarray) -> np.ndarray:
        """Unit viewing rays (N,3) in the camera frame for pixels (N,2)."""
        xy = self.undistort_normalized(uv)
        d = np.column_stack([xy, np.ones(len(xy))])
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def undistort_points(self, uv: np.ndarray, K_new: np.ndarray | None = None) -> np.ndarray:
        """Pixels of an ideal pinhole camera `K_new` (default: same focal length and centre) for distorted pixels."""
        xy = self.undistort_normalized(uv)
        K = self.pinhole_K() if K_new is None else K_new
        return xy @ K[:2, :2].T + K[:2, 2]

    def pinhole_K(self) -> np.ndarray:
        """The 3x3 pinhole matrix of the model's linear part (skew dropped)."""
        raise NotImplementedError

    def project_with_jacobians(self, X_cam: np.ndarray, params: bool = True
                               ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """Pixels (N,2) of camera-frame points (N,3) with d(uv)/d(params) (N,2,P) (None when `params` is False)
        and d(uv)/d(X_cam) (N,2,3)."""
        X = np.atleast_2d(np.asarray(X_cam, float))
        iz = 1.0 / X[:, 2]
        xy = X[:, :2] * iz[:, None]
        xyd = self.distort(xy)
        uv = self.to_pixels(xyd)
        J_params = self._param_jacobian(xy, xyd) if params else None
        return uv, J_params, _point_jacobian(self.pixel_jacobian(), self.distort_jacobian(xy), xy, iz)

    def pixel_jacobian(self) -> np.ndarray:
        """d(uv)/d(distorted normalised xy), the constant 2x2 linear part (px)."""
        raise NotImplementedError

    def opencv_K_dist(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(K, distortion vector) when the model is exactly an OpenCV model, else None."""
        return None

    def _param_jacobian(self, xy: np.ndarray, xyd: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def undistortion_maps(self, K_new: np.ndarray | None = None, size: tuple[int, int] | None = None,
                          rows_per_block: int = 256) -> tuple[np.ndarray, np.ndarray]:
        """cv2.remap maps (float32, height x width): for each pixel of the ideal pinhole image `K_new`, its
        position (px) in the distorted image. Default K_new: `pinhole_K()`; default size: the image size."""
        K = self.pinhole_K() if K_new is None else np.asarray(K_new, float)
        w, h = self.image_size if size is None else (int(size[0]), int(size[1]))
        cv = self.opencv_K_dist()
        if cv is not None:
            # the model is exactly OpenCV's: its C++ map builder is ~20x faster than NumPy here
            return cv2.initUndistortRectifyMap(cv[0], cv[1], None, K, (w, h), cv2.CV_32FC1)
        map_x = np.empty((h, w), np.float32)
        map_y = np.empty((h, w), np.float32)
        Kinv = np.linalg.inv(K)
        u = np.arange(w, dtype=float)
        # in blocks of rows so a 24 MP map never needs GBs of float64 temporaries
        for r0 in range(0, h, rows_per_block):
            v = np.arange(r0, min(h, r0 + rows_per_block), dtype=float)
            uu, vv = np.meshgrid(u, v)
            hom = Kinv[:, 0, None] * uu.ravel() + Kinv[:, 1, None] * vv.ravel() + Kinv[:, 2, None]
            uvd = self.to_pixels(self.distort((hom[:2] / hom[2]).T))
            map_x[r0:r0 + len(v)] = uvd[:, 0].reshape(len(v), w)
            map_y[r0:r0 + len(v)] = uvd[:, 1].reshape(len(v), w)
        return map_x, map_y

    def undistort_image(self, img: np.ndarray, K_new: np.ndarray | None = None,
                        size: tuple[int, int] | None = None, interpolation: int | None = None) -> np.ndarray:
        """The image resampled to the ideal pinhole camera `K_new` (default `pinhole_K()`), via cv2.remap."""
        map_x, map_y = self.undistortion_maps(K_new, size)
        return cv2.remap(img, map_x, map_y, cv2.INTER_LINEAR if interpolation is None else interpolation,
                         borderMode=cv2.BORDER_CONSTANT)


def _point_jacobian(P: np.ndarray, D: np.ndarray, xy: np.ndarray, iz: np.ndarray) -> np.ndarray:
    """d(uv)/d(X_cam) (N,2,3) px/m by the chain rule pixels <- distorted (P, 2x2) <- ideal normalised (D, (N,2,2))
    <- camera-frame point (iz = 1/Z (N,), xy = (X/Z, Y/Z) (N,2)), written out entry by entry: NumPy's batched
    matmul of 2x2 stacks costs ~10x the arithmetic."""
    J = np.empty((len(xy), 2, 3))
    mx, my = -xy[:, 0] * iz, -xy[:, 1] * iz
    for a in range(2):
        gx = P[a, 0] * D[:, 0, 0] + P[a, 1] * D[:, 1, 0]    # d(uv_a)/dx
        gy = P[a, 0] * D[:, 0, 1] + P[a, 1] * D[:, 1, 1]    # d(uv_a)/dy
        J[:, a, 0] = gx * iz
        J[:, a, 1] = gy * iz
        J[:, a, 2] = gx * mx + gy * my
    return J


def _brown_distort_jacobian(x, y, rad, drad, p1, p2) -> np.ndarray:
    """d(distorted)/d(ideal) (N,2,2) of `radial(r^2) * xy + Brown tangential(p1, p2)`; drad = d radial / d r^2."""
    J = np.empty((len(x), 2, 2))
    J[:, 0, 0] = rad + x * drad * 2 * x + 2 * p1 * y + 6 * p2 * x
    J[:, 0, 1] = x * drad * 2 * y + 2 * p1 * x + 2 * p2 * y
    J[:, 1, 0] = y * drad * 2 * x + 2 * p1 * x + 2 * p2 * y
    J[:, 1, 1] = rad + y * drad * 2 * y + 6 * p1 * y + 2 * p2 * x
    return J


def _radial_r2(xy):
    x, y = xy[:, 0], xy[:, 1]
    return x, y, x * x + y * y


class Fraser7(CameraModel):
    """f, cx, cy (px), K1, K2, K3, P1, P2 (OpenCV p1, p2), B1, B2 (px): Metashape-style forward model."""

    NAME = "fraser7"
    PARAMS = ("f", "cx", "cy", "K1", "K2", "K3", "P1", "P2", "B1", "B2")

    def distort(self, xy):
        _, _, _, k1, k2, k3, p1, p2, _, _ = self.params
        x, y, r2 = _radial_r2(np.atleast_2d(xy))
        rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.column_stack([xd, yd])

    def distort_jacobian(self, xy):
        _, _, _, k1, k2, k3, p1, p2, _, _ = self.params
        x, y, r2 = _radial_r2(np.atleast_2d(xy))
        rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d rad / d r2
        return _brown_distort_jacobian(x, y, rad, drad, p1, p2)

    def to_pixels(self, xyd):
        f, cx, cy = self.params[:3]
        b1, b2 = self.params[8:10]
        return np.column_stack([cx + (f + b1) * xyd[:, 0] + b2 * xyd[:, 1], cy + f * xyd[:, 1]])

    def from_pixels(self, uv):
        f, cx, cy = self.params[:3]
        b1, b2 = self.params[8:10]
        yd = (uv[:, 1] - cy) / f
        xd = (uv[:, 0] - cx - b2 * yd) / (f + b1)
        return np.column_stack([xd, yd])

    def pinhole_K(self):
        f, cx, cy = self.params[:3]
        return np.array([[f + self.params[8], 0, cx], [0, f, cy], [0, 0, 1.0]])

    def pixel_jacobian(self):
        f, b1, b2 = self.params[0], self.params[8], self.params[9]
        return np.array([[f + b1, b2], [0.0, f]])

    def opencv_K_dist(self):
        if self.params[9] != 0.0:
            return None
        k1, k2, k3, p1, p2 = self.params[3:8]
        return self.pinhole_K(), np.array([k1, k2, p1, p2, k3])

    def _param_jacobian(self, xy, xyd):
        x, y, r2 = _radial_r2(xy)
        r4 = r2 * r2
        xy2 = 2 * x * y
        # d(xd, yd)/d(K1, K2, K3, P1, P2), then through the pixel part column by column (no batched matmul)
        D = ((x * r2, y * r2), (x * r4, y * r4), (x * (r4 * r2), y * (r4 * r2)), (xy2, r2 + 2 * y * y),
             (r2 + 2 * x * x, xy2))
        P = self.pixel_jacobian()
        J = np.zeros((len(x), 2, 10))
        J[:, 0, 0] = xyd[:, 0]
        J[:, 1, 0] = xyd[:, 1]
        J[:, 0, 1] = 1.0
        J[:, 1, 2] = 1.0
        for j, (dx, dy) in enumerate(D):
            J[:, 0, 3 + j] = P[0, 0] * dx + P[0, 1] * dy
            J[:, 1, 3 + j] = P[1, 1] * dy           # P[1, 0] = 0: v = cy + f yd
        J[:, 0, 8] = xyd[:, 0]
        J[:, 0, 9] = xyd[:, 1]
        return J


class OpenCVPixels(CameraModel):
    """A model whose linear part is OpenCV's K: fx, fy, cx, cy (px) are its first four parameters, no skew."""

    def to_pixels(self, xyd):
        fx, fy, cx, cy = self.params[:4]
        return np.column_stack([fx * xyd[:, 0] + cx, fy * xyd[:, 1] + cy])

    def from_pixels(self, uv):
        fx, fy, cx, cy = self.params[:4]
        return np.column_stack([(uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy])

    def pinhole_K(self):
        fx, fy, cx, cy = self.params[:4]
        return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])

    def pixel_jacobian(self):
        return np.diag(self.params[:2]).astype(float)


class OpenCV8(OpenCVPixels):
    """OpenCV rational model: fx, fy, cx, cy (px), k1, k2, p1, p2, k3, k4, k5, k6 (OpenCV's order)."""

    NAME = "opencv8"
    PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")

    def _rad(self, r2):
        k1, k2, p1, p2, k3, k4, k5, k6 = self.params[4:]
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        dnum = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        dden = k4 + r2 * (2 * k5 + 3 * k6 * r2)
        return num / den, (dnum * den - num * dden) / den**2

    def distort(self, xy):
        p1, p2 = self.params[6:8]
        x, y, r2 = _radial_r2(np.atleast_2d(xy))
        rad, _ = self._rad(r2)
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.column_stack([xd, yd])

    def distort_jacobian(self, xy):
        p1, p2 = self.params[6:8]
        x, y, r2 = _radial_r2(np.atleast_2d(xy))
        rad, drad = self._rad(r2)
        return _brown_distort_jacobian(x, y, rad, drad, p1, p2)

    def opencv_K_dist(self):
        return self.pinhole_K(), self.params[4:].copy()

    def _param_jacobian(self, xy, xyd):
        k1, k2, p1, p2, k3, k4, k5, k6 = self.params[4:]
        x, y, r2 = _radial_r2(xy)
        n = len(x)
        r4 = r2 * r2
        r6 = r4 * r2
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        # d radial / d(k1, k2, p1, p2, k3, k4, k5, k6); p1, p2 act on the tangential part only
        drad = np.zeros((n, 8))
        drad[:, 0], drad[:, 1], drad[:, 4] = r2 / den, r4 / den, r6 / den
        q = -num / den**2
        drad[:, 5], drad[:, 6], drad[:, 7] = q * r2, q * r4, q * r6
        D = np.empty((n, 2, 8))
        D[:, 0, :] = x[:, None] * drad
        D[:, 1, :] = y[:, None] * drad
        D[:, 0, 2] = 2 * x * y
        D[:, 1, 2] = r2 + 2 * y * y
        D[:, 0, 3] = r2 + 2 * x * x
        D[:, 1, 3] = 2 * x * y
        fx, fy = self.params[:2]
        J = np.zeros((n, 2, 12))
        J[:, 0, 0] = xyd[:, 0]
        J[:, 1, 1] = xyd[:, 1]
        J[:, 0, 2] = 1.0
        J[:, 1, 3] = 1.0
        J[:, 0, 4:] = fx * D[:, 0]
        J[:, 1, 4:] = fy * D[:, 1]
        return J


class Fisheye(OpenCVPixels):
    """Kannala-Brandt / OpenCV fisheye (cv::fisheye, COLMAP OPENCV_FISHEYE): fx, fy, cx, cy (px), k1..k4 on the
    angle theta = atan(r) of the ray from the optical axis: theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6
    + k4 theta^8), distorted = (x, y) theta_d / r, u = fx xd + cx, v = fy yd + cy (no skew; rays within 90 deg of
    the axis, z > 0)."""

    NAME = "fisheye"
    PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")

    def _theta(self, r):
        """theta, theta_d(theta), d theta_d / d theta, and the odd powers theta^3..theta^9."""
        k1, k2, k3, k4 = self.params[4:]
        th = np.arctan(r)
        t2 = th * th
        thd = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        dthd = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        return th, thd, dthd

    def _scale(self, r):
        """s = theta_d / r and (ds/dr) / r, with their limits at r -> 0."""
        k1 = self.params[4]
        small = r < 1e-6
        rs = np.where(small, 1.0, r)
        th, thd, dthd = self._theta(rs)
        s = thd / rs
        ds_r = (dthd / (1 + rs * rs) * rs - thd) / rs**3
        return np.where(small, 1.0, s), np.where(small, 2 * (k1 - 1.0 / 3.0), ds_r)

    def distort(self, xy):
        xy = np.atleast_2d(xy)
        s, _ = self._scale(np.hypot(xy[:, 0], xy[:, 1]))
        return xy * s[:, None]

    def distort_jacobian(self, xy):
        xy = np.atleast_2d(xy)
        s, ds_r = self._scale(np.hypot(xy[:, 0], xy[:, 1]))
        J = ds_r[:, None, None] * xy[:, :, None] * xy[:, None, :]
        J[:, 0, 0] += s
        J[:, 1, 1] += s
        return J

    def undistort_normalized(self, uv, iterations: int = 30):
        """Ideal normalised coordinates of pixels: theta from theta_d by 1-D Newton (monotonic part), r = tan(theta)."""
        xyd = self.from_pixels(np.atleast_2d(np.asarray(uv, float)))
        thd = np.hypot(xyd[:, 0], xyd[:, 1])
        th = np.clip(thd, 0, 1.5)
        for _ in range(iterations):
            _, f, df = self._theta(np.tan(th))
            step = (f - thd) / np.where(np.abs(df) > 1e-12, df, 1e-12)
            th = np.clip(th - step, 0.0, np.pi / 2 - 1e-9)
            if np.max(np.abs(step), initial=0.0) < 1e-15:
                break
        r = np.tan(th)
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.where(thd > 1e-15, r / np.where(thd > 1e-15, thd, 1.0), 1.0)
        return xyd * k[:, None]

    def _param_jacobian(self, xy, xyd):
        r = np.hypot(xy[:, 0], xy[:, 1])
        small = r < 1e-6
        rs = np.where(small, 1.0, r)
        th = np.arctan(rs)
        n = len(r)
        J = np.zeros((n, 2, 8))
        J[:, 0, 0] = xyd[:, 0]
        J[:, 1, 1] = xyd[:, 1]
        J[:, 0, 2] = 1.0
        J[:, 1, 3] = 1.0
        fx, fy = self.params[:2]
        for j in range(4):
            # d(xd, yd)/dk_j = (x, y) theta^(2j+3) / r  (-> 0 at the axis)
            g = np.where(small, 0.0, th ** (2 * j + 3) / rs)
            J[:, 0, 4 + j] = fx * xy[:, 0] * g
            J[:, 1, 4 + j] = fy * xy[:, 1] * g
        return J


MODELS: dict[str, type[CameraModel]] = {m.NAME: m for m in (Fraser7, OpenCV8, Fisheye)}


def model_class(name: str) -> type[CameraModel]:
    """The camera model class for a name ('fraser7', 'opencv8' or 'fisheye')."""
    try:
        return MODELS[name]
    except KeyError:
        raise InputError(f"unknown camera model {name!r}; choose one of {', '.join(MODELS)}", field="model") from None
