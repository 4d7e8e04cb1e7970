"""Benchmark: bundle adjustment time for 300 images x 50k tie points (simulated flight, 0.3 px noise).

Prints the time of each stage (simulation, initial orientation by PnP growth, bundle adjustment with
covariance) and the accuracy against truth. Run by hand: `.venv/bin/python bench/bundle.py [--tie N]`.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# run as `python bench/bundle.py`, this file's folder comes first on sys.path and its name would shadow
# the `bundle` package
sys.path = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--tie", type=int, default=50000, help="simulated tie points")
    ap.add_argument("--out", help="keep the simulated data here")
    args = ap.parse_args()
    from dgcal.bundle.triangulation import TriangulationOptions, triangulate
    from dgcal.calib.camera.files import load_camera
    from dgcal.fields.io.formats import read_eop, read_measurements, read_points
    from dgcal.sim.flight import simulate_block_flight

    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_bundle_"))
    t0 = time.perf_counter()
    truth = simulate_block_flight(out, seed=1, render=False, heights=(80.0, 120.0), n_strips=(6, 4), n_images=(30, 30),
                                  n_control=20, n_check=16, n_tie=args.tie)
    t1 = time.perf_counter()
    cam = load_camera(out / "camera.json")
    pts = read_points(out / "gcp.csv")
    meas = read_measurements(out / "measurements_all.csv")
    n_img, n_pts = len(truth["images"]), truth["n_tie_points"]
    print(f"simulated {n_img} images, {n_pts} tie points, {len(meas)} image observations in {t1 - t0:.1f} s")
    t2 = time.perf_counter()
    res = triangulate(cam, pts, meas, truth["crs"], TriangulationOptions(verbose=False))
    t3 = time.perf_counter()
    te = read_eop(out / "truth_eop.csv")
    idx = {k: i for i, k in enumerate(te.image)}
    ti = [idx[k] for k in res.eop.image]
    z = np.column_stack([res.eop.xyz - te.xyz[ti], (res.eop.opk - te.opk[ti] + 180) % 360 - 180]) / res.eop.sigma
    s = res.summary
    print(f"triangulation (initial orientation + bundle + covariance + check points): {t3 - t2:.1f} s, "
          f"{res.bundle.iterations} LM iterations, sigma0 {res.bundle.sigma0:.3f}")
    print("stages (s):", s["timings_s"], "(initialised = PnP growth; adjusted = first bundle with covariance; "
          "cleaned = outlier/blunder re-adjustments; done = check points, map conversion, reports)")
    print("normalised EOP errors RMS (X Y Z omega phi kappa):", np.round(np.sqrt(np.mean(z ** 2, 0)), 2))
    print(f"{s['n_oriented']}/{s['n_images']} images oriented, {s['n_tie_points']} tie points adjusted; warnings:",
          "; ".join(s["warnings"]) or "none")
    print(f"check RMSE horizontal {s['check_rmse_m']['horizontal']:.4f} m, vertical {s['check_rmse_m']['U']:.4f} m "
          f"(GSD {min(truth['gsd_m'].values()):.3f} m)")


if __name__ == "__main__":
    main()
