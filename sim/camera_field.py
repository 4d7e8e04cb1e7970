"""Simulate photos of the rotating target plate taken by a camera with known fraser7 truth.

The plate turns about its normal in equal steps; for every plate angle the camera takes one photo from each
of a few stations (tilt 0, 30, 45 degrees, two distances, landscape and portrait) so the targets cover the
whole frame, corners included. Images are rendered exactly through the camera model (dgcal.sim.render), then
blurred, vignetted, noised and written as JPEG. Writes `images/*.jpg`, `field.csv` (+ `field.json`),
`truth.json` (camera, poses R_field_to_cam/t_field_to_cam, noise, seed) and `truth_measurements.csv`
(noise-free projections of every visible target; column `complete` = 1 when the target's four squares lie
wholly inside the frame, i.e. a detector can be expected to find it).

`simulate_board_views` does the same for a standard board (charuco, chessboard, aruco-grid of
dgcal.fields.targets.boards): hand-held views spread over the frame, the whole board in view, optionally mirrored
(the back face).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from dgcal.calib.camera.files import camera_json_dict
from dgcal.calib.camera.models import CameraModel, Fraser7
from dgcal.fields.io.csv_tables import atomic_write, staged_dir, write_table
from dgcal.fields.targets.boards import Board, board_texture, write_board_field
from dgcal.fields.targets.plate import TargetField, nonplanar_field, write_field
from dgcal.fields.targets.texture import field_texture
from dgcal.sim.render import Facet, RayGrid, facet_depth_at, render


# (tilt deg, distance factor, roll deg): distance factor 1 = the plate diameter fills the image diagonal
STATIONS = ((0.0, 0.95, 0.0), (30.0, 1.05, 90.0), (45.0, 1.2, 0.0),
            (0.0, 1.3, 90.0), (30.0, 1.3, 0.0), (45.0, 1.45, 90.0))


def calibration_field_camera(image_size: tuple[int, int] = (3000, 2000)) -> Fraser7:
    """The simulator's truth camera: f = image width (53 deg across), ~2 % radial distortion in the corners."""
    w, h = image_size
    s = w / 3000.0
    return Fraser7((w, h), [1.0 * w, (w - 1) / 2 + 14.0 * s, (h - 1) / 2 - 9.0 * s,
                            -0.11, 0.09, -0.03, 2.5e-4, -1.5e-4, 0.6 * s, 0.25 * s])


@dataclass
class Shot:
    """One simulated photo: plate-to-camera pose and how it was taken."""

    image: str
    R_field_to_cam: np.ndarray
    t_field_to_cam: np.ndarray
    rotation_deg: float
    tilt_deg: float
    distance_m: float
    roll_deg: float


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def plan_shots(n_images: int, camera: CameraModel, tf: TargetField, rng: np.random.Generator) -> list[Shot]:
    """Poses of `n_images` photos: stations x plate angles, with small random jitter (m, deg)."""
    w, h = camera.image_size
    f = camera.pinhole_K()[1, 1]
    d0 = tf.diameter_m * f / math.hypot(w, h)
    per = math.ceil(n_images / len(STATIONS))
    shots = []
    for k in range(n_images):
        st, j = k % len(STATIONS), k // len(STATIONS)
        tilt, dist_f, roll = STATIONS[st]
        rot = 360.0 * j / per + 17.0 * st
        tilt_j = tilt + rng.uniform(-3, 3)
        roll_j = roll + rng.uniform(-5, 5)
        dist = d0 * dist_f * rng.uniform(0.97, 1.03)
        look = np.append(rng.uniform(-0.05, 0.05, 2) * tf.diameter_m, 0.0)
        # nadir camera (x east, y south, z down) tilted about its x axis, then rolled about its z axis
        R_world_to_cam = _rz(math.radians(roll_j)) @ _rx(math.radians(tilt_j)) @ np.diag([1.0, -1.0, -1.0])
        C_world = look - dist * R_world_to_cam[2]  # camera z axis in the world is row 2 of R_world_to_cam
        R_field_to_cam = R_world_to_cam @ _rz(math.radians(rot))
        t = -R_world_to_cam @ C_world
        shots.append(Shot(f"IMG_{k + 1:04d}.jpg", R_field_to_cam, t, rot % 360.0, tilt_j, dist, roll_j))
    return shots


def field_facets(tf: TargetField, texel_m: float) -> list[Facet]:
    """The plate (and its raised blocks with grey side walls) as facets in the plate frame."""
    grey, alpha = field_texture(tf, texel_m)
    grey = np.rint(grey * 65535).astype(np.uint16)  # half the memory of float32, still 16-bit smooth
    alpha = np.rint(alpha * 255).astype(np.uint8)
    half = tf.board_size_m / 2
    ex, ey = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])

    def board_point(xb, yb, z):
        return np.array([xb - half, half - yb, z])

    facets = [Facet(board_point(texel_m / 2, texel_m / 2, 0.0), ex * texel_m, -ey * texel_m, grey, alpha)]
    wall = np.full((4, 4), 0.45, np.float32)
    s = tf.square_m
    for b in tf.blocks:
        i0, i1 = round(b.row0 * s / texel_m), round((b.row0 + b.nrows) * s / texel_m)
        j0, j1 = round(b.col0 * s / texel_m), round((b.col0 + b.ncols) * s / texel_m)
        facets.append(Facet(board_point((j0 + 0.5) * texel_m, (i0 + 0.5) * texel_m, b.height_m),
                            ex * texel_m, -ey * texel_m, grey[i0:i1, j0:j1].copy(), None))
        x0, x1 = b.col0 * s, (b.col0 + b.ncols) * s
        y0, y1 = b.row0 * s, (b.row0 + b.nrows) * s
        hgt = b.height_m
        for pa, pb in (((x0, y0), (x1, y0)), ((x1, y0), (x1, y1)), ((x1, y1), (x0, y1)), ((x0, y1), (x0, y0))):
            A, B = board_point(*pa, 0.0), board_point(*pb, 0.0)
            du, dv = (B - A) / 4, np.array([0, 0, hgt / 4])
            facets.append(Facet(A + du / 2 + dv / 2, du, dv, wall, None))
    return facets


def truth_projections(camera: CameraModel, tf: TargetField, shot: Shot, facets: list[Facet],
                      max_incidence_deg: float = 75.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ids, noise-free pixels and `complete` flags of the targets visible in one shot (in frame, facing the
    camera within `max_incidence_deg`, not hidden by a block)."""
    ids, _, xyz = tf.targets()
    R_field_to_cam, t = shot.R_field_to_cam, shot.t_field_to_cam
    X = xyz @ R_field_to_cam.T + t
    w, h = camera.image_size
    n_cam = R_field_to_cam[:, 2]  # plate normal in the camera frame
    cos_inc = -(X @ n_cam) / np.linalg.norm(X, axis=1)
    ok = (X[:, 2] > 0) & (cos_inc > math.cos(math.radians(max_incidence_deg)))
    uv = np.full((len(ids), 2), np.nan)
    uv[ok] = camera.project(X[ok])
    inside = ok & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    if tf.blocks:
        depth = np.full(len(ids), np.inf)
        depth[inside] = facet_depth_at(X[inside], facets, R_field_to_cam, t)
        inside &= depth >= X[:, 2] - 1e-6
    # complete: the 3x3 grid of square corners around the target is in the frame (margin 2 px)
    s = tf.square_m
    offs = np.array([[dx, dy, 0.0] for dx in (-s, 0, s) for dy in (-s, 0, s)])
    complete = inside.copy()
    for o in offs:
        Y = (xyz + o) @ R_field_to_cam.T + t
        good = complete & (Y[:, 2] > 0)
        q = np.full((len(ids), 2), np.nan)
        q[good] = camera.project(Y[good])
        complete = good & (q[:, 0] >= 2) & (q[:, 0] <= w - 3) & (q[:, 1] >= 2) & (q[:, 1] <= h - 3)
    return ids[inside], uv[inside], complete[inside]


def _finish(radiance: np.ndarray, rng: np.random.Generator, blur_px: float, noise_dn: float) -> np.ndarray:
    """Photometric part: exposure, vignetting, optical blur, noise, 8-bit quantisation."""
    h, w = radiance.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    gain = rng.uniform(0.85, 1.05)
    img = (15.0 + 215.0 * gain * radiance) * (1.0 - 0.25 * r2)
    if blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_px)
    img += rng.normal(0.0, noise_dn, img.shape).astype(np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def simulate_camera_field(out: str | Path, seed: int = 0, n_images: int = 48,
                          image_size: tuple[int, int] = (3000, 2000), camera: CameraModel | None = None,
                          field: TargetField | None = None, nonplanar: bool = False, blur_px: float = 0.8,
                          noise_dn: float = 2.0, jpeg_quality: int = 95, supersample: int = 2,
                          texel_m: float | None = None, progress: bool = True) -> dict:
    """Render the data set into `out` (see module doc); returns the truth dict written to truth.json."""

    rng = np.random.default_rng(seed)
    camera = calibration_field_camera(image_size) if camera is None else camera
    tf = field if field is not None else (nonplanar_field() if nonplanar else TargetField())
    if texel_m is None:
        # about the finest pixel footprint on the plate (the texture is area-filtered and sampled at
        # half-pixel steps), and a whole number of texels per square
        w, h = camera.image_size
        texel_m = 0.9 * tf.diameter_m / math.hypot(w, h)
    texel_m = tf.square_m / max(1, round(tf.square_m / texel_m))
    facets = field_facets(tf, texel_m)
    shots = plan_shots(n_images, camera, tf, rng)
    rays = RayGrid(camera)
    rows_meas = []
    with staged_dir(out) as tmp:
        (tmp / "images").mkdir()
        write_field(tmp / "field.csv", tf)
        for shot in tqdm(shots, desc="render", unit="img", disable=not progress):
            rad = render(camera, shot.R_field_to_cam, shot.t_field_to_cam, facets, background=0.3,
                         supersample=supersample, rays=rays)
            img = _finish(rad, rng, blur_px, noise_dn)
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
            with atomic_write(tmp / "images" / shot.image, "wb") as fh:
                fh.write(buf.tobytes())
            ids, uv, complete = truth_projections(camera, tf, shot, facets)
            rows_meas += [(shot.image, i, *p, int(c)) for i, p, c in zip(ids, uv, complete)]
        write_table(tmp / "truth_measurements.csv", ["image", "id", "x", "y", "complete"], rows_meas, fmt="%.5f")
        truth = {
            "simulator": "camera-field", "seed": int(seed), "n_images": len(shots),
            "camera": camera_json_dict(camera),
            "field": tf.to_dict(),
            "noise": {"blur_px": blur_px, "noise_dn": noise_dn, "jpeg_quality": int(jpeg_quality),
                      "supersample": int(supersample), "texel_m": texel_m},
            "frames": "X_cam = R_plate_to_cam @ X_plate + t_plate_to_cam; camera x right, y down, z forward; "
                      "plate x right, y up on the print, z out of the printed face",
            "images": [{"image": s.image, "R_plate_to_cam": s.R_field_to_cam.tolist(),
                        "t_plate_to_cam": s.t_field_to_cam.tolist(), "plate_rotation_deg": s.rotation_deg,
                        "tilt_deg": s.tilt_deg, "distance_m": s.distance_m, "roll_deg": s.roll_deg}
                       for s in shots],
        }
        with atomic_write(tmp / "truth.json") as fh:
            json.dump(truth, fh, indent=1)
    return truth


# ---------------------------------------------------------------------------------------------
# standard boards (charuco, chessboard, aruco-grid): hand-held views over the whole frame
# ---------------------------------------------------------------------------------------------
def board_facets(board: Board, texel_m: float) -> list[Facet]:
    """The printed board (with its white margin) as one facet in the board frame (x right, y down, z into it)."""
    grey, (ox, oy) = board_texture(board, texel_m)
    grey = np.rint(grey * 65535).astype(np.uint16)
    return [Facet(np.array([ox + texel_m / 2, oy + texel_m / 2, 0.0]), np.array([texel_m, 0, 0.0]),
                  np.array([0, texel_m, 0.0]), grey, None)]


def _board_outline(board: Board) -> np.ndarray:
    """(4,3) outer corners of the printed board including its white margin (board frame, m)."""
    bw, bh = board.size_m
    m = board.square_m
    return np.array([[-m, -m, 0], [bw + m, -m, 0], [bw + m, bh + m, 0], [-m, bh + m, 0]], float)


def plan_board_shots(n_images: int, camera: CameraModel, board: Board, rng: np.random.Generator,
                     size_fraction: tuple[float, float] = (0.45, 0.8), max_tilt_deg: float = 50.0) -> list[Shot]:
    """Poses of `n_images` views of a hand-held board: its centre aimed at pixels spread over the frame (a 4 x 3
    grid first, frame corners included, then at random), apparent width `size_fraction` of the image's, tilted up
    to `max_tilt_deg` about a random in-plane axis and turned at random. A chessboard stays wholly in the frame
    (its detector needs it all); a ChArUco or ArUco-grid board may leave it partly, keeping at least 40 % of its
    corners in view, so that its corners reach the frame's corners. X_cam = R X_board + t (m)."""
    w, h = camera.image_size
    f = camera.pinhole_K()[0, 0]
    bw, bh = board.size_m
    centre = np.array([bw / 2, bh / 2, 0.0])
    outline = _board_outline(board)
    corners = board.corner_xyz()
    partial = board.type != "chessboard"
    lo, hi = (0.0, 1.0) if partial else (0.12, 0.88)
    gx, gy = np.meshgrid(np.linspace(lo, hi, 4), np.linspace(lo, hi, 3))
    aims = np.column_stack([gx.ravel(), gy.ravel()])
    shots = []
    for k in range(n_images):
        aim = aims[k % len(aims)] + rng.uniform(-0.04, 0.04, 2) if k < 2 * len(aims) else rng.uniform(lo, hi, 2)
        frac = rng.uniform(*size_fraction)
        tilt = math.radians(rng.uniform(15.0, max_tilt_deg))
        axis_ang = rng.uniform(0, 2 * math.pi)
        spin = rng.uniform(-math.pi, math.pi) if partial else rng.uniform(-0.6, 0.6)
        ax = np.array([math.cos(axis_ang), math.sin(axis_ang), 0.0])
        R_board_to_cam = _axis_angle(ax, tilt) @ _rz(spin)
        for _ in range(40):
            uv_aim = np.array([aim[0] * (w - 1), aim[1] * (h - 1)])
            ray = camera.ray(uv_aim[None])[0]
            dist = f * bw / (frac * w)
            t = ray / ray[2] * dist - R_board_to_cam @ centre
            if partial:
                X = corners @ R_board_to_cam.T + t
                uv = camera.project(X)
                seen = (X[:, 2] > 0) & np.all((uv >= 4) & (uv <= [w - 5, h - 5]), axis=1)
                if seen.mean() >= 0.4:
                    break
            else:
                X = outline @ R_board_to_cam.T + t
                if np.all(X[:, 2] > 0):
                    uv = camera.project(X)
                    if np.all((uv >= 2) & (uv <= [w - 3, h - 3])):
                        break
            frac *= 0.93
            aim = 0.5 + 0.93 * (aim - 0.5)
        shots.append(Shot(f"IMG_{k + 1:04d}.png", R_board_to_cam, t, math.degrees(spin), math.degrees(tilt),
                          float(dist), 0.0))
    return shots


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix of `angle` (rad) about the unit `axis`."""
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def board_truth_projections(camera: CameraModel, board: Board, shot: Shot) -> tuple[np.ndarray, np.ndarray]:
    """Ids and noise-free pixels of the board corners inside the frame in one shot."""
    X = board.corner_xyz() @ shot.R_field_to_cam.T + shot.t_field_to_cam
    w, h = camera.image_size
    uv = np.full((len(X), 2), np.nan)
    ok = X[:, 2] > 0
    uv[ok] = camera.project(X[ok])
    inside = ok & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    return board.corner_ids()[inside], uv[inside]


def simulate_board_views(out: str | Path, board: Board, seed: int = 0, n_images: int = 30,
                         image_size: tuple[int, int] = (1200, 800), camera: CameraModel | None = None,
                         blur_px: float = 0.8, noise_dn: float = 2.0, supersample: int = 2,
                         texel_m: float | None = None, mirrored: bool = False, progress: bool = False) -> dict:
    """Render views of a standard board into `out`: `images/IMG_0001.png ...`, `board.toml`, `field.csv` (+
    `field.json`), `truth.json` (camera, poses) and `truth_measurements.csv`; returns the truth dict. With
    `mirrored` every image is flipped left-right (a view of the board's back face)."""
    rng = np.random.default_rng(seed)
    camera = calibration_field_camera(image_size) if camera is None else camera
    w, h = camera.image_size
    if texel_m is None:
        # a fraction of the finest pixel footprint of the closest view, a whole number of texels per square
        texel_m = 0.5 * board.size_m[0] / (0.55 * w)
    texel_m = board.square_m / max(1, round(board.square_m / texel_m))
    facets = board_facets(board, texel_m)
    shots = plan_board_shots(n_images, camera, board, rng)
    rays = RayGrid(camera)
    rows = []
    with staged_dir(out) as tmp:
        (tmp / "images").mkdir()
        write_board_field(tmp / "field.csv", board)
        with atomic_write(tmp / "board.toml") as fh:
            fh.write(board.to_toml())
        for shot in tqdm(shots, desc="render", unit="img", disable=not progress):
            rad = render(camera, shot.R_field_to_cam, shot.t_field_to_cam, facets, background=0.3,
                         supersample=supersample, rays=rays)
            img = _finish(rad, rng, blur_px, noise_dn)
            if mirrored:
                img = np.ascontiguousarray(img[:, ::-1])
            ok, buf = cv2.imencode(".png", img)
            with atomic_write(tmp / "images" / shot.image, "wb") as fh:
                fh.write(buf.tobytes())
            ids, uv = board_truth_projections(camera, board, shot)
            if mirrored:
                uv = uv.copy()
                uv[:, 0] = (w - 1) - uv[:, 0]
            rows += [(shot.image, i, *p) for i, p in zip(ids, uv)]
        write_table(tmp / "truth_measurements.csv", ["image", "id", "x", "y"], rows, fmt="%.5f")
        truth = {"simulator": "board-views", "seed": int(seed), "n_images": len(shots),
                 "camera": camera_json_dict(camera), "board": board.to_dict(), "mirrored": bool(mirrored),
                 "noise": {"blur_px": blur_px, "noise_dn": noise_dn, "supersample": int(supersample),
                           "texel_m": texel_m},
                 "frames": "X_cam = R_board_to_cam @ X_board + t_board_to_cam; board x right, y down, z into the "
                           "board; camera x right, y down, z forward" + ("; images flipped left-right" if mirrored
                                                                          else ""),
                 "images": [{"image": s.image, "R_board_to_cam": s.R_field_to_cam.tolist(),
                             "t_board_to_cam": s.t_field_to_cam.tolist(), "tilt_deg": s.tilt_deg,
                             "spin_deg": s.rotation_deg, "distance_m": s.distance_m} for s in shots]}
        with atomic_write(tmp / "truth.json") as fh:
            json.dump(truth, fh, indent=1)
    return truth
