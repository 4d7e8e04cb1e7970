"""Simulate a data set with known truth (`truth.json`); the sub-commands are the modules of `sim`."""
from __future__ import annotations

import argparse

from dgcal.cli import _verb_modules

NAME = "simulate"
HELP = "simulate a synthetic data set with known truth"


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="what", metavar="WHAT")
    sub.required = True
    for mod in _verb_modules("sim"):
        q = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, "__doc__", None))
        mod.add_arguments(q)
        q.set_defaults(_sim_run=mod.run)


def run(args: argparse.Namespace) -> int:
    return int(args._sim_run(args) or 0)
