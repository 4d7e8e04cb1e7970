"""Simulate a data set with known truth (`truth.json`); the sub-commands are the modules of dgcal.simulators."""
from __future__ import annotations

import argparse

from dgcal.cli import add_verbs, rest_after

NAME = "simulate"
HELP = "simulate a synthetic data set with known truth"


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="what", metavar="WHAT")
    sub.required = True
    add_verbs(sub, "dgcal.simulators", rest_after(NAME), run_key="_sim_run")


def run(args: argparse.Namespace) -> int:
    return int(args._sim_run(args) or 0)
