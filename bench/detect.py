"""Benchmark: render 20 MP photos of the default plate and time/score the target detection.

Prints per-image render and detection times, recovery of the visible targets, corner errors against the
true projections (dgcal's refinement and OpenCV's plain CharucoDetector corners on the same images) and
the honesty of the reported sigmas. Usage: python bench/detect.py [--n-images 4] [--image-size 5472 3648]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n-images", type=int, default=4)
    p.add_argument("--image-size", type=int, nargs=2, default=(5472, 3648))
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", help="keep the rendered data set here (default: a temporary folder)")
    p.add_argument("--boards", action="store_true", help="also the standard boards (charuco, chessboard, aruco-grid)")
    a = p.parse_args()

    import cv2

    from dgcal.calib.selfcal.detection import CharucoFieldDetector, detect_folder, read_gray
    from dgcal.fields.io.csv_tables import read_table
    from dgcal.fields.targets.plate import TargetField
    from dgcal.sim.camera_field import simulate_camera_field

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(a.out or tmp)
        t0 = time.perf_counter()
        simulate_camera_field(out, seed=a.seed, n_images=a.n_images, image_size=tuple(a.image_size))
        t_render = (time.perf_counter() - t0) / a.n_images
        tf = TargetField()
        det = CharucoFieldDetector(tf)
        names = sorted(p.name for p in (out / "images").iterdir())
        t_serial = []
        for n in names:
            img = read_gray(out / "images" / n)
            t1 = time.perf_counter()
            det.detect(img)
            t_serial.append(time.perf_counter() - t1)
        t1 = time.perf_counter()
        meas, report = detect_folder(out / "images", out / "field.csv", workers=a.workers)
        t_folder = time.perf_counter() - t1

        tr = read_table(out / "truth_measurements.csv", ["image", "id", "x", "y", "complete"])
        truth = {(i, k): (np.array([x, y]), c) for i, k, x, y, c in
                 zip(tr["image"], tr["id"], tr["x"], tr["y"], tr["complete"])}
        found = {(i, k): (xy, s) for i, k, xy, s in zip(meas.image, meas.id, meas.xy, meas.sigma)}
        visible = [k for k, (_, c) in truth.items() if c == 1]
        rec = np.mean([k in found for k in visible])
        err = np.array([found[k][0] - truth[k][0] for k in found])
        z = np.concatenate([(found[k][0] - truth[k][0]) / found[k][1] for k in found])

        # OpenCV's own ChArUco corners (its cornerSubPix settings) on the same images, same targets
        board = tf.board()
        cd = cv2.aruco.CharucoDetector(board)
        target_of = det.target_of_corner
        err_cv = []
        for n in names:
            cc, cids, _, _ = cd.detectBoard(read_gray(out / "images" / n))
            if cids is None:
                continue
            for c, k in zip(cc.reshape(-1, 2), cids.ravel()):
                key = (n, target_of.get(int(k)))
                if key in found:
                    err_cv.append(c - truth[key][0])
        err_cv = np.array(err_cv)

    w, h = a.image_size
    print(f"images: {a.n_images} x {w}x{h} ({w * h / 1e6:.1f} MP), default plate ({len(tf.targets()[0])} targets)")
    print(f"render: {t_render:.1f} s/image")
    print(f"detect: {np.mean(t_serial):.2f} s/image serial (min {np.min(t_serial):.2f}, max {np.max(t_serial):.2f}); "
          f"folder with {a.workers} workers {t_folder / a.n_images:.2f} s/image")
    print(f"recovered {rec * 100:.1f} % of {len(visible)} visible targets; {len(found)} measurements")
    print(f"corner error dgcal : RMS {np.sqrt(np.mean(err ** 2)):.4f} px per axis, max {np.abs(err).max():.3f} px")
    if len(err_cv):
        print(f"corner error OpenCV: RMS {np.sqrt(np.mean(err_cv ** 2)):.4f} px per axis, "
              f"max {np.abs(err_cv).max():.3f} px (CharucoDetector defaults, same targets)")
    print(f"sigma honesty: RMS(error/sigma) = {np.sqrt(np.mean(z ** 2)):.2f} (1 = honest)")
    if a.boards:
        bench_boards(a.seed)


def bench_boards(seed: int, n_images: int = 12, size=(960, 720)) -> None:
    """Standard boards rendered by the simulator: detection time per image and corner errors against the truth."""
    import cv2

    from dgcal.calib.selfcal.board_detection import BoardDetector
    from dgcal.fields.io.formats import read_measurements
    from dgcal.fields.targets.boards import Board
    from dgcal.sim.camera_field import simulate_board_views
    boards = {"charuco (inverted)": Board("charuco", 12, 9, 0.03, 0.0225, "DICT_4X4_250", inverted=True),
              "chessboard": Board("chessboard", 12, 9, 0.025),
              "aruco-grid": Board("aruco-grid", 8, 6, 0.04, 0.032, "DICT_5X5_250", first_id=3)}
    print(f"standard boards, {n_images} rendered views of {size[0]}x{size[1]}:")
    for name, b in boards.items():
        with tempfile.TemporaryDirectory() as d:
            out = Path(d) / "v"
            simulate_board_views(out, b, seed=seed, n_images=n_images, image_size=size)
            tm = read_measurements(out / "truth_measurements.csv")
            key = {(i, k): p for i, k, p in zip(tm.image, tm.id, tm.xy)}
            det = BoardDetector(b)
            err, t = [], 0.0
            for f in sorted((out / "images").iterdir()):
                g = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
                t0 = time.perf_counter()
                r = det.detect(g)
                t += time.perf_counter() - t0
                err += [p - key[(f.name, k)] for k, p in zip(r.ids, r.xy) if (f.name, k) in key]
            e = np.array(err)
            print(f"  {name:20s} {t / n_images * 1000:6.0f} ms/image, {len(e)} of {len(tm)} corners, error RMS "
                  f"{np.sqrt(np.mean(e ** 2)):.4f} px per axis, median |e| {np.median(np.abs(e)):.4f} px")


if __name__ == "__main__":
    main()
