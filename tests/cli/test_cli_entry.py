"""The console script's entry ends the process without the interpreter's teardown: what was printed must still
arrive whole, and the exit status must be main's (or argparse's)."""
from __future__ import annotations

import subprocess
import sys


def _entry(argv: list[str], before: str = "") -> subprocess.CompletedProcess:
    code = f"import sys; sys.argv = {['dgcal', *argv]!r}\n{before}\nfrom dgcal.cli import entry\nentry()\n"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


def test_buffered_output_arrives_whole_and_help_exits_0():
    out = _entry(["--help"], before="print('x' * 200000, end='')")    # block-buffered: a pipe, not a terminal
    assert out.returncode == 0
    assert out.stdout.startswith("x" * 200000) and "usage: dgcal" in out.stdout


def test_exit_status_of_bad_usage_and_bad_input():
    assert _entry(["no-such-verb"]).returncode == 2                       # argparse's SystemExit(2)
    bad = _entry(["camera", "--field", "/no/such/field.csv", "--measurements", "/no/such/m.csv", "--out", "/tmp/x"])
    assert bad.returncode == 2 and "dgcal camera: error:" in bad.stderr


def test_a_profiler_still_gets_its_results(tmp_path):
    prof = tmp_path / "help.prof"
    out = subprocess.run([sys.executable, "-m", "cProfile", "-o", str(prof), "-m", "dgcal", "--help"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and prof.is_file() and prof.stat().st_size > 0
