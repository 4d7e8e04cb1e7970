"""Run a calibration campaign: camera field -> triangulation -> POS -> mounting (and the methods compared) ->
DG check, resumable (a finished step is skipped unless its arguments or inputs changed or its outputs are
incomplete; an interrupted run's leftovers are cleaned up first), ending with the calibration
report DIR/report.html and DIR/report.json. The campaign file is described in docs/campaign.md."""
from __future__ import annotations

import argparse
from pathlib import Path

from dgcal.step_pool import default_jobs
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "run"
HELP = "run (or resume) a calibration campaign from CAMPAIGN.toml and write its calibration report"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("campaign", type=Path, metavar="CAMPAIGN.toml", help="campaign file (paths relative to it)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (one sub-folder per step)")
    p.add_argument("--force", action="store_true", help="rerun every step even when it is up to date")
    p.add_argument("--rerun", nargs="+", default=[], metavar="STEP",
                   help="rerun these steps (and every step after them that reads their outputs) even when up to "
                        "date: step names as --dry-run lists them (mount_iso) or verbs (mount: every mounting step)")
    add_jobs_argument(p)
    p.add_argument("--dry-run", action="store_true", help="list the steps and their commands, run nothing")


def add_jobs_argument(p: argparse.ArgumentParser) -> None:
    """--jobs: steps run at once (each in its own process)."""
    n = default_jobs()
    p.add_argument("--jobs", "-j", type=arg_types.positive_int, default=n, metavar="N",
                   help=f"run up to N independent steps at once, each in its own process (default {n}: one per "
                        "CPU, at most 4; 1 runs the steps in order in this process)")


def run(args: argparse.Namespace) -> int:
    from dgcal.campaign import load_campaign, plan, run_campaign
    if args.dry_run:
        for step in plan(load_campaign(args.campaign), args.out):
            print(f"[{step.name}] dgcal {' '.join(step.argv)}")
        return 0
    res = run_campaign(args.campaign, args.out, force=args.force, rerun=args.rerun, jobs=max(1, args.jobs))
    ran = [k for k, v in res["steps"].items() if v == "ran"]
    print(f"{len(ran)} step(s) ran, {len(res['steps']) - len(ran)} up to date; "
          + ", ".join(f"{k} {v:.1f} s" for k, v in res["timings_s"].items()))
    print(res["report"])
    return 0
