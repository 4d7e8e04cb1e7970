"""The `dgcal` command: finds the verbs in dgcal.commands and runs one, turning input errors into one line."""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import traceback

from fields.errors import InputError


def _verb_modules(package: str):
    pkg = importlib.import_module(package)
    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{package}.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            yield mod


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every verb found in dgcal.commands."""
    parser = argparse.ArgumentParser(prog="dgcal", description="Calibrate UAV payloads for direct georeferencing.")
    parser.add_argument("--debug", action="store_true", help="show the full traceback on errors")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    sub.required = True
    for mod in _verb_modules("dgcal.commands"):
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, "__doc__", None))
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `dgcal` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except InputError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"dgcal {args.verb}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"dgcal {args.verb}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
