"""Render textured planar facets through a dgcal camera model (exact for the lens distortion).

For each output pixel the camera model's inverse (`undistort_normalized`, the ideal ray) is intersected with
each facet's plane and the facet texture is sampled with cv2.remap; a z-buffer keeps the nearest facet.
Anti-aliasing: each pixel averages k x k sub-samples at offsets (m + 0.5)/k - 0.5 px, whose rays are
interpolated bilinearly from the rays of the pixel grid (rays vary smoothly, the error is far below 1e-3 px).
Textures should themselves be area-filtered (see dgcal.fields.targets.texture.field_texture).

Generic: a facet is any textured parallelogram in a world frame (a plate, a block face, a ground tile).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from dgcal.calib.camera.models import CameraModel


@dataclass
class Facet:
    """A textured planar parallelogram in the world frame.

    The centre of texel (row i, col j) lies at `origin_w + j * du_w + i * dv_w` (m); `grey` is the
    radiance (H x W; float32 0..1, or uint8/uint16 scaled to 0..1); `alpha` (same shape, 0..1) the coverage of the
    surface, None = opaque."""

    origin_w: np.ndarray
    du_w: np.ndarray
    dv_w: np.ndarray
    grey: np.ndarray
    alpha: np.ndarray | None = None


class RayGrid:
    """Ideal normalised image coordinates (x/z, y/z) of every pixel of a camera, padded by one pixel on each
    side (pixel -1 .. W), float32 (H+2, W+2, 2); computed once per camera and shared by all its images."""

    def __init__(self, camera: CameraModel, rows_per_block: int = 128):
        w, h = camera.image_size
        self.camera = camera
        self.xy = np.empty((h + 2, w + 2, 2), np.float32)
        u = np.arange(-1, w + 1, dtype=float)
        for r0 in range(-1, h + 1, rows_per_block):
            v = np.arange(r0, min(h + 1, r0 + rows_per_block), dtype=float)
            uu, vv = np.meshgrid(u, v)
            xy = camera.undistort_normalized(np.column_stack([uu.ravel(), vv.ravel()]))
            self.xy[r0 + 1:r0 + 1 + len(v)] = xy.reshape(len(v), w + 2, 2)


def _upsample_axis(a: np.ndarray, k: int, axis: int) -> np.ndarray:
    """Linear interpolation of the interior of `a` (one padding cell at each end of `axis`) at k sub-positions."""
    a = np.moveaxis(a, axis, 0)
    mid, lo, hi = a[1:-1], a[:-2], a[2:]
    subs = []
    for m in range(k):
        d = (m + 0.5) / k - 0.5
        subs.append(mid * (1 + d) - lo * d if d < 0 else mid * (1 - d) + hi * d)
    out = np.stack(subs, axis=1).reshape((mid.shape[0] * k,) + mid.shape[1:])
    return np.moveaxis(out, 0, axis)


_SCALE = {np.dtype(np.uint8): 1 / 255, np.dtype(np.uint16): 1 / 65535, np.dtype(np.float32): 1.0}


def _opaque(shape: tuple[int, int], col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Coverage of an opaque facet: 1 over its texels [-0.5, W-0.5] x [-0.5, H-0.5], 0 outside (bilinear edge)."""
    hgt, wid = shape
    a = np.clip(np.minimum(col + 1.0, wid - col), 0, 1) * np.clip(np.minimum(row + 1.0, hgt - row), 0, 1)
    return a.astype(np.float32)


def _sample(tex: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Bilinear texture lookup scaled to 0..1 (float32), 0 outside the texture."""
    if tex.dtype not in _SCALE:
        tex = tex.astype(np.float32)
    out = cv2.remap(tex, col, row, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.astype(np.float32) * np.float32(_SCALE[tex.dtype])


def render(camera: CameraModel, R_world_to_cam: np.ndarray, t_world_to_cam: np.ndarray, facets: list[Facet],
           background: float = 0.0, supersample: int = 2, rays: RayGrid | None = None,
           rows_per_block: int = 128) -> np.ndarray:
    """Radiance image (float32, H x W) of `facets` seen by `camera` with X_cam = R_world_to_cam X_w + t (m)."""
    w, h = camera.image_size
    rays = RayGrid(camera) if rays is None else rays
    R_world_to_cam = np.asarray(R_world_to_cam, float)
    t = np.asarray(t_world_to_cam, float).ravel()
    k = int(supersample)
    # per facet, linear forms in d = (x, y, 1): depth s = no / (n.d), texel (col, row) = s (m.d) - m.o
    forms = []
    for f in facets:
        du, dv = R_world_to_cam @ np.asarray(f.du_w, float), R_world_to_cam @ np.asarray(f.dv_w, float)
        o = R_world_to_cam @ np.asarray(f.origin_w, float) + t
        n = np.cross(du, dv)
        M_inv = np.linalg.inv(np.column_stack([du, dv, n]))
        forms.append((n, float(n @ o), M_inv[0], M_inv[1], float(M_inv[0] @ o), float(M_inv[1] @ o),
                      np.ascontiguousarray(f.grey), None if f.alpha is None else np.ascontiguousarray(f.alpha)))
    out = np.empty((h, w), np.float32)
    for r0 in range(0, h, rows_per_block):
        r1 = min(h, r0 + rows_per_block)
        xy = rays.xy[r0:r1 + 2]
        xy = _upsample_axis(_upsample_axis(xy, k, 0), k, 1) if k > 1 else xy[1:-1, 1:-1]
        x, y = xy[..., 0], xy[..., 1]
        img = np.full(x.shape, background, np.float32)
        depth = np.full(x.shape, np.inf, np.float32)
        for n, no, m0, m1, m0o, m1o, grey, alpha in forms:
            with np.errstate(divide="ignore", invalid="ignore"):
                s = (no / (n[0] * x + n[1] * y + n[2])).astype(np.float32)
                col = (s * (m0[0] * x + m0[1] * y + m0[2]) - m0o).astype(np.float32)
                row = (s * (m1[0] * x + m1[1] * y + m1[2]) - m1o).astype(np.float32)
            ok = (s > 0) & (s < depth)
            col[~ok] = -10.0
            row[~ok] = -10.0
            val = _sample(grey, col, row)
            a = _opaque(grey.shape, col, row) if alpha is None else _sample(alpha, col, row)
            hit = ok & (a > 0)
            img[hit] = a[hit] * val[hit] + (1 - a[hit]) * img[hit]
            solid = ok & (a >= 0.5)
            depth[solid] = s[solid]
        if k > 1:
            img = img.reshape(r1 - r0, k, w, k).mean(axis=(1, 3))
        out[r0:r1] = img
    return out


def facet_depth_at(points_cam: np.ndarray, facets: list[Facet], R_world_to_cam: np.ndarray,
                   t_world_to_cam: np.ndarray) -> np.ndarray:
    """Depth (m, camera z) of the nearest solid facet (alpha >= 0.5) along the ray to each camera-frame point."""
    R_world_to_cam = np.asarray(R_world_to_cam, float)
    t = np.asarray(t_world_to_cam, float).ravel()
    d = np.asarray(points_cam, float) / np.asarray(points_cam, float)[:, 2:3]
    best = np.full(len(d), np.inf)
    for f in facets:
        du, dv = R_world_to_cam @ np.asarray(f.du_w, float), R_world_to_cam @ np.asarray(f.dv_w, float)
        o = R_world_to_cam @ np.asarray(f.origin_w, float) + t
        n = np.cross(du, dv)
        M_inv = np.linalg.inv(np.column_stack([du, dv, n]))
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (n @ o) / (d @ n)
        P = s[:, None] * d
        cr = (P - o) @ M_inv[:2].T
        hgt, wid = f.grey.shape
        j, i = np.rint(cr[:, 0]), np.rint(cr[:, 1])
        inside = (s > 0) & (j >= 0) & (j < wid) & (i >= 0) & (i < hgt)
        if f.alpha is not None:
            a = np.zeros(len(d))
            a[inside] = f.alpha[i[inside].astype(int), j[inside].astype(int)]
            inside &= a >= 0.5
        best = np.where(inside & (s < best), s, best)
    return best
