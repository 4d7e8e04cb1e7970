"""Progress lines: a heartbeat while a stage runs (even inside compiled code), nested stages, quiet, forks."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time

import pytest

from dgcal.fields import progress

PY = sys.executable


def _run(code: str, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([PY, "-c", textwrap.dedent(code), *args], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "DGCAL_HEARTBEAT_S": "0.3", **(env or {})})


def test_heartbeat_while_python_lock_is_held():
    """A stage sitting in one long call that never gives Python's lock back still says it is alive."""
    out = _run("""
        import re
        from dgcal.fields import progress
        progress.configure(prefix="t")
        with progress.stage("busy", total=5) as st:
            st.update(2)
            re.match(r"(a+)+$", "a" * 27 + "b")   # catastrophic backtracking: seconds inside C, the lock held
        """)
    assert out.returncode == 0, out.stderr
    lines = out.stderr.splitlines()
    assert lines[0] == "[t] busy …"
    beats = [ln for ln in lines if ln.startswith("[t] busy 2/5 … ")]
    assert len(beats) >= 2, out.stderr          # several heartbeats while the regex ran
    assert lines[-1].startswith("[t] busy 2/5: done in ")


def test_nested_stage_counts_and_forks_end_cleanly():
    out = _run("""
        import time
        from dgcal.fields import progress
        from dgcal.fields.processes import fork_map
        progress.configure(prefix="t")
        with progress.stage("outer", announce=False):
            for _ in progress.track(range(4), "items"):
                time.sleep(0.25)
            print(sum(fork_map([lambda: 1, lambda: 2], jobs=2)))
            time.sleep(0.5)
        """)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "3"
    err = out.stderr
    assert "[t] items …" in err and "[t] items 4/4: done in" in err
    assert any(ln.startswith("[t] items ") and "/4 … " in ln for ln in err.splitlines())
    assert "[t] working" not in err and "outer:" not in err   # not announced: only its heartbeat
    assert any(ln.startswith("[t] outer … ") for ln in err.splitlines())


def test_failed_stage_says_stopped_and_ticker_ends():
    t0 = time.monotonic()
    out = _run("""
        from dgcal.fields import progress
        progress.configure(prefix="t")
        with progress.stage("doomed"):
            raise SystemExit(4)
        """)
    assert out.returncode == 4
    assert "[t] doomed: stopped after" in out.stderr
    assert time.monotonic() - t0 < 20


def test_quiet_prints_nothing(capfd):
    with progress.configured(quiet=True, prefix="t"):
        with progress.stage("silent", total=3) as st:
            st.update(3)
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize("quiet", [False, True])
def test_cli_quiet_flag(tmp_path, quiet):
    """`dgcal --quiet VERB` prints no progress; without it a long verb is never silent for long (heartbeat)."""
    code = """
        import sys, time
        from dgcal.cli import main
        import dgcal.commands.field as field
        real = field.run
        def slow(args):
            time.sleep(1.2)
            return real(args)
        field.run = slow
        sys.exit(main(sys.argv[1:]))
        """
    args = (["--quiet"] if quiet else []) + ["field", "--out", str(tmp_path / "f")]
    out = _run(code, *args)
    assert out.returncode == 0, out.stderr
    beats = [ln for ln in out.stderr.splitlines() if ln.startswith("[field] working … ")]
    assert (len(beats) == 0) if quiet else (len(beats) >= 2), out.stderr
