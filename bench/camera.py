"""Benchmark of camera calibration: the self-calibrating adjustment for 60 images x ~1000 corners beside
OpenCV calibrateCamera on the same measurements (median time of alternating runs, the ratio, and accuracy
against the simulated truth for both), target
refinement, ChArUco detection time per 20 MP image, the real webcam videos of ../shared/data/charuco-webcam
(detection against OpenCV's own ChArUco detector, RMS against calibrateCamera, timings) and `--model auto` on
mrcal's corners. Run by hand: `.venv/bin/python bench/camera.py`."""
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


def bench_adjustment(n_images: int, square_m: float, seed: int, repeats: int = 3) -> None:
    """dgcal's self-calibration beside OpenCV calibrateCamera on the same measurements: every solver run
    `repeats` times, the solvers alternating (the machine is shared), the median time; RMS and the projection
    difference from the truth over the frame (px) for both."""
    from dgcal.calib.selfcal.diagnostics import projection_difference
    from dgcal.calib.selfcal.adjustment import adjust
    size = (5472, 3648)
    truth, pts, img, ids, xy = simulate(n_images, square_m, seed, size)
    n_img = len(set(img.tolist()))
    print(f"simulated: {n_img} images, {len(pts.ids)} field corners, {len(xy)} observations "
          f"({len(xy) / n_img:.0f} per image), 0.1 px noise, {size[0]}x{size[1]} px; median of {repeats} "
          "alternating runs")

    def dgcal_run(model, refine, fixed):
        def run():
            t0 = time.perf_counter()
            res = adjust(pts.ids, pts.xyz, img, ids, xy, size, model, refine_targets=refine, fixed=fixed)
            return time.perf_counter() - t0, res.rms_px, res.camera, res
        return run

    def opencv_run(rational):
        def run():
            dt, rms, cam = opencv_calibrate(pts, img, ids, xy, size, rational)
            return dt, rms, cam, None
        return run

    solvers = {   # label -> (run, the OpenCV solver it is compared with)
        "dgcal fraser7": (dgcal_run("fraser7", "none", ()), "OpenCV 5-coeff"),
        "dgcal fraser7 (B2 held)": (dgcal_run("fraser7", "none", ("B2",)), "OpenCV 5-coeff"),
        "dgcal opencv8": (dgcal_run("opencv8", "none", ()), "OpenCV rational"),
        "dgcal fraser7 + targets": (dgcal_run("fraser7", "free", ()), "OpenCV 5-coeff"),
        "OpenCV 5-coeff": (opencv_run(False), None),
        "OpenCV rational": (opencv_run(True), None),
    }
    runs: dict[str, list] = {k: [] for k in solvers}
    first = {label: run()[0] for label, (run, _) in solvers.items()}   # warm-up: first calls in this process
    for _ in range(repeats):
        for label, (run, _) in solvers.items():
            runs[label].append(run())
    times = {k: float(np.median([r[0] for r in v])) for k, v in runs.items()}
    print(f"{'solver':26s} {'time s':>7s} {'vs OpenCV':>10s} {'RMS px':>8s} {'truth diff RMS px':>18s} "
          f"{'max px':>8s}")
    for label, (_, peer) in solvers.items():
        dt, rms, cam, res = runs[label][-1]
        d_rms, d_max, _ = projection_difference(truth, cam)
        ratio = f"{times[label] / times[peer]:9.2f}x" if peer else f"{'':10s}"
        extra = f"   ({res.iterations} iterations)" if res is not None else ""
        print(f"{label:26s} {times[label]:7.3f} {ratio} {rms:8.4f} {d_rms:18.4f} {d_max:8.4f}{extra}")
        if label == "dgcal fraser7":
            e = (res.camera.params - truth.params) / res.camera.sigmas
            print(f"{'':26s} parameter errors / sigma: max {np.max(np.abs(e[res.free])):.2f}, "
                  f"RMS {np.sqrt(np.mean(e[res.free] ** 2)):.2f}")
    for label in ("dgcal fraser7", "dgcal fraser7 (B2 held)"):
        ratio = times[label] / times["OpenCV 5-coeff"]
        print(f"target {label} <= 1.5x OpenCV 5-coeff: {ratio:.2f}x, {'met' if ratio <= 1.5 else 'NOT met'}")
    print("(vs OpenCV: dgcal's median time over OpenCV's, fraser7 beside the 5-coefficient model, opencv8 beside "
          "the rational one; RMS px = sqrt(mean |v|^2) over the points for both; after one untimed warm-up call "
          "of each, whose times were: " + ", ".join(f"{k} {v:.3f} s" for k, v in first.items()) + ")")


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


def bench_webcam() -> None:
    """`dgcal camera --board charuco.toml --images cam_N.mp4` on the real webcam videos, beside OpenCV."""
    import cv2

    from dgcal.calib.selfcal.calibration import calibrate_camera
    from dgcal.fields.targets.boards import read_board
    d = Path(__file__).resolve().parents[2] / "shared" / "data" / "charuco-webcam"
    if not d.is_dir():
        print(f"(no {d}: webcam benchmark skipped)")
        return
    board = read_board(d / "charuco.toml")
    ref_det = cv2.aruco.CharucoDetector(board.cv_board())
    print(f"{'video':8s} {'frames':>6s} {'corners':>8s} {'OpenCV':>7s} {'time s':>7s} {'RMS':>7s} {'OpenCV RMS':>10s} "
          f"{'fx':>8s} {'OpenCV fx':>9s} {'valid %':>7s} {'sigma px':>8s}")
    for cam in ("cam_0", "cam_2"):
        t0 = time.perf_counter()
        cal = calibrate_camera(None, images=d / f"{cam}.mp4", board=d / "charuco.toml", fixed=("B2",), reject_k=0,
                               progress=False)
        dt = time.perf_counter() - t0
        chosen = {int(c.label.split("#")[1]) for c in cal.frames.chosen}
        cap = cv2.VideoCapture(str(d / f"{cam}.mp4"))
        objs, imgs, n_cv, k = [], [], 0, 0
        while True:
            ok, fr = cap.read()
            if not ok:
                break
            cc, ci, _, _ = ref_det.detectBoard(255 - cv2.cvtColor(fr, cv2.COLOR_BGR2GRAY))
            if k in chosen and ci is not None:
                n_cv += len(ci)
                objs.append(board.corner_xyz()[ci.ravel()].astype(np.float32))
                imgs.append(cc.reshape(-1, 2))
            k += 1
        rms, K, _, _, _ = cv2.calibrateCamera(objs, imgs, (1280, 720), None, None)
        sig = cal.uncertainty.at(cal.region.grid((41, 29)), infinity=True)
        print(f"{cam:8s} {len(chosen):6d} {len(cal.measurements):8d} {n_cv:7d} {dt:7.2f} {cal.ba.rms_px:7.4f} "
              f"{rms:10.4f} {cal.camera['f'] + cal.camera['B1']:8.1f} {K[0, 0]:9.1f} "
              f"{100 * cal.region.fractions()['valid']:7.1f} {np.median(sig):8.3f}")


def bench_auto() -> None:
    """`--model auto` on mrcal's figueroa corners: the comparison table and the time."""
    from dgcal.calib.selfcal.calibration import calibrate_camera
    d = Path(__file__).resolve().parents[2] / "shared" / "data" / "mrcal-figueroa"
    if not d.is_dir():
        print(f"(no {d}: model-comparison benchmark skipped)")
        return
    t0 = time.perf_counter()
    cal = calibrate_camera(d / "field.csv", measurements=d / "measurements.csv", image_size=(6016, 4016),
                           model="auto", progress=False)
    print(f"--model auto on mrcal's corners: {time.perf_counter() - t0:.1f} s, chose {cal.comparison.chosen}")
    for f in cal.comparison.fits.values():
        r = f.row()
        print(f"  {r['model']:8s} RMS {r['rms_px']:7.3f} px  cross-validation {r['cv_rms_px']:6.3f} px "
              f"(x{r['cv_ratio']:.2f} noise)  {r['rejected'] or ''}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--images", type=int, default=60)
    p.add_argument("--square", type=float, default=0.06, help="ChArUco square (m): 0.06 gives ~1000 corners")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--repeats", type=int, default=3, help="alternating runs of every solver (median time)")
    p.add_argument("--detect-images", type=int, default=3, help="20 MP images to render and detect (0: skip)")
    p.add_argument("--skip-real", action="store_true", help="skip the webcam and mrcal runs")
    a = p.parse_args()
    bench_adjustment(a.images, a.square, a.seed, a.repeats)
    if a.detect_images:
        bench_detection(a.detect_images)
    if not a.skip_real:
        bench_webcam()
        bench_auto()


if __name__ == "__main__":
    main()
