"""Photogrammetric blocks with known truth, measurements only (no images): any strip pattern, height and terrain.

A `BlockPattern` plans strips (count, length in images, heading; neighbouring strips flown in opposite
headings or all the same way; optional cross strips; one or more flying heights above the terrain). The
camera looks nadir with the image top along the flight direction, with attitude and position jitter.
Control, check and tie points lie on the terrain (flat, or hills of a given amplitude); every image measures
what it sees (0.3 px noise by default). Coordinates are in a map CRS (a UTM zone by default, at a site where
the meridian convergence exceeds 1 degree), ellipsoidal heights; EOPs are PATB omega/phi/kappa in that CRS.

`simulate_block(...)` returns a `BlockSim` in memory; `write_block(sim, out)` writes `gcp.csv`,
`measurements.csv` (all image measurements), `camera.json`, `truth_eop.csv`, `truth.json` and, when the
block has GNSS camera centres (`centre_sigma_m`), `centres.csv` (EOP columns, angles blank, sX,sY,sZ).

The RTK-drone family (`rtk_drone_pattern`, `p1_35mm_camera`, `simulate_rtk_block`): a 35 mm lens on an
8192 x 5460 px full frame (4.4 um pixels, DJI Zenmuse P1 class), 150 m above the mean terrain, 80 % / 70 %
overlap, +-50 m hills, a gimbal-stabilised nadir camera, RTK camera centres with noise 2/2/5 cm (E, N, Up).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dgcal.calib.camera.files import write_camera_json
from dgcal.calib.camera.models import Fraser7
from dgcal.fields.crs import LocalENU, MapGrid
from dgcal.fields.frames import R_CV_TO_PHOTO
from dgcal.fields.io.csv_tables import atomic_write, formatted, staged_dir, write_columns
from dgcal.fields.io.formats import EOP, Measurements, Points, write_eop, write_measurements, write_points
from dgcal.fields.pose import Poses, so3_exp
from dgcal.fields.world import World

# 47 N, 17.5 E in UTM zone 33 (central meridian 15 E): meridian convergence about 1.8 degrees
SITE = (47.0, 17.5, 250.0)
SITE_CRS = "EPSG:32633"


def full_frame_20mm_camera() -> Fraser7:
    """A 20 mm lens on a 36 x 24 mm, 6000 x 4000 px sensor (6 um pixels): f = 3333 px, mild distortion."""
    return Fraser7((6000, 4000), np.array([3333.3, 2999.5 + 12.0, 1999.5 - 8.0, -0.045, 0.012, 0.0,
                                           1.5e-4, -1.0e-4, 0.3, 0.1]))


def p1_35mm_camera() -> Fraser7:
    """A 35 mm lens on a 35.9 x 24 mm, 8192 x 5460 px sensor (4.4 um pixels): f = 7954.5 px, mild distortion."""
    return Fraser7((8192, 5460), np.array([7954.5, 4095.5 + 9.0, 2729.5 - 6.0, -0.021, 0.006, 0.0,
                                           6.0e-5, -4.0e-5, 0.0, 0.0]))


@dataclass
class BlockPattern:
    """A flight pattern: strips per height, images per strip, heading, overlaps, cross strips, terrain."""

    heights_m: tuple[float, ...] = (300.0,)         # above the mean terrain
    n_strips: tuple[int, ...] = (4,)                # per height
    images_per_strip: tuple[int, ...] = (15,)       # per height
    heading_deg: float = 0.0                        # flight direction of the first strip (azimuth)
    alternate: bool = True                          # neighbouring strips in opposite headings
    cross_strips: int = 0                           # extra strips at heading + 90 deg (at the first height)
    forward_overlap: float = 0.8
    side_overlap: float = 0.6
    terrain_amplitude_m: float = 0.0                # hills of this amplitude (0: flat)
    jitter_deg: tuple[float, float, float] = (1.5, 1.5, 2.0)   # roll-like, pitch-like, yaw-like (camera axes)
    jitter_m: tuple[float, float, float] = (2.0, 2.0, 1.0)


@dataclass
class BlockSim:
    """A simulated block: the truth (poses in the world frame and as map EOPs, points) and its measurements."""

    crs: str
    local: LocalENU                 # the world frame of the truth (ENU at the site)
    camera: Fraser7
    images: list[str]
    poses: Poses                    # truth in the world frame
    eop: EOP                        # truth in the map CRS (PATB)
    points: Points                  # control and check points as given (map CRS, perturbed by their sigmas)
    points_true_map: np.ndarray     # (n,3) their true map coordinates
    tie_world: np.ndarray           # (t,3) true tie points, world frame
    measurements: Measurements      # ground and tie points together
    strip: list[str] = field(default_factory=list)
    pattern: BlockPattern | None = None
    centres: EOP | None = None      # GNSS camera centres (map CRS, truth + noise) with sigma (n,6), angles NaN

    def truth_dict(self) -> dict:
        """The truth as JSON-able data."""
        return {"crs": self.crs, "site": {"lat": self.local.lat0, "lon": self.local.lon0, "h": self.local.h0},
                "camera": {"model": self.camera.NAME, "image_size": list(self.camera.image_size),
                           "params": self.camera.as_dict()},
                "pattern": None if self.pattern is None else {k: v for k, v in vars(self.pattern).items()},
                "images": [{"image": n, "X": self.eop.xyz[i].tolist(), "opk_deg": self.eop.opk[i].tolist(),
                            "strip": self.strip[i]} for i, n in enumerate(self.images)],
                "ground_points": [{"id": str(self.points.ids[i]), "role": str(self.points.role[i]),
                                   "xyz": self.points_true_map[i].tolist()} for i in range(len(self.points.ids))],
                "n_tie_points": int(len(self.tie_world)), "n_observations": int(len(self.measurements.id)),
                "centre_sigma_m": None if self.centres is None else self.centres.sigma[0, :3].tolist()}


def terrain(e: np.ndarray, n: np.ndarray, amplitude_m: float) -> np.ndarray:
    """Terrain height above the site (m, world Up) at world E, N (m): smooth hills of the given amplitude."""
    if amplitude_m == 0:
        return np.zeros_like(np.asarray(e, float))
    return amplitude_m * (0.6 * np.sin(e / 310.0 + 0.4) * np.cos(n / 270.0) + 0.4 * np.sin((e - n) / 190.0))


def plan_strips(camera: Fraser7, pattern: BlockPattern) -> list[dict]:
    """Nominal camera stations: world E, N, height above terrain, heading (deg) and strip name."""
    w, h = camera.image_size
    f = camera["f"]
    plan = []
    groups = [(H, ns, ni, pattern.heading_deg, f"h{k}") for k, (H, ns, ni) in
              enumerate(zip(pattern.heights_m, pattern.n_strips, pattern.images_per_strip))]
    if pattern.cross_strips:
        H0, _, ni0 = pattern.heights_m[0], pattern.n_strips[0], pattern.images_per_strip[0]
        groups.append((H0, pattern.cross_strips, ni0, pattern.heading_deg + 90.0, "x"))
    for H, ns, ni, heading, tag in groups:
        along = h / f * H * (1 - pattern.forward_overlap)      # image y along track
        across = w / f * H * (1 - pattern.side_overlap)        # image x across track
        az = np.radians(heading)
        u_along = np.array([np.sin(az), np.cos(az)])            # E, N of the flight direction
        u_across = np.array([np.cos(az), -np.sin(az)])
        for s in range(ns):
            forward = not pattern.alternate or s % 2 == 0
            off = (s - (ns - 1) / 2) * across
            for j in range(ni):
                jj = j if forward else ni - 1 - j
                en = off * u_across + (jj - (ni - 1) / 2) * along * u_along
                plan.append({"e": en[0], "n": en[1], "height": H,
                             "heading": heading if forward else heading + 180.0, "strip": f"{tag}s{s}"})
    return plan


def _ground_point_layout(lo: np.ndarray, hi: np.ndarray, n: int, n_control: int, rng: np.random.Generator
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Ground points as a surveyor lays them out: a jittered grid over the block (E, N, m), the control points
    the best spread of them (farthest-point order, corners first), the others check points."""
    span = np.maximum(hi - lo, 1.0)
    gx = max(2, int(np.ceil(np.sqrt(n * span[0] / span[1]))))
    gy = max(2, int(np.ceil(n / gx)))
    ee, nn = np.meshgrid(np.linspace(lo[0], hi[0], gx), np.linspace(lo[1], hi[1], gy))
    cell = span / np.array([gx - 1, gy - 1])
    pts = np.column_stack([ee.ravel(), nn.ravel()])
    pts = pts[rng.permutation(len(pts))[:n]] + rng.uniform(-0.25, 0.25, (n, 2)) * cell
    control = np.zeros(n, bool)
    if n_control <= 0:
        return pts, control
    order = [int(np.argmin(np.linalg.norm(pts - lo, axis=1)))]
    dmin = np.linalg.norm(pts - pts[order[0]], axis=1)
    while len(order) < n_control:
        k = int(np.argmax(dmin))
        order.append(k)
        dmin = np.minimum(dmin, np.linalg.norm(pts - pts[k], axis=1))
    control[order] = True
    return pts, control


def _observe(camera: Fraser7, poses: Poses, names: list[str], ids: np.ndarray, X: np.ndarray, margin: float = 5.0):
    """Image measurements (image, id, uv) of world points X seen in front of and inside each image."""
    img, pid, uv = [], [], []
    w, h = camera.image_size
    for i in range(len(poses)):
        Xc = poses[i:i + 1].to_cam(X, np.zeros(len(X), int))
        ok = Xc[:, 2] > 1.0
        p = np.full((len(X), 2), np.nan)
        p[ok] = camera.project(Xc[ok])
        ok &= (p[:, 0] > margin) & (p[:, 0] < w - 1 - margin) & (p[:, 1] > margin) & (p[:, 1] < h - 1 - margin)
        k = np.flatnonzero(ok)
        img.append(np.full(len(k), names[i], dtype=object))
        pid.append(ids[k])
        uv.append(p[k])
    return np.concatenate(img), np.concatenate(pid), np.vstack(uv)


def simulate_block(seed: int = 0, pattern: BlockPattern | None = None, *, camera: Fraser7 | None = None,
                   site: tuple[float, float, float] = SITE, crs: str = SITE_CRS, n_control: int = 12,
                   n_check: int = 10, n_tie: int = 3000, noise_px: float = 0.3,
                   gcp_sigma_m: tuple[float, float, float] = (0.01, 0.01, 0.015),
                   centre_sigma_m: tuple[float, float, float] | None = None) -> BlockSim:
    """A measurement-only block with known truth (see the module docstring); `centre_sigma_m` (E, N, Up, m) adds
    GNSS camera centres: the true centres plus normal noise of these sigmas, in the map CRS."""
    pattern = pattern or BlockPattern()
    rng = np.random.default_rng(seed)
    cam = camera or full_frame_20mm_camera()
    local = LocalENU(*site)
    grid = MapGrid(crs)
    amp = pattern.terrain_amplitude_m
    plan = plan_strips(cam, pattern)
    n = len(plan)
    en = np.array([[p["e"], p["n"]] for p in plan])
    C = np.column_stack([en, [p["height"] for p in plan]])
    C += rng.normal(0, pattern.jitter_m, (n, 3))
    # nadir camera, image top towards the heading: R_cam_to_enu = Rz(-heading) R_cam_to_photo, then jitter
    kappa = -np.array([p["heading"] for p in plan])
    R_cam_to_world = (so3_exp(np.column_stack([np.zeros((n, 2)), np.radians(kappa)]))
                      @ R_CV_TO_PHOTO @ so3_exp(np.radians(rng.normal(0, pattern.jitter_deg, (n, 3)))))
    poses = Poses.from_cam_to_world(R_cam_to_world, C)
    names = [f"IMG_{k:04d}.tif" for k in range(n)]
    # ground points inside the block (inset by a quarter footprint), tie points over the whole footprint
    H0 = min(pattern.heights_m)
    fp = H0 * np.array(cam.image_size, float) / cam["f"]
    lo, hi = en.min(0), en.max(0)
    n_gp = n_control + n_check
    inset = np.minimum(0.25 * fp.min(), 0.25 * (hi - lo))
    gp_en, ctrl_first = _ground_point_layout(lo + inset, hi - inset, n_gp, n_control, rng)
    gp = np.column_stack([gp_en, terrain(gp_en[:, 0], gp_en[:, 1], amp)])
    role = np.where(ctrl_first, "control", "check").astype(object)
    gp_ids = np.array([f"GCP{i:02d}" if r == "control" else f"CHK{i:02d}" for i, r in enumerate(role)], dtype=object)
    t_en = rng.uniform(lo - 0.45 * fp.max(), hi + 0.45 * fp.max(), (n_tie, 2))
    tie = np.column_stack([t_en, terrain(t_en[:, 0], t_en[:, 1], amp)])
    tie_ids = np.array([f"T{i:06d}" for i in range(n_tie)], dtype=object)
    X = np.vstack([gp, tie])
    ids = np.concatenate([gp_ids, tie_ids])
    img, pid, uv = _observe(cam, poses, names, ids, X)
    # tie points seen once are no tie points
    _, inv, cnt = np.unique(pid, return_inverse=True, return_counts=True)
    keep = (cnt[inv] >= 2) | ~np.char.startswith(pid.astype(str), "T")
    img, pid, uv = img[keep], pid[keep], uv[keep]
    uv_noisy = uv + rng.normal(0, noise_px, uv.shape)
    meas = Measurements(img, pid, uv_noisy, np.full(uv.shape, noise_px))
    # map coordinates and PATB angles (grid-level axes at each centre)
    world = World(grid, local, crs_text=crs)
    gp_map = world.to_map(gp)
    sig = np.tile(np.asarray(gcp_sigma_m, float), (n_gp, 1))
    points = Points(gp_ids, gp_map + rng.normal(0, 1.0, gp_map.shape) * sig, sig, role)
    C_map, opk, _ = world.poses_to_eop(poses)
    eop = EOP(np.array(names, dtype=object), C_map, opk)
    centres = None
    if centre_sigma_m is not None:
        # map grid axes and ENU differ by the convergence (< 2 deg): the noise is drawn along grid E, N, Up,
        # the axes of an EOP file's sigmas
        csig = np.tile(np.r_[np.asarray(centre_sigma_m, float), np.full(3, np.nan)], (n, 1))
        centres = EOP(eop.image.copy(), C_map + rng.normal(0, 1.0, (n, 3)) * csig[:, :3], np.full((n, 3), np.nan),
                      csig)
    return BlockSim(crs, local, cam, names, poses, eop, points, gp_map, tie, meas,
                    [p["strip"] for p in plan], pattern, centres)


def rtk_drone_pattern(n_strips: int = 6, images_per_strip: int = 16, terrain_amplitude_m: float = 50.0,
                      height_m: float = 150.0) -> BlockPattern:
    """The RTK-drone family's flight: strips in opposite headings at 150 m, 80 % / 70 % overlap, +-50 m hills, a
    gimbal-stabilised nadir camera (0.5 deg attitude jitter), the planned line held to a metre."""
    return BlockPattern(heights_m=(height_m,), n_strips=(n_strips,), images_per_strip=(images_per_strip,),
                        forward_overlap=0.8, side_overlap=0.7, terrain_amplitude_m=terrain_amplitude_m,
                        jitter_deg=(0.5, 0.5, 1.0), jitter_m=(1.0, 1.0, 0.5))


RTK_CENTRE_SIGMA_M = (0.02, 0.02, 0.05)   # E, N, Up of an RTK camera centre


def simulate_rtk_block(seed: int = 0, n_images: int = 96, n_control: int = 0, n_check: int = 10,
                       n_tie: int | None = None, noise_px: float = 0.3,
                       centre_sigma_m: tuple[float, float, float] | None = RTK_CENTRE_SIGMA_M,
                       terrain_amplitude_m: float = 50.0) -> BlockSim:
    """An RTK-drone block of about `n_images` images (strips about 2.5 times as many as the images per strip: a
    roughly square block) with `n_control` GCPs, `n_check` check points and RTK camera centres (see the module
    docstring)."""
    n_strips = max(2, int(round(np.sqrt(n_images / 2.5))))
    per_strip = max(3, int(round(n_images / n_strips)))
    pattern = rtk_drone_pattern(n_strips, per_strip, terrain_amplitude_m)
    # about 60 tie points per image are seen by each image (a real block has hundreds: the accuracy of the
    # centres, not of the ties, is what this family tests)
    n_tie = n_tie if n_tie is not None else 120 * n_strips * per_strip
    return simulate_block(seed, pattern, camera=p1_35mm_camera(), n_control=n_control, n_check=n_check,
                          n_tie=n_tie, noise_px=noise_px, gcp_sigma_m=(0.01, 0.01, 0.015),
                          centre_sigma_m=centre_sigma_m)


def write_centres(path: str | Path, centres: EOP) -> None:
    """GNSS camera centres as an EOP CSV whose angles are blank: image,X,Y,Z,omega,phi,kappa,sX,sY,sZ (map CRS, m)."""
    blank = [""] * len(centres.image)
    cols = [list(centres.image)] + [formatted(centres.xyz[:, j], "%.4f") for j in range(3)] + [blank] * 3
    cols += [formatted(centres.sigma[:, j], "%.4f") for j in range(3)]
    write_columns(path, ["image", "X", "Y", "Z", "omega", "phi", "kappa", "sX", "sY", "sZ"], cols)


def write_block(sim: BlockSim, out: str | Path) -> Path:
    """Write gcp.csv, measurements.csv, camera.json, truth_eop.csv, truth.json (and centres.csv when the block has
    GNSS centres) into `out` (all or nothing)."""
    out = Path(out)
    with staged_dir(out) as tmp:
        write_points(tmp / "gcp.csv", sim.points, with_role=True)
        write_measurements(tmp / "measurements.csv", sim.measurements)
        write_camera_json(tmp / "camera.json", sim.camera, stats={"rms_px": 0.0, "n_observations": 0,
                                                                  "n_rejected": 0})
        write_eop(tmp / "truth_eop.csv", sim.eop)
        if sim.centres is not None:
            write_centres(tmp / "centres.csv", sim.centres)
        with atomic_write(tmp / "truth.json") as fh:
            json.dump(sim.truth_dict(), fh, indent=1)
    return out
