"""The distortion curve of a camera model drawn the same way in the camera and the campaign reports: the image
displacement of a ray, distorted minus ideal pinhole position (same focal length and principal point), split into
its radial part Δr (positive outward, away from the principal point: pincushion; negative inward: barrel) and its
tangential part, along lines from the principal point to the right edge, the bottom edge and the farthest corner."""
from __future__ import annotations

import numpy as np

from dgcal.reports.html import new_figure

RADIAL_LABEL = "radial distortion Δr (px), positive outward"
TANGENTIAL_LABEL = "tangential distortion (px), positive counter-clockwise"
CAPTION = ("Distortion: distorted minus ideal pinhole position of the same ray (same focal length and principal "
           "point), px. Radial part Δr positive outward (pincushion), negative inward (barrel); along three lines "
           "from the principal point.")


def distortion_curves(model, n: int = 150) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per line from the principal point ('to right edge', 'to bottom edge', 'to farthest corner'): image radius
    r (px), radial Δr (px, positive outward) and tangential displacement (px) of `model` (a dgcal camera model)."""
    w, h = model.image_size
    K = model.pinhole_K()
    c = K[:2, 2]
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], float)
    far = corners[np.argmax(np.linalg.norm(corners - c, axis=1))]
    ends = {"to right edge": np.array([w - 1, c[1]]), "to bottom edge": np.array([c[0], h - 1]),
            "to farthest corner": far}
    out = {}
    for lab, end in ends.items():
        rmax = float(np.linalg.norm(end - c))
        e = (end - c) / max(rmax, 1e-9)
        r = np.linspace(0, rmax, n)
        uv = c + r[:, None] * e
        d = uv - model.undistort_points(uv, K)
        out[lab] = (r, d @ e, d[:, 0] * -e[1] + d[:, 1] * e[0])
    return out


def distortion_figure(model, tangential: bool = True):
    """Radial (and, with `tangential`, tangential) distortion of `model` against the image radius (px)."""
    curves = distortion_curves(model)
    fig, axes = new_figure(9 if tangential else 7, 4.0, ncols=2 if tangential else 1, squeeze=False)
    axes = axes[0]
    for (lab, (r, rad, tan)), style in zip(curves.items(), ("-", "--", ":")):
        axes[0].plot(r, rad, style, label=lab)
        if tangential:
            axes[1].plot(r, tan, style, label=lab)
    for ax, t in zip(axes, (RADIAL_LABEL, TANGENTIAL_LABEL)):
        ax.axhline(0, color="0.5", lw=0.6)
        ax.set_xlabel("image radius from the principal point (px)")
        ax.set_ylabel(t)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return fig
