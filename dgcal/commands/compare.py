"""Has the mounting changed since the last calibration? Differences against combined sigmas, chi-square test."""
from __future__ import annotations

import argparse
from pathlib import Path
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "compare"
HELP = "compare two mounting calibrations (chi-square test of change)"
OUTPUTS: dict[str, str] = {}  # writes only the --out file it is given


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("old", type=Path, help="earlier mounting.json")
    p.add_argument("new", type=Path, help="newer mounting.json")
    p.add_argument("--alpha", type=arg_types.probability, default=0.01,
                   help="significance level of the test (default 0.01)")
    p.add_argument("--out", type=Path, help="write the comparison as JSON here")
    p.add_argument("--fail-on-change", action="store_true", help="exit 1 when the change is significant")


def run(args: argparse.Namespace) -> int:
    from dgcal.calib.mounting.compare import CompareOptions, compare_mounting_files
    from dgcal.reports.mounting import write_comparison_json

    r = compare_mounting_files(CompareOptions(args.old, args.new, args.alpha))
    d, s = r["difference"], r["combined_sigma"]
    print(f"delay     {d['delay_s']:+.5f} s  (sigma {s['delay_s']:.5f})")
    print("lever arm " + ", ".join(f"{v:+.4f}" for v in d["lever_arm_m"]) + " m  (sigma "
          + ", ".join(f"{v:.4f}" for v in s["lever_arm_m"]) + ")")
    print("boresight " + ", ".join(f"{v:+.5f}" for v in d["boresight_deg"]) + " deg  (sigma "
          + ", ".join(f"{v:.5f}" for v in s["boresight_deg"]) + ")")
    print(f"chi2 {r['chi2']:.2f} with {r['dof']} dof, p = {r['p_value']:.4g}: "
          + ("CHANGED significantly" if r["changed"] else "no significant change") + f" at alpha {args.alpha}")
    if args.out:
        write_comparison_json(args.out, r)
    return 1 if (args.fail_on_change and r["changed"]) else 0
