"""Benchmark of the demo campaign: wall time of the simulation and of each step of `dgcal run` (printed).

Runs what `make demo` runs (`dgcal demo`: seed 3, 300 m + 600 m flight, 112 images) in a temporary folder,
then the resumed run (every step up to date) and prints the accuracy against the simulation truth.
Usage: .venv/bin/python bench/campaign.py [--keep DIR]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--keep", type=Path, help="write into this folder and keep it")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=None, help="steps at once (default: as `make demo`, one per CPU)")
    args = ap.parse_args()
    from dgcal.campaign import run_campaign
    from dgcal.step_pool import default_jobs
    jobs = args.jobs or default_jobs()
    from dgcal.sim.campaign import simulate_campaign

    root = args.keep or Path(tempfile.mkdtemp(prefix="dgcal-bench-"))
    data, out = root / "data", root / "results"
    devnull = open(os.devnull, "w")
    t0 = time.perf_counter()
    truth = simulate_campaign(data, args.seed)
    t_sim = time.perf_counter() - t0
    stdout = sys.stdout
    sys.stdout = devnull  # the verbs' own output
    try:
        res = run_campaign(data / "campaign.toml", out, log=devnull, jobs=jobs)
        t1 = time.perf_counter()
        res2 = run_campaign(data / "campaign.toml", out, log=devnull, jobs=jobs)
        t_resume = time.perf_counter() - t1
    finally:
        sys.stdout = stdout
    total = time.perf_counter() - t0
    print(f"demo campaign (seed {args.seed}): {truth['flight']['n_images']} images, "
          f"{truth['flight']['duration_s']:.0f} s flight, {truth['n_observations']['tie']} tie observations, "
          f"{truth['camera_field']['n_observations']} plate observations; {os.cpu_count()} CPUs, "
          f"{jobs} step(s) at once")
    print(f"  {'simulate':18s} {t_sim:7.1f} s")
    for k, v in res["timings_s"].items():
        print(f"  {k:18s} {v:7.1f} s")
    print(f"  {'total':18s} {total - t_resume:7.1f} s   (issue 17's target for `make demo`: 20 s)")
    print(f"  resumed run (all {sum(v == 'skipped' for v in res2['steps'].values())} steps skipped, report): "
          f"{t_resume:.1f} s")
    rep = json.loads((out / "report.json").read_text())
    for k, e in rep["truth_comparison"]["mounting"].items():
        print(f"  {k:11s} delay {e['delay_error_s'] * 1e3:+6.2f} ms, lever arm "
              + ", ".join(f"{v * 100:+6.2f}" for v in e["lever_arm_error_m"]) + " cm, boresight "
              + ", ".join(f"{v:+.4f}" for v in e["boresight_error_deg"]) + " deg (estimate - truth)")
    for k, c in rep["check"]["checks"].items():
        b = c["budget"]
        print(f"  DG {k:11s} 3D RMS {c['stats']['rms']['3D']:.3f} m, predicted {b['predicted_rms']['3D']:.3f} m "
              f"(ratio {b['ratio_achieved_to_predicted']['3D']:.2f}) on {c['stats']['n']} check points")
    print(f"  report: {out / 'report.html'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
