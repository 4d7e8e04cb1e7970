"""Where a calibrated camera model can be trusted: its monotonic region and the observed region of the frame.

- Monotonic region: along every direction from the principal point the model's distorted radius must grow
  with the ideal one (d r_d / d r > 0) and the distortion must not fold (det d(distorted)/d(ideal) > 0). A
  polynomial fitted to observations that do not reach the frame corners can turn back there: beyond the first
  fold a pixel has two rays (or none). The region is star-shaped around the principal point; its boundary is
  found along 180 directions (ideal radii sampled finely up to 85 deg off the axis) and stored as a polygon in
  pixels (points beyond the frame where the model stays monotonic across it).
- Observed region: the convex hull of the pixels of the observations the calibration used (px). Outside it the
  model is an extrapolation, however well it fits inside.
- Valid region: both. Conversions between models are fitted and checked only there (dgcal.calib.camera.conversions),
  and the exports say so.

Pixels: OpenCV convention (x right, y down, origin at the centre of the top-left pixel).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

N_DIRECTIONS = 180
MAX_ANGLE_DEG = 85.0


def monotonic_boundary(model, n_dir: int = N_DIRECTIONS, n_r: int = 3000) -> tuple[np.ndarray, bool]:
    """Polygon (n_dir, 2) px of the boundary of the model's monotonic region around its principal point, and
    whether the whole frame lies inside it."""
    w, h = model.image_size
    K = model.pinhole_K()
    c = K[:2, 2]
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], float)
    reach = 1.05 * float(np.max(np.linalg.norm(corners - c, axis=1)))
    phi = np.linspace(0, 2 * np.pi, n_dir, endpoint=False)
    e = np.column_stack([np.cos(phi), np.sin(phi)])
    # ideal radii: fine near the axis, up to MAX_ANGLE_DEG off it
    r = np.tan(np.radians(MAX_ANGLE_DEG)) * np.linspace(0, 1, n_r) ** 1.5
    xy = (r[None, :, None] * e[:, None, :]).reshape(-1, 2)
    with np.errstate(all="ignore"):
        uv = model.to_pixels(model.distort(xy)).reshape(n_dir, n_r, 2)
        det = np.linalg.det(model.distort_jacobian(xy)).reshape(n_dir, n_r)
    rho = np.linalg.norm(uv - c, axis=2)
    grows = np.ones((n_dir, n_r), bool)
    grows[:, 1:] = np.diff(rho, axis=1) > 0
    ok = grows & (det > 0) & np.isfinite(rho)
    ok[:, 0] = True
    bad = ~ok
    first_bad = np.where(bad.any(axis=1), np.argmax(bad, axis=1), n_r)
    beyond = rho >= reach
    first_out = np.where(beyond.any(axis=1), np.argmax(beyond, axis=1), n_r)
    end = np.minimum(first_bad - 1, first_out)
    end = np.clip(end, 0, n_r - 1)
    boundary = uv[np.arange(n_dir), end]
    folds_inside = False
    for k in range(n_dir):
        if first_bad[k] < n_r and first_bad[k] <= first_out[k]:
            folds_inside = True
            break
    poly = boundary.copy()
    whole = not folds_inside or bool(np.all(_star_contains(poly, c, corners)))
    if whole:
        # the frame lies inside the region: check the frame itself densely
        whole = bool(np.all(_star_contains(poly, c, _frame_edge(w, h))))
    return poly, whole


def _frame_edge(w: int, h: int, n: int = 200) -> np.ndarray:
    """Pixels (4n,2) along the frame's border."""
    t = np.linspace(0, 1, n)
    x, y = t * (w - 1), t * (h - 1)
    return np.concatenate([np.column_stack([x, np.zeros(n)]), np.column_stack([x, np.full(n, h - 1.0)]),
                           np.column_stack([np.zeros(n), y]), np.column_stack([np.full(n, w - 1.0), y])])


def _star_contains(poly: np.ndarray, centre: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Pixels inside a polygon that is star-shaped around `centre` (radius interpolated by azimuth)."""
    d = poly - centre
    ang = np.arctan2(d[:, 1], d[:, 0])
    rad = np.hypot(d[:, 0], d[:, 1])
    o = np.argsort(ang)
    ang, rad = ang[o], rad[o]
    ang = np.concatenate([ang[-1:] - 2 * np.pi, ang, ang[:1] + 2 * np.pi])
    rad = np.concatenate([rad[-1:], rad, rad[:1]])
    q = np.atleast_2d(uv) - centre
    return np.hypot(q[:, 0], q[:, 1]) <= np.interp(np.arctan2(q[:, 1], q[:, 0]), ang, rad)


def hull_candidates(uv: np.ndarray, mask: np.ndarray | None = None, chunk: int = 100_000) -> np.ndarray:
    """The pixels of uv (N,2) (where `mask`, when given) that may be on their convex hull: all but those strictly
    inside the octagon of the extreme pixels along x, y and the diagonals (Akl-Toussaint; strictly inside it a
    pixel is strictly inside the hull, neither a vertex nor on an edge). Reads `chunk` rows at a time: no copy of
    millions of observations. convex_hull(hull_candidates(uv, m)) == convex_hull(uv[m])."""
    dirs = np.array([[1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0], [-1, -1], [0, -1], [1, -1]], float)
    parts = [slice(a, min(a + chunk, len(uv))) for a in range(0, len(uv), chunk)]

    def rows(s):
        q = np.asarray(uv[s], float)
        return q if mask is None else q[mask[s]]
    best = np.full(len(dirs), -np.inf)
    ext = np.zeros((len(dirs), 2))
    for s in parts:
        q = rows(s)
        if not len(q):
            continue
        proj = q @ dirs.T
        k = np.argmax(proj, axis=0)
        better = proj[k, np.arange(len(dirs))] > best
        best[better] = proj[k, np.arange(len(dirs))][better]
        ext[better] = q[k[better]]
    if not np.isfinite(best).all():
        return np.zeros((0, 2))
    # the octagon, counter-clockwise (x right, y up) in the order of `dirs`, repeated vertices dropped
    poly = ext[np.r_[True, np.any(ext[1:] != ext[:-1], axis=1)]]
    if len(poly) > 1 and np.all(poly[0] == poly[-1]):
        poly = poly[:-1]
    out = []
    for s in parts:
        q = rows(s)
        inside = np.full(len(q), len(poly) >= 3)
        for k in range(len(poly) if len(poly) >= 3 else 0):
            o, e = poly[k], poly[(k + 1) % len(poly)] - poly[k]
            inside &= e[0] * (q[:, 1] - o[1]) - e[1] * (q[:, 0] - o[0]) > 0
        out.append(q[~inside])
    return np.concatenate(out) if out else np.zeros((0, 2))


def convex_hull(uv: np.ndarray) -> np.ndarray:
    """Counter-clockwise (in x right, y up terms) convex hull vertices (H,2) of pixels (Andrew's monotone chain;
    of many pixels only their `hull_candidates`, which leaves the hull as it is)."""
    uv = np.asarray(uv, float)
    if len(uv) > 1000 and np.isfinite(uv).all():
        uv = hull_candidates(uv)
    p = np.unique(uv, axis=0)
    if len(p) < 3:
        return p

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    lower: list = []
    for q in p:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], q) <= 0:
            lower.pop()
        lower.append(q)
    upper: list = []
    for q in p[::-1]:
        while len(upper) >= 2 and cross(upper[-2], upper[-1], q) <= 0:
            upper.pop()
        upper.append(q)
    return np.array(lower[:-1] + upper[:-1])


def _hull_contains(hull: np.ndarray, uv: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
    """Pixels inside a convex polygon (vertices in the order `convex_hull` gives), grown by margin_px."""
    uv = np.atleast_2d(uv)
    if len(hull) < 3:
        return np.zeros(len(uv), bool)
    a = hull
    b = np.roll(hull, -1, axis=0)
    edge = b - a
    ln = np.maximum(np.hypot(edge[:, 0], edge[:, 1]), 1e-12)
    # signed distance to the left of every edge (inside for a counter-clockwise polygon)
    s = (edge[:, 0][None] * (uv[:, 1][:, None] - a[:, 1][None])
         - edge[:, 1][None] * (uv[:, 0][:, None] - a[:, 0][None]))
    return np.all(s / ln[None] >= -margin_px, axis=1)


def _pct(x: float) -> str:
    """A fraction as a percentage: whole numbers, one decimal near 100 (so 'all but a corner' is not '100')."""
    return f"{100 * x:.1f}" if 0.995 <= x < 1.0 else f"{100 * x:.0f}"


@dataclass
class ValidRegion:
    """The monotonic region of a model (star-shaped polygon around `centre`, px), the observed region (convex hull
    of the observations, px; None when unknown) and the image size."""

    image_size: tuple[int, int]
    centre: np.ndarray
    monotonic: np.ndarray
    whole_frame_monotonic: bool
    observed: np.ndarray | None = None

    @classmethod
    def of(cls, model, observed_uv: np.ndarray | None = None) -> "ValidRegion":
        """The region of `model`, with the observed region of the pixels `observed_uv` (px) if given."""
        poly, whole = monotonic_boundary(model)
        hull = None if observed_uv is None or len(observed_uv) < 3 else convex_hull(observed_uv)
        return cls(tuple(int(v) for v in model.image_size), model.pinhole_K()[:2, 2].copy(), poly, whole, hull)

    def in_monotonic(self, uv: np.ndarray) -> np.ndarray:
        """Pixels (N,2) inside the monotonic region."""
        if self.whole_frame_monotonic:
            return np.ones(len(np.atleast_2d(uv)), bool)
        return _star_contains(self.monotonic, self.centre, uv)

    def in_observed(self, uv: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Pixels (N,2) inside the observed region (all of them when it is unknown)."""
        if self.observed is None:
            return np.ones(len(np.atleast_2d(uv)), bool)
        return _hull_contains(self.observed, uv, margin_px)

    def contains(self, uv: np.ndarray) -> np.ndarray:
        """Pixels (N,2) inside the valid region (monotonic and observed)."""
        return self.in_monotonic(uv) & self.in_observed(uv)

    def grid(self, n: tuple[int, int] = (61, 41)) -> np.ndarray:
        """Pixels of a regular frame grid (corners included) that lie in the valid region."""
        w, h = self.image_size
        uu, vv = np.meshgrid(np.linspace(0.0, w - 1.0, n[0]), np.linspace(0.0, h - 1.0, n[1]))
        uv = np.column_stack([uu.ravel(), vv.ravel()])
        return uv[self.contains(uv)]

    def sample(self, n: tuple[int, int] = (61, 41)) -> np.ndarray:
        """Pixels filling the valid region: a grid of n over its bounding box (not the frame's: a small region gets
        as many points as a large one) plus points along the observed region's border, where fits are worst."""
        w, h = self.image_size
        if self.observed is not None:
            lo = np.maximum(self.observed.min(axis=0), 0.0)
            hi = np.minimum(self.observed.max(axis=0), [w - 1.0, h - 1.0])
        else:
            lo, hi = np.zeros(2), np.array([w - 1.0, h - 1.0])
        uu, vv = np.meshgrid(np.linspace(lo[0], hi[0], n[0]), np.linspace(lo[1], hi[1], n[1]))
        uv = np.column_stack([uu.ravel(), vv.ravel()])
        if self.observed is not None and len(self.observed) >= 3:
            a, b = self.observed, np.roll(self.observed, -1, axis=0)
            t = np.linspace(0, 1, 12, endpoint=False)
            edge = (a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]).reshape(-1, 2)
            c = self.observed.mean(axis=0)
            d = c - edge
            edge = edge + 0.5 * d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)  # half a pixel in
            uv = np.vstack([uv, edge])
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
        uv = uv[inside]
        return uv[self.contains(uv)]

    def fractions(self, n: tuple[int, int] = (160, 100)) -> dict[str, float]:
        """Fractions of the frame's area that are monotonic, observed and valid."""
        w, h = self.image_size
        uu, vv = np.meshgrid((np.arange(n[0]) + 0.5) * w / n[0] - 0.5, (np.arange(n[1]) + 0.5) * h / n[1] - 0.5)
        uv = np.column_stack([uu.ravel(), vv.ravel()])
        m, o = self.in_monotonic(uv), self.in_observed(uv)
        return {"monotonic": float(m.mean()), "observed": float(o.mean()), "valid": float((m & o).mean())}

    @property
    def whole_frame(self) -> bool:
        """The whole frame is valid (monotonic and observed)."""
        return self.whole_frame_monotonic and self.observed is None

    def describe(self) -> str:
        """One line: how much of the frame is monotonic, observed and valid."""
        f = self.fractions()
        mono = ("the whole frame" if self.whole_frame_monotonic else "all of the frame but its extreme corners"
                if f["monotonic"] >= 0.9995 else f"{_pct(f['monotonic'])} % of the frame")
        if self.observed is None:
            return f"monotonic (no fold) over {mono}"
        return (f"observations cover {_pct(f['observed'])} % of the frame (convex hull); the model is monotonic "
                f"(no fold) over {mono}; valid region {_pct(f['valid'])} % of the frame")

    def to_dict(self) -> dict:
        """JSON form: polygons (px), flags and area fractions."""
        f = self.fractions()
        return {"definition": "valid = monotonic (d r_d/d r > 0, no fold) and observed (convex hull of the used "
                              "observations); pixels, OpenCV convention",
                "whole_frame_monotonic": self.whole_frame_monotonic,
                "monotonic_fraction": round(f["monotonic"], 4), "observed_fraction": round(f["observed"], 4),
                "valid_fraction": round(f["valid"], 4),
                "principal_point_px": [float(v) for v in self.centre],
                "monotonic_polygon_px": np.round(self.monotonic, 2).tolist(),
                "observed_polygon_px": None if self.observed is None else np.round(self.observed, 2).tolist()}

    @classmethod
    def from_dict(cls, d: dict, image_size) -> "ValidRegion":
        """The region from its JSON form (`to_dict`)."""
        obs = d.get("observed_polygon_px")
        return cls(tuple(int(v) for v in image_size), np.asarray(d["principal_point_px"], float),
                   np.asarray(d["monotonic_polygon_px"], float), bool(d["whole_frame_monotonic"]),
                   None if obs is None else np.asarray(obs, float))
