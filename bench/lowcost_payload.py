"""Benchmark of the low-cost payload toolchain (seeds 000 and 001) at full size: the 15-state UKF against the
gtsam smoother on a 6-minute ADIS16405 + 50 Hz GNSS flight, seed 000 Table 6 (15 images, several seeds) and
seed 001 Table 2 on a 300 s flight with a frame pair every 2 s. Prints tables, accuracies and run times.
Run by hand: `.venv/bin/python bench/lowcost_payload.py [--quick]`."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

# run as a script, bench/ is first on sys.path and bench/pos.py would shadow the `pos` package
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="shorter runs")
    args = ap.parse_args()
    from dgcal.sim.forward_camera import flow_attitude_study, format_table2, make_forward_camera_sim
    from dgcal.sim.lowcost_flight import (compare_ukf_smoother, format_accuracy_table, format_table6, georef_campaign,
                                    simulate_lowcost_flight)

    dur = 120.0 if args.quick else 360.0
    f = simulate_lowcost_flight(duration_s=dur, rate_hz=100.0, seed=1)
    t0 = time.process_time()
    rep = compare_ukf_smoother(f, smoother_rate_hz=10.0, skip_s=30.0, progress=True)
    print(f"\nUKF vs smoother, {dur:.0f} s flight, 100 Hz IMU, 50 Hz GNSS ({time.process_time() - t0:.1f} s CPU)")
    print(format_accuracy_table(rep))
    print("UKF normalised attitude errors (rms of error/sigma):", np.round(rep["ukf_normalised_error_rms"], 2))

    seeds = [0] if args.quick else [0, 1, 2, 3]
    for s in seeds:
        t0 = time.process_time()
        r6 = georef_campaign(seed=s)
        print(f"\nseed 000 Table 6, simulation seed {s} ({time.process_time() - t0:.1f} s CPU)")
        print(format_table6(r6))
        for k, v in r6["summary"].items():
            print(f"  {k:10s} mean {v['mean_total_m']:6.2f} m  std {v['std_total_m']:5.2f} m  average of 15 "
                  f"{v['average_error_m']:5.2f} m  weighted {v['weighted_average_error_m']:5.2f} m "
                  f"(sigma incl. common GNSS error {v['weighted_average_sigma_common_m']:5.2f} m)  "
                  f"error/sigma rms {v['normalised_error_rms']:4.2f}")

    t0 = time.process_time()
    sim = make_forward_camera_sim(duration_s=300.0, image_px=240)
    r2 = flow_attitude_study(sim, pair_every_s=10.0 if args.quick else 2.0, frame_dt=0.5, progress=True)
    print(f"\nseed 001 Table 2 ({r2['n_pairs']} frame pairs, {time.process_time() - t0:.1f} s CPU)")
    print(format_table2(r2))
    print("pseudo attitude alone:", {k: round(v, 3) for k, v in r2["pseudo_only"].items()})
    print("FOE sigma honesty (rms error/sigma):", r2["normalised_error_rms"])


if __name__ == "__main__":
    main()
