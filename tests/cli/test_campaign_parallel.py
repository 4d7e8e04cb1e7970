"""`dgcal run --jobs N`: independent steps side by side in child processes — never before a step they follow,
failures reported after the steps beside them end (whose results are kept), crashes and killed children
named, and the children die with a killed parent."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from dgcal.campaign import STATE, load_state, run_campaign
from dgcal.fields.errors import InputError
from dgcal.fields.io.atomic import staged_dir
from dgcal.fields.processes import fork_map

from test_campaign_runner import _campaign

NULL = open(os.devnull, "w")


def _verb(trace: Path, seconds: dict[str, float], fail: dict[str, object] | None = None):
    """A stand-in for the dgcal verbs: appends `name start end` to `trace`, sleeps, writes its outputs."""
    fail = fail or {}

    def runner(argv: list[str]) -> int:
        out = Path(argv[argv.index("--out") + 1])
        name = {"triangulation": "triangulate"}.get(out.name, out.name)   # the step's name
        t0 = time.time()
        time.sleep(seconds.get(name, 0.05))
        what = fail.get(name)
        if what == "crash":
            raise ZeroDivisionError("boom")
        if what == "kill":
            os.kill(os.getpid(), signal.SIGKILL)
        if what is not None:
            return int(what)
        assert fork_map([lambda: 1, lambda: 2], jobs=2) == [1, 2]   # a step may fork in turn (its figures)
        with staged_dir(out) as d:   # as the verbs write: a folder with its manifest
            for f in ("camera.json", "eop.csv", "trajectory.csv", "events.csv", "mounting.json", "check.json",
                      "pos_summary.json", "summary.json"):
                (d / f).write_text("x")
        with open(trace, "a") as fh:
            fh.write(f"{name} {t0} {time.time()} {os.nice(0)}\n")
        return 0
    return runner


def _spans(trace: Path) -> dict[str, tuple[float, float]]:
    rows = [ln.split() for ln in trace.read_text().splitlines()]
    return {r[0]: (float(r[1]), float(r[2])) for r in rows}


def _niceness(trace: Path) -> dict[str, int]:
    return {r[0]: int(r[3]) for r in (ln.split() for ln in trace.read_text().splitlines())}


def test_steps_run_side_by_side_after_the_steps_they_follow(tmp_path):
    c = _campaign(tmp_path)
    trace, out = tmp_path / "trace.txt", tmp_path / "out"
    res = run_campaign(c, out, runner=_verb(trace, {"camera": 1.0, "pos": 1.2}), log=NULL, report=False, jobs=2)
    assert list(res["steps"]) == ["camera", "triangulate", "pos", "mount_proposed", "mount_traditional",
                                  "mount_iso", "check"]
    assert set(res["steps"].values()) == {"ran"}
    s = _spans(trace)
    assert s["pos"][0] < s["camera"][1]                       # POS beside the camera
    assert s["triangulate"][0] >= s["camera"][1]             # never before a step it follows
    for m in ("mount_proposed", "mount_traditional", "mount_iso"):
        assert s[m][0] >= max(s["triangulate"][1], s["pos"][1], s["camera"][1])
    assert s["check"][0] >= max(s[m][1] for m in ("mount_proposed", "mount_traditional", "mount_iso"))
    # the heaviest ready steps first (two slots): the lightest waits for one of them to end (a comparison of start
    # times would race the start of the children)
    assert s["mount_traditional"][0] >= min(s["mount_iso"][1], s["mount_proposed"][1])
    nice = _niceness(trace)
    assert nice["pos"] == nice["mount_iso"] == os.nice(0)     # the heaviest run at the runner's priority,
    assert nice["camera"] > nice["pos"] and nice["mount_proposed"] > nice["mount_iso"]   # lighter ones beside yield
    assert nice["check"] == os.nice(0)                        # nothing heavier left
    assert sorted(load_state(out / STATE)) == sorted(res["steps"])
    again = run_campaign(c, out, runner=_verb(trace, {}), log=NULL, report=False, jobs=2)
    assert set(again["steps"].values()) == {"skipped"}


def test_a_failure_waits_for_the_steps_beside_it_and_keeps_them(tmp_path):
    c = _campaign(tmp_path)
    trace, out = tmp_path / "trace.txt", tmp_path / "out"
    slow_pos_fails = _verb(trace, {"camera": 0.05, "triangulate": 0.05, "pos": 1.0}, fail={"pos": 2})
    with pytest.raises(InputError, match="step pos failed"):
        run_campaign(c, out, runner=slow_pos_fails, log=NULL, report=False, jobs=2)
    assert sorted(load_state(out / STATE)) == ["camera", "triangulate"]
    trace.unlink()
    res = run_campaign(c, out, runner=_verb(trace, {}), log=NULL, report=False, jobs=2)
    assert res["steps"]["camera"] == res["steps"]["triangulate"] == "skipped"
    assert sorted(_spans(trace)) == ["check", "mount_iso", "mount_proposed", "mount_traditional", "pos"]


def test_a_slow_failure_beside_a_longer_step_lets_it_finish(tmp_path):
    c = _campaign(tmp_path)
    trace, out = tmp_path / "trace.txt", tmp_path / "out"
    with pytest.raises(InputError, match="step camera failed"):
        run_campaign(c, out, runner=_verb(trace, {"camera": 0.1, "pos": 0.8}, fail={"camera": 2}), log=NULL,
                     report=False, jobs=2)
    assert sorted(load_state(out / STATE)) == ["pos"]         # finished beside the failure: kept
    assert "triangulate" not in _spans(trace)                 # nothing new started after the failure


@pytest.mark.parametrize("how, message", [("crash", r"step pos crashed \(ZeroDivisionError: boom\)"),
                                          ("kill", r"step pos crashed .*killed by signal 9")])
def test_crashed_and_killed_children_are_named(tmp_path, how, message):
    c = _campaign(tmp_path)
    with pytest.raises(InputError, match=message):
        run_campaign(c, tmp_path / "out", runner=_verb(tmp_path / "t.txt", {}, fail={"pos": how}), log=NULL,
                     report=False, jobs=2)


def _alive(pid: int) -> bool:
    """The process exists and is not a zombie waiting to be reaped."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in status


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_children_die_with_a_killed_parent(tmp_path):
    c = _campaign(tmp_path)
    pids = tmp_path / "pids"
    pids.mkdir()
    script = textwrap.dedent(f"""
        import os, time
        from pathlib import Path
        from dgcal.campaign import run_campaign
        def runner(argv):
            Path({str(pids)!r}, str(os.getpid())).write_text(argv[0])
            time.sleep(60)
            return 0
        run_campaign(Path({str(c)!r}), Path({str(tmp_path / 'out')!r}), runner=runner, report=False, jobs=2)
    """)
    parent = subprocess.Popen([sys.executable, "-c", script], stderr=subprocess.DEVNULL)
    deadline = time.time() + 60
    while len(list(pids.iterdir())) < 2 and time.time() < deadline:   # camera and pos started
        time.sleep(0.05)
    children = [int(p.name) for p in pids.iterdir()]
    assert sorted(p.read_text() for p in pids.iterdir()) == ["camera", "pos"]
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    deadline = time.time() + 10
    while any(_alive(p) for p in children) and time.time() < deadline:
        time.sleep(0.05)
    assert not any(_alive(p) for p in children)
    state = tmp_path / "out" / STATE
    assert not state.exists() or json.loads(state.read_text())["steps"] == {}


def test_the_runners_preload_starts_no_thread_and_imports_no_opencv():
    """What the runner loads before it forks must be fork-safe: no thread of its own (a forked child has none of
    its parent's threads, and a pool expecting them hangs) and no OpenCV, which starts one on import."""
    script = ("import os, sys\n"
              "import numpy, scipy.linalg\n"     # BLAS's own pool, which handles fork, before the count
              "n = len(os.listdir('/proc/self/task'))\n"
              "from dgcal.campaign import preload_for_steps\n"
              "preload_for_steps()\n"
              "print(len(os.listdir('/proc/self/task')) - n, 'cv2' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["0", "False"]
