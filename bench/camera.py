"""Benchmark of camera calibration: the self-calibrating adjustment for 60 images x ~1000 corners beside
OpenCV calibrateCamera on the same measurements (time and accuracy against the simulated truth), target
refinement, and ChArUco detection time per 20 MP image. Run by hand: `.venv/bin/python bench/camera.py`."""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def simulate(n_images: int, square_m: float, seed: int, size=(5472, 3648), noise_px=0.1):
    """Projected field corners (px) with Gaussian noise for a fraser7 truth; returns truth, points, image, id, xy."""
    from dgcal.fields.targets.plate import TargetField
    from dgcal.sim.camera_field import calibration_field_camera, plan_shots
    rng = np.random.default_rng(seed)
    tf = TargetField(square_m=square_m, marker_m=0.75 * square_m)
    pts = tf.points()
    truth = calibration_field_camera(size)
    truth.params[9] = 0.0  # no skew, so OpenCV's model can represent the truth
    w, h = size
    img, ids, xy = [], [], []
    for s in plan_shots(n_images, truth, tf, rng):
        Xc = pts.xyz @ s.R_field_to_cam.T + s.t_field_to_cam
        uv = truth.project(Xc)
        ok = (Xc[:, 2] > 0) & (uv[:, 0] >= 2) & (uv[:, 0] <= w - 3) & (uv[:, 1] >= 2) & (uv[:, 1] <= h - 3)
        img += [s.image] * int(ok.sum())
        ids.append(pts.ids[ok])
        xy.append(uv[ok] + rng.normal(0, noise_px, (int(ok.sum()), 2)))
    return truth, pts, np.array(img), np.concatenate(ids), np.vstack(xy)


def opencv_calibrate(pts, img, ids, xy, size, rational=False):
    """Time (s), RMS (px) and model of OpenCV calibrateCamera on the same measurements."""
    from dgcal.calib.selfcal.opencv_baseline import calibrate_with_opencv
    t0 = time.perf_counter()
    rms, cam = calibrate_with_opencv(pts, img, ids, xy, size, rational)
    return time.perf_counter() - t0, rms, cam


def bench_adjustment(n_images: int, square_m: float, seed: int) -> None:
    from dgcal.calib.selfcal.diagnostics import projection_difference
    from dgcal.calib.selfcal.adjustment import adjust
    size = (5472, 3648)
    truth, pts, img, ids, xy = simulate(n_images, square_m, seed, size)
    n_img = len(set(img.tolist()))
    print(f"simulated: {n_img} images, {len(pts.ids)} field corners, {len(xy)} observations "
          f"({len(xy) / n_img:.0f} per image), 0.1 px noise, {size[0]}x{size[1]} px")
    print(f"{'solver':34s} {'time s':>8s} {'RMS px':>8s} {'truth diff RMS':>15s} {'max px':>8s}")
    runs = (("fraser7", "none", ()), ("fraser7", "none", ("B2",)), ("opencv8", "none", ()),
            ("fraser7", "free", ()))
    for model, refine, fixed in runs:
        t0 = time.perf_counter()
        res = adjust(pts.ids, pts.xyz, img, ids, xy, size, model, refine_targets=refine, fixed=fixed)
        dt = time.perf_counter() - t0
        d_rms, d_max, _ = projection_difference(truth, res.camera)
        label = "dgcal " + model + (" + targets" if refine != "none" else "") + \
            (f" ({', '.join(fixed)} held)" if fixed else "")
        print(f"{label:34s} {dt:8.2f} {res.rms_px:8.4f} {d_rms:15.4f} {d_max:8.4f}   ({res.iterations} iterations)")
        if model == "fraser7" and refine == "none" and not fixed:
            e = (res.camera.params - truth.params) / res.camera.sigmas
            print(f"{'':34s} parameter errors / sigma: max {np.max(np.abs(e[res.free])):.2f}, "
                  f"RMS {np.sqrt(np.mean(e[res.free] ** 2)):.2f}")
    for rational in (False, True):
        dt, rms, cam = opencv_calibrate(pts, img, ids, xy, size, rational)
        d_rms, d_max, _ = projection_difference(truth, cam)
        print(f"{'OpenCV calibrateCamera ' + ('rational' if rational else '5-coeff'):34s} {dt:8.2f} {rms:8.4f} "
              f"{d_rms:15.4f} {d_max:8.4f}")


def bench_detection(n_images: int) -> None:
    from dgcal.calib.selfcal.detection import detect_folder
    from dgcal.sim.camera_field import simulate_camera_field
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        simulate_camera_field(Path(d) / "sim", seed=1, n_images=n_images, image_size=(5472, 3648), progress=False)
        t_sim = time.perf_counter() - t0
        t0 = time.perf_counter()
        meas, rep = detect_folder(Path(d) / "sim" / "images", Path(d) / "sim" / "field.csv", workers=1,
                                  progress=False)
        dt = time.perf_counter() - t0
    print(f"detection, 20 MP (5472x3648) rendered JPEG: {dt / n_images:.2f} s per image (1 process), "
          f"{len(meas) / n_images:.0f} corners per image; rendering took {t_sim / n_images:.1f} s per image")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--images", type=int, default=60)
    p.add_argument("--square", type=float, default=0.06, help="ChArUco square (m): 0.06 gives ~1000 corners")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--detect-images", type=int, default=3, help="20 MP images to render and detect (0: skip)")
    a = p.parse_args()
    bench_adjustment(a.images, a.square, a.seed)
    if a.detect_images:
        bench_detection(a.detect_images)


if __name__ == "__main__":
    main()
