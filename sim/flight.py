"""Simulate a control-field flight: terrain, GCP targets, strips at two heights, images and measurements.

`dgcal simulate flight --out DIR --seed N` writes
- `gcp.csv` (ground points in the map CRS, ellipsoidal heights, sigmas, role control/check, coordinates
  perturbed by those sigmas), `camera.json` (the fraser7 camera), `truth.json`, `truth_eop.csv`;
- `measurements.csv` (noisy GCP image measurements, 0.3 px), `measurements_exact.csv` (noise-free),
  `tie_measurements.csv` (simulated tie points, noisy), `measurements_all.csv` (GCPs + tie points);
- `images/*.png` rendered views of a textured terrain with GCP targets (unless `--no-render`).
Strips fly north and south alternately (kappa 0 / 180 deg) at two heights, 80 % forward and 40 % side
overlap, with small random attitude and position jitter.
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.calib.camera.files import write_camera_json
from dgcal.calib.camera.models import Fraser7
from dgcal.fields import progress
from dgcal.fields.crs import LocalENU, MapGrid
from dgcal.fields.io.csv_tables import atomic_write, staged_dir
from dgcal.fields.io.formats import EOP, Measurements, Points, write_eop, write_measurements, write_points
from dgcal.fields.frames import R_CV_TO_PHOTO
from dgcal.fields.pose import Poses
from dgcal.fields.world import World


DEFAULT_CRS = "EPSG:32651"
CENTRE_LAT, CENTRE_LON, CENTRE_H = 24.0, 121.3, 120.0   # west of UTM 51's central meridian: convergence ~ -0.7 deg


def block_flight_camera(width: int = 1200, height: int = 800) -> Fraser7:
    """The simulated payload camera (fraser7, px): f ~ 0.83 w, mild barrel distortion, small affinity."""
    s = width / 1200.0
    return Fraser7((width, height), np.array([1000.0 * s, (width - 1) / 2 + 4.0 * s, (height - 1) / 2 - 3.0 * s,
                                              -0.06, 0.02, 0.0, 2e-4, -1e-4, 0.4 * s, 0.15 * s]))


def terrain_height(e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Terrain height (m, local Up) at local E, N (m): gentle hills a few metres high."""
    return (3.0 * np.sin(e / 45.0) * np.cos(n / 60.0) + 1.5 * np.sin((e + n) / 25.0) + 0.004 * e)


def _flight_plan(camera: Fraser7, heights, n_strips, n_images, rng):
    w, h = camera.image_size
    f = camera["f"]
    plan = []
    for hi, (H, ns, ni) in enumerate(zip(heights, n_strips, n_images)):
        across = w / f * H          # image x across track for north/south strips
        along = h / f * H
        base = 0.2 * along          # 80 % forward overlap
        spacing = 0.6 * across      # 40 % side overlap
        e0 = -spacing * (ns - 1) / 2
        n0 = -base * (ni - 1) / 2
        for s in range(ns):
            north = s % 2 == 0
            for j in range(ni):
                jj = j if north else ni - 1 - j
                plan.append(dict(height=H, strip=f"h{hi}s{s}", heading=0.0 if north else 180.0,
                                 e=e0 + s * spacing, n=n0 + jj * base))
    return plan


def simulate_block_flight(out: str | Path, seed: int = 0, crs: str = DEFAULT_CRS, render: bool = True,
                          heights=(80.0, 120.0), n_strips=(3, 2), n_images=(14, 10), n_control: int = 12,
                          n_check: int = 10, n_tie: int = 1500, noise_px: float = 0.3,
                          gcp_sigma=(0.01, 0.01, 0.02), image_size=(1200, 800), targets: str = "disc",
                          target_size_m: float = 2.0) -> dict:
    """Write a simulated flight to `out` and return the truth dictionary (also in `truth.json`).

    `targets`: "disc" (quartered discs, ids GCPnn/CHKnn) or "aruco" (DICT_4X4_50 markers of
    `target_size_m`, top to grid north, point ids = marker ids "0", "1", ...)."""
    rng = np.random.default_rng(seed)
    cam = block_flight_camera(*image_size)
    world = World(MapGrid(crs), LocalENU(CENTRE_LAT, CENTRE_LON, CENTRE_H))
    plan = _flight_plan(cam, heights, n_strips, n_images, rng)
    names, C_world, R_world_to_cam = _true_poses(plan, rng)
    # ground points: control and check spread over the low-flight block, inset from its edge
    gp_ids, role, gp_loc = _ground_points(rng, cam, C_world, heights, n_control + n_check, targets)
    # tie points spread over the whole block
    lo2, hi2 = C_world[:, :2].min(0) - 20, C_world[:, :2].max(0) + 20
    te = rng.uniform(lo2, hi2, (n_tie, 2))
    tie_loc = np.column_stack([te, terrain_height(te[:, 0], te[:, 1])])
    tie_ids = np.array([f"T{i:05d}" for i in range(n_tie)], dtype=object)
    gi, gid, guv = _observe(cam, names, C_world, R_world_to_cam, gp_ids, gp_loc)
    ti, tid, tuv = _observe(cam, names, C_world, R_world_to_cam, tie_ids, tie_loc)
    # keep tie points seen at least twice
    uniq, cnt = np.unique(tid, return_counts=True)
    twice = set(uniq[cnt >= 2].tolist())
    keep = np.array([t in twice for t in tid], bool)   # np.isin on object arrays is quadratic
    ti, tid, tuv = ti[keep], tid[keep], tuv[keep]
    g_noisy = guv + rng.normal(0, noise_px, guv.shape)
    t_noisy = tuv + rng.normal(0, noise_px, tuv.shape)

    # map coordinates
    gp_map = world.to_map(gp_loc)
    sig = np.tile(np.asarray(gcp_sigma, float), (len(gp_ids), 1))
    gp_map_obs = gp_map + rng.normal(0, 1.0, gp_map.shape) * sig
    C_map, opk, _ = world.poses_to_eop(Poses(R_world_to_cam, C_world))
    gsd = {f"{H:g}": float((H - 0.0) / cam["f"]) for H in heights}

    with staged_dir(Path(out)) as tmp:
        write_points(tmp / "gcp.csv", Points(gp_ids, gp_map_obs, sig, role), with_role=True)
        write_measurements(tmp / "measurements.csv", Measurements(gi, gid, g_noisy, np.full(guv.shape, noise_px)))
        write_measurements(tmp / "measurements_exact.csv", Measurements(gi, gid, guv, np.full(guv.shape, np.nan)))
        write_measurements(tmp / "tie_measurements.csv", Measurements(ti, tid, t_noisy, np.full(tuv.shape, noise_px)))
        write_measurements(tmp / "measurements_all.csv",
                           Measurements(np.concatenate([gi, ti]), np.concatenate([gid, tid]),
                                        np.concatenate([g_noisy, t_noisy]), np.full((len(gi) + len(ti), 2), noise_px)))
        write_eop(tmp / "truth_eop.csv", EOP(np.array(names, dtype=object), C_map, opk))
        write_camera_json(tmp / "camera.json", cam, stats={"rms_px": 0.0, "n_observations": 0, "n_rejected": 0})
        if render:
            # texels a little finer than the lowest flight's ground pixel: detail without aliasing
            _render_all(tmp / "images", cam, names, R_world_to_cam, C_world, gp_loc, seed,
                        texel_m=0.8 * min(heights) / cam["f"], targets=targets, target_size_m=target_size_m)
        truth = {
            "crs": crs, "local_frame": {"lat0": CENTRE_LAT, "lon0": CENTRE_LON, "h0": CENTRE_H},
            "camera": {"model": cam.NAME, "image_size": list(cam.image_size), "params": cam.as_dict()},
            "noise_px": noise_px, "gcp_sigma_m": list(gcp_sigma), "gsd_m": gsd,
            "images": [{"image": names[i], "X": C_map[i].tolist(), "opk_deg": opk[i].tolist(),
                        "C_local": C_world[i].tolist(), "R_world_to_cv_local": R_world_to_cam[i].tolist(),
                        "height_m": plan[i]["height"], "strip": plan[i]["strip"]} for i in range(len(names))],
            "ground_points": [{"id": gp_ids[i], "role": role[i], "xyz": gp_map[i].tolist(),
                               "local": gp_loc[i].tolist()} for i in range(len(gp_ids))],
            "n_tie_points": int(len(np.unique(tid))), "n_tie_observations": int(len(tid)),
        }
        with atomic_write(tmp / "truth.json") as fh:
            json.dump(truth, fh, indent=1)
    return truth


def _true_poses(plan: list[dict], rng) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Image names, true centres (M,3) (world, m) and R_world_to_cam (M,3,3) of the planned stations: nadir, image
    top to the heading, with position and attitude jitter."""
    names, C_world, R_world_to_cam = [], [], []
    for k, p in enumerate(plan):
        C_world_i = np.array([p["e"], p["n"], p["height"]]) + rng.normal(0, [1.0, 1.0, 0.5])
        # camera: nadir, image top to the heading direction, plus a few degrees of jitter
        kappa = -p["heading"]
        R_cam_to_enu = (Rotation.from_euler("xyz", rng.normal(0, [1.5, 1.5, 2.0]), degrees=True).as_matrix()
                        @ Rotation.from_euler("z", kappa, degrees=True).as_matrix() @ R_CV_TO_PHOTO)
        names.append(f"IMG_{k:04d}.png")
        C_world.append(C_world_i)
        R_world_to_cam.append(R_cam_to_enu.T)
    return names, np.array(C_world), np.array(R_world_to_cam)


def _ground_points(rng, cam: Fraser7, C_world: np.ndarray, heights, n_gp: int,
                   targets: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ids, roles (control/check alternately) and world coordinates (m, on the terrain) of ground points on a
    jittered grid over the low-flight block, inset from its edge."""
    half_fp = 0.3 * min(heights) * np.array(cam.image_size, float)[::-1] / cam["f"]   # N-S strips: x across
    mid = 0.5 * (C_world[:, :2].min(0) + C_world[:, :2].max(0))
    lo = np.minimum(C_world[:, :2].min(0) + 10, mid - half_fp)
    hi = np.maximum(C_world[:, :2].max(0) - 10, mid + half_fp)
    gx = int(np.ceil(np.sqrt(n_gp * (hi[0] - lo[0]) / (hi[1] - lo[1]))))
    gy = int(np.ceil(n_gp / gx))
    ee, nn = np.meshgrid(np.linspace(lo[0], hi[0], gx), np.linspace(lo[1], hi[1], gy))
    step = np.min((hi - lo) / np.maximum([gx - 1, gy - 1], 1))
    # jitter small enough that neighbouring targets (up to ~3 m with their quiet zone) never overlap
    jitter = min(3.0, max(0.0, step / 2 - 2.0))
    en = np.column_stack([ee.ravel(), nn.ravel()])[:n_gp] + rng.uniform(-1, 1, (n_gp, 2)) * jitter
    gp_loc = np.column_stack([en, terrain_height(en[:, 0], en[:, 1])])
    role = np.array(["control", "check"] * n_gp, dtype=object)[:n_gp]
    if targets == "aruco":
        gp_ids = np.array([str(i) for i in range(n_gp)], dtype=object)
    else:
        gp_ids = np.array([f"GCP{i:02d}" if role[i] == "control" else f"CHK{i:02d}" for i in range(n_gp)], dtype=object)
    return gp_ids, role, gp_loc


def _observe(cam: Fraser7, names: list[str], C_world: np.ndarray, R_world_to_cam: np.ndarray, ids: np.ndarray,
             X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noise-free projections (px) of world points X (m) into every image: (image, id, uv) rows."""
    rows_img, rows_id, rows_uv = [], [], []
    for i in range(len(names)):
        Xc = (X - C_world[i]) @ R_world_to_cam[i].T
        ok = Xc[:, 2] > 1.0
        uv = np.full((len(X), 2), np.nan)
        uv[ok] = cam.project(Xc[ok])
        w, h = cam.image_size
        ok &= (uv[:, 0] > 5) & (uv[:, 0] < w - 6) & (uv[:, 1] > 5) & (uv[:, 1] < h - 6)
        for j in np.nonzero(ok)[0]:
            rows_img.append(names[i])
            rows_id.append(ids[j])
            rows_uv.append(uv[j])
    return (np.array(rows_img, dtype=object), np.array(rows_id, dtype=object), np.array(rows_uv).reshape(-1, 2))


# ---------------------------------------------------------------------------------------------
def _texture(seed: int, size: int = 4096) -> np.ndarray:
    """A seamless (periodic) 1/f noise texture (uint8): detail at every scale, for SIFT, and no tile seams.
    Its period (size x texel) must exceed the block, or SIFT matches repeated ground."""
    rng = np.random.default_rng(seed + 1000)
    fx = np.fft.rfftfreq(size)[None, :]
    fy = np.fft.fftfreq(size)[:, None]
    f = np.hypot(fx, fy)
    f[0, 0] = 1.0
    spec = np.fft.rfft2(rng.normal(size=(size, size)).astype(np.float32)) / f ** 1.1 * np.exp(-(f / 0.25) ** 2)
    tex = np.fft.irfft2(spec, s=(size, size))
    tex = (tex - tex.mean()) / tex.std()
    return np.clip(128 + 38 * tex, 10, 245).astype(np.uint8)


def _render_all(folder: Path, cam: Fraser7, names, R_world_to_cam, C_world, gp_loc, seed: int,
                texel_m: float = 0.07, targets: str = "disc", target_size_m: float = 2.0) -> None:
    """Render each image: ray -> terrain intersection (fixed-point on height) -> texture, plus GCP targets
    (a white disc of 1 m radius with a black-and-white quartered centre of 0.5 m radius)."""
    folder.mkdir(parents=True, exist_ok=True)
    tex = _texture(seed)
    size = tex.shape[0]
    w, h = cam.image_size
    uu, vv = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    rays_cam = cam.ray(np.column_stack([uu.ravel(), vv.ravel()]))
    target_r = 0.5
    markers = None
    if targets == "aruco":
        dic = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
        markers = [cv2.aruco.generateImageMarker(dic, j, 120, borderBits=1) for j in range(len(gp_loc))]
    for i, name in progress.track(list(enumerate(names)), "rendering images"):
        d = rays_cam @ R_world_to_cam[i]          # world directions
        C_world_i = C_world[i]
        z = np.full(len(d), terrain_height(np.array([C_world_i[0]]), np.array([C_world_i[1]]))[0])
        for _ in range(5):
            t = (z - C_world_i[2]) / d[:, 2]
            P = C_world_i + t[:, None] * d
            z = terrain_height(P[:, 0], P[:, 1])
        ix = np.mod(P[:, 0] / texel_m, size).astype(np.float32).reshape(h, w)
        iy = np.mod(-P[:, 1] / texel_m, size).astype(np.float32).reshape(h, w)
        img = cv2.remap(tex, ix, iy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP).astype(np.float32)
        P3 = P.reshape(h, w, 3)
        Xc = (gp_loc - C_world_i) @ R_world_to_cam[i].T
        front = Xc[:, 2] > 1
        if front.any():
            uv = np.full((len(gp_loc), 2), np.nan)
            uv[front] = cam.project(Xc[front])
            reach = 1.5 if markers is None else target_size_m
            rad = int(np.ceil(reach * cam["f"] / max(np.min(Xc[front, 2]), 1.0))) + 3
            for gi, (g, (u, v)) in enumerate(zip(gp_loc, uv)):
                if not (np.isfinite(u) and -rad < u < w + rad and -rad < v < h + rad):
                    continue
                r0, r1 = max(0, int(v) - rad), min(h, int(v) + rad + 1)
                c0, c1 = max(0, int(u) - rad), min(w, int(u) + rad + 1)
                if r0 >= r1 or c0 >= c1:
                    continue
                win = P3[r0:r1, c0:c1]
                dx, dy = win[..., 0] - g[0], win[..., 1] - g[1]
                sub = img[r0:r1, c0:c1]
                if markers is not None:
                    # white quiet zone, then the marker: image rows run from grid north to south
                    half = target_size_m / 2
                    sub[(np.abs(dx) < 1.4 * half) & (np.abs(dy) < 1.4 * half)] = 245.0
                    inside = (np.abs(dx) < half) & (np.abs(dy) < half)
                    mk = markers[gi]
                    n_px = mk.shape[0]
                    col = np.clip(((dx / target_size_m + 0.5) * n_px).astype(int), 0, n_px - 1)
                    row = np.clip(((-dy / target_size_m + 0.5) * n_px).astype(int), 0, n_px - 1)
                    sub[inside] = np.where(mk[row, col] > 127, 245.0, 15.0)[inside]
                    continue
                r = np.hypot(dx, dy)
                sub[r < 1.0] = 245.0
                sub[r < target_r] = 15.0
                sub[(r < target_r) & ((dx > 0) == (dy > 0))] = 245.0
        img = cv2.GaussianBlur(img, (0, 0), 0.6)
        cv2.imwrite(str(folder / name), np.clip(img, 0, 255).astype(np.uint8))
