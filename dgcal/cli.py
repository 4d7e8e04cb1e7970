"""The `dgcal` command: finds the verbs in dgcal.commands and runs one, turning input errors into one line."""
from __future__ import annotations

import argparse
import ast
import importlib
import os
import re
import sys
from pathlib import Path

from dgcal.fields import progress
from dgcal.fields.errors import InputError
from dgcal.fields.io.atomic import verb_output_lock
from dgcal.flags import flags_in_errors


_ARGV: list[str] | None = None  # the command line being parsed; None builds every verb (slow, complete)


_FIRST_DEF = re.compile(r"^(?:def|async def|class|@)\b", re.MULTILINE)   # a module's first top-level definition
_RUN = re.compile(r"^def run\s*\(", re.MULTILINE)                      # a top-level run(...)


def _module_constants(source: str) -> dict[str, str]:
    """The string constants a module assigns at its top level (NAME, HELP, ...), read from its source.

    Only the part before its first definition is parsed, where a verb declares them (a seventh of the source of
    dgcal's verbs, and a tenth of the time); the whole source when that part does not parse alone or lacks them.
    """
    def constants(text: str) -> dict[str, str]:
        return {node.targets[0].id: node.value.value for node in ast.parse(text).body
                if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
                and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)}
    m = _FIRST_DEF.search(source)
    if m is not None:
        try:
            head = constants(source[:m.start()])
        except SyntaxError:
            head = {}
        if "NAME" in head and "HELP" in head:
            return head
    return constants(source)


def _verb_index(package: str):
    """(NAME, HELP, module) of every verb module of `package`, read from the source without importing it.

    Importing every verb (and every simulator) pulls in scipy, OpenCV and gtsam; `dgcal --help` and each
    command only import the module they run.
    """
    folder = Path(importlib.import_module(package).__path__[0])
    for path in sorted(folder.glob("[!_]*.py"), key=lambda p: p.stem):
        if "." in path.stem or not path.is_file():
            continue
        source = path.read_text(encoding="utf-8")
        consts = _module_constants(source)
        if "NAME" in consts and _RUN.search(source):
            yield consts["NAME"], consts.get("HELP", ""), f"{package}.{path.stem}"


def rest_after(word: str) -> list[str] | None:
    """The words of the command line after `word` (None when every verb is being built)."""
    if _ARGV is None:
        return None
    return _ARGV[_ARGV.index(word) + 1:] if word in _ARGV else []


def add_verbs(sub, package: str, argv: list[str] | None, run_key: str = "_run") -> None:
    """Add the verbs of `package` to subparsers `sub`; only the one named first in `argv` is imported."""
    word = None if argv is None else next((a for a in argv if not a.startswith("-")), None)
    for name, help_text, modname in _verb_index(package):
        if argv is not None and name != word:
            sub.add_parser(name, help=help_text)  # listed by --help; loaded when chosen
            continue
        mod = importlib.import_module(modname)
        p = sub.add_parser(name, help=help_text, description=getattr(mod, "DESCRIPTION", None) or mod.__doc__)
        mod.add_arguments(p)
        # library errors name options' fields: the verb's flags by destination, and its table where names differ
        flags = {a.dest: max(a.option_strings, key=len) for a in p._actions if a.option_strings}
        p.set_defaults(**{run_key: mod.run, "_flags": {**flags, **getattr(mod, "OPTION_FLAGS", {})}})


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser: every verb of dgcal.commands (all loaded when `argv` is None, else the chosen one)."""
    global _ARGV
    _ARGV = None if argv is None else list(argv)
    parser = argparse.ArgumentParser(prog="dgcal", description="Calibrate UAV payloads for direct georeferencing.")
    parser.add_argument("--debug", action="store_true", help="show the full traceback on errors")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress lines on stderr (warnings and errors still); also DGCAL_QUIET=1")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    sub.required = True
    add_verbs(sub, "dgcal.commands", _ARGV)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `dgcal` console script; returns the exit status (0 done, 2 bad input or an untrusted
    result, 3 an internal error, 130 interrupted)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(argv).parse_args(argv)
    quiet = args.quiet or os.environ.get("DGCAL_QUIET", "") not in ("", "0")
    try:
        with (flags_in_errors(getattr(args, "_flags", {})), progress.configured(quiet=quiet or None, prefix=args.verb),
              progress.stage("working", announce=False)):
            with verb_output_lock(getattr(args, "out", None)):   # a second run into --out refused now
                return int(args._run(args) or 0)
    except InputError as exc:
        if args.debug:
            import traceback   # why: only on a failure
            traceback.print_exc()
        print(f"dgcal {args.verb}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"dgcal {args.verb}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # the last line of defence: a bug, never a traceback for the user
        if args.debug:
            import traceback   # why: only on a failure
            traceback.print_exc()
        print(f"dgcal {args.verb}: internal error: {type(exc).__name__}: {_one_line(exc)} ({_where(exc)}; "
              f"`dgcal --debug {args.verb} ...` shows the traceback)", file=sys.stderr)
        return INTERNAL_ERROR


INTERNAL_ERROR = 3   # exit status of an unexpected failure (bad input is 2)


def entry() -> None:
    """The `dgcal` console script and `python -m dgcal`: `main`, then the process ends without the interpreter's
    teardown (0.6 s after a campaign: unloading gtsam, numba's LLVM, pycolmap, matplotlib). Every output is
    written and closed by then (atomic writes), child processes have been joined, and the streams are flushed
    here; under a profiler or coverage the teardown runs (they write their results then). `main` itself returns
    normally, for callers in Python."""
    try:
        rc = main()
    except SystemExit as exc:                # argparse: --help, usage errors
        rc = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1   # as Python's own exit
        if exc.code is not None and not isinstance(exc.code, int):
            print(exc.code, file=sys.stderr)
    if sys.getprofile() is not None or sys.gettrace() is not None:
        sys.exit(rc)                         # a profiler or coverage writes its results at the teardown
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):        # a closed pipe (`dgcal ... | head`): nothing more to say
            pass
    os._exit(rc)


def _one_line(exc: BaseException, limit: int = 300) -> str:
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _where(exc: BaseException) -> str:
    """The innermost dgcal frame of the traceback (file:line), where the failure surfaced."""
    import traceback   # why: only on a failure
    tb = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in tb if "/dgcal/" in f.filename or any(f"/{p}/" in f.filename for p in
                                                              ("fields", "calib", "bundle", "pos", "reports", "sim"))]
    f = (ours or tb)[-1] if (ours or tb) else None
    return "unknown place" if f is None else f"{Path(f.filename).name}:{f.lineno}"


if __name__ == "__main__":
    entry()
