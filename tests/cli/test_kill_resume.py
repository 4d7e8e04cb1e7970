"""kill -9 during `dgcal run` and during single verbs (issue 16): every output folder is absent, the old
complete output set or the new complete one (its files exactly those of its manifest, with the manifest's
SHA-256, and by content one of the clean runs' sets), no staging folder, set-aside folder or partial file
survives the next run, and the resumed campaign gives the clean run's results to the last byte.

The default run kills a handful of times (seeded random delays); `-m killstress` runs the 100-kill
acceptance (40 during `dgcal run`, 15 each during `camera`, `triangulate`, `pos` and `mount`)."""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from dgcal.campaign import STATE, load_campaign, plan, run_campaign
from dgcal.fields.io.atomic import MANIFEST, read_manifest
from dgcal.sim.campaign import simulate_campaign

# a small campaign: 32 images at two heights, 200 tie points, 12 target-plate photos (a run takes ~10 s)
SIM = dict(seed=1, gnss_mode="lc", heights_agl=(300.0, 600.0), n_strips=2, n_tie=200, field_images=12)
VOLATILE = {"metashape.xml", "summary.json", "pos_summary.json"}   # hold dates or timings, differ run to run
LEFTOVER = re.compile(r"\.(staging|old)\.|\.part$")
REPORT_KEYS = ("camera", "mounting", "mounting_method", "check", "truth_comparison")


def _edit(text: str, camera_args: str | None = None, lever_z: str | None = None) -> str:
    """The simulated campaign file without iso (the slowest step), optionally changed so that every step's
    results change: camera parameters held (-> camera, triangulation, mounting, check), GNSS lever arm (-> pos)."""
    text = re.sub(r'compare = \[[^]]*\]', 'compare = ["traditional"]', text)
    if camera_args is not None:
        text = re.sub(r'(model = "fraser7"\n)', rf'\1args = {camera_args}\n', text, count=1)
    if lever_z is not None:
        text = re.sub(r"(lever_arm_gnss = \[[^,]+,[^,]+,)[^]]+\]", rf"\1 {lever_z}]", text, count=1)
    return text


@pytest.fixture(scope="module")
def camp(tmp_path_factory):
    """Data of a simulated campaign, campaign files A (old) and B (new: every step's results differ), and a
    clean uninterrupted run of B (the reference)."""
    root = tmp_path_factory.mktemp("killresume")
    data = root / "data"
    simulate_campaign(data, **SIM)
    text = (data / "campaign.toml").read_text()
    (data / "a.toml").write_text(_edit(text))
    b = _edit(text, camera_args='["--fix", "K3"]', lever_z="-0.37")
    assert b != _edit(text) and '"--fix"' in b and "-0.37]" in b
    (data / "b.toml").write_text(b)
    ref_b = root / "ref_b"
    with open(os.devnull, "w") as null:
        run_campaign(data / "b.toml", ref_b, log=null)
    return {"root": root, "data": data, "a": data / "a.toml", "b": data / "b.toml", "ref_b": ref_b}


# ------------------------------------------------------------------------------------------------ checks
def _files(folder: Path) -> dict[str, str]:
    """Every file of a folder but its manifest, relative path -> SHA-256."""
    from dgcal.fields.io.atomic import file_sha256
    return {p.relative_to(folder).as_posix(): file_sha256(p) for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != MANIFEST}


def _whole(folder: Path, only_listed: bool = False) -> dict[str, str] | None:
    """The files of an output folder when it is one complete output set per its manifest (exactly the listed
    files, with the listed SHA-256; `only_listed`: a folder holding more, e.g. the campaign folder), None when
    the folder is absent; AssertionError on anything else (a half-written or mixed folder)."""
    if not folder.exists():
        return None
    m = read_manifest(folder)
    assert m is not None, f"{folder}: no manifest (half-written)"
    files = _files(folder)
    if only_listed:
        files = {k: v for k, v in files.items() if k in m["entries"]}
    assert sorted(files) == sorted(m["files"]), f"{folder}: files {sorted(files)} != manifest {sorted(m['files'])}"
    bad = [f for f, e in m["entries"].items() if files.get(f) != e["sha256"]]
    assert not bad, f"{folder}: contents differ from the manifest: {bad}"
    return files


def _stable(files: dict[str, str]) -> dict[str, str]:
    return {k: v for k, v in files.items() if Path(k).name not in VOLATILE}


def _which(folder: Path, refs: dict[str, dict] | None) -> str:
    """'absent', or the name of the reference output set (old, new) the whole folder is; `refs` None: 'whole'."""
    got = _whole(folder)
    if got is None:
        return "absent"
    if refs is None:
        return "whole"
    for name, ref in refs.items():
        if _stable(got) == _stable(ref):
            return name
    raise AssertionError(f"{folder}: complete per its manifest but none of {sorted(refs)}: a mixed folder")


def _leftovers(root: Path) -> set[Path]:
    """Staging and set-aside folders and partial files under `root` and beside it."""
    near = list(root.parent.iterdir()) + (list(root.rglob("*")) if root.exists() else [])
    return {p for p in near if LEFTOVER.search(p.name)}


def _check_campaign(out: Path, dirs: list[Path], refs: dict[str, dict[str, dict]] | None, seen: dict) -> None:
    """After a kill: every step folder absent, old or new; the report pair whole unless being merged in;
    the state file readable."""
    for d in dirs:
        state = _which(d, None if refs is None else {k: v[d.name] for k, v in refs.items()})
        seen[state] = seen.get(state, 0) + 1
    if (out / MANIFEST).exists():
        _whole(out, only_listed=True)
    if (out / STATE).exists():
        json.loads((out / STATE).read_text())


# ------------------------------------------------------------------------------------------------ killing
def _dgcal(*argv) -> list[str]:
    return [sys.executable, "-m", "dgcal", *map(str, argv)]


def _kill(argv: list[str], delay: float, line: str | None = None, staging: Path | None = None) -> bool:
    """Run dgcal and SIGKILL it `delay` s after a stderr line starting with `line`, or after a staging folder
    of `staging` appeared, or after its start; True when it was killed, False when it finished first."""
    pattern = None if staging is None else f".{staging.name}.staging.*"
    stale = set() if staging is None else set(staging.parent.glob(pattern))   # a killed run's, not this one's
    p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    hit, done, tail = threading.Event(), threading.Event(), []

    def pump():
        for ln in p.stderr:
            tail.append(ln)
            if line is not None and ln.startswith(line):
                hit.set()
        done.set()
    threading.Thread(target=pump, daemon=True).start()
    t_end = time.monotonic() + 300
    while not done.is_set() and time.monotonic() < t_end:
        if line is None and staging is None:
            break
        if hit.is_set() or (staging is not None and set(staging.parent.glob(pattern)) - stale):
            break
        time.sleep(0.002)
    time.sleep(delay)
    killed = p.poll() is None
    if killed:
        os.kill(p.pid, signal.SIGKILL)
    rc = p.wait()
    done.wait(10)
    assert killed or rc == 0, f"{' '.join(argv[2:4])} failed (exit {rc}): {''.join(tail[-5:])}"
    return killed


def _campaign_kills(camp, out: Path, toml: Path, n: int, rng, refs, seen) -> int:
    """`n` runs of `dgcal run toml --out out`, each killed at a random moment of a random step (after its
    start line, or while its staging folder is written); every kill followed by the checks. Returns kills."""
    steps = plan(load_campaign(toml), out)
    dirs = sorted({s.out_dir for s in steps})
    kills, before, since = 0, set(), time.time()
    for _ in range(n):
        done = json.loads((out / STATE).read_text())["steps"] if (out / STATE).exists() else {}
        # a step this campaign finished is skipped: no kill in it (records before `since`: the old campaign's)
        todo = [s for s in steps if done.get(s.name, {}).get("finished_unix", 0) < since]
        if not todo:
            break
        step = todo[int(rng.integers(min(2, len(todo))))]
        if rng.random() < 0.5:
            killed = _kill(_dgcal("run", toml, "--out", out), float(rng.uniform(0, 2.0)), line=f"[{step.name}] (")
        else:
            killed = _kill(_dgcal("run", toml, "--out", out), float(rng.uniform(0, 0.4)), staging=step.out_dir)
        kills += killed
        _check_campaign(out, dirs, refs, seen)
        now = _leftovers(out)
        if killed:   # the run got past its start, which cleans what the kill before left
            assert not (before & now), f"not cleaned up by the next run: {sorted(map(str, before & now))}"
        seen["leftovers"] = seen.get("leftovers", 0) + bool(now)
        before = now
    return kills


def _finish_campaign(camp, out: Path, toml: Path) -> None:
    r = subprocess.run(_dgcal("run", toml, "--out", out), capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    assert not _leftovers(out), sorted(map(str, _leftovers(out)))


def _assert_same_results(out: Path, ref: Path, dirs: list[Path]) -> None:
    """The resumed campaign's outputs are the clean run's: every file of every step folder (but the ones
    holding timings), and the numbers of report.json."""
    for d in dirs:
        got, want = _whole(d), _whole(ref / d.name)
        assert _stable(got) == _stable(want), f"{d.name}: {set(_stable(got).items()) ^ set(_stable(want).items())}"
    for name in ("mount_proposed/mounting.json", "triangulation/eop.csv", "pos/trajectory.csv", "check/check.json"):
        assert (out / name).read_bytes() == (ref / name).read_bytes(), name
    a, b = (json.loads((p / "report.json").read_text()) for p in (out, ref))
    for k in REPORT_KEYS:
        assert a.get(k) == b.get(k), k


def _verb_kills(argv: list[str], out: Path, old: Path, new_ref: Path, n: int, rng, seen: dict,
                timed: float = 0.0) -> int:
    """Runs of one verb writing `out` (holding `old`, a complete earlier output) until `n` were killed: while
    it writes its staging folder or (a share `timed` of the runs) at a random moment from its start; when a
    run left the new folder, the old one is put back for the next. Returns the kills."""
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(old, out)
    refs = {"old": _files(old), "new": _files(new_ref)}
    kills, before = 0, set()
    for _ in range(3 * n):
        if kills == n:
            break
        if rng.random() < timed:
            killed = _kill(argv, float(rng.uniform(0, 6.0)))
            reached = False
        else:
            killed = _kill(argv, float(rng.uniform(0, 0.3)), staging=out)
            reached = True     # the verb reached staged_dir, which first cleans what the kill before left
        kills += killed
        state = _which(out, refs)
        seen[state] = seen.get(state, 0) + 1
        now = _leftovers(out)
        if reached and killed:
            assert not (before & now), f"not cleaned up by the next run: {sorted(map(str, before & now))}"
        before = now
        if state == "new":
            shutil.rmtree(out)
            shutil.copytree(old, out)
    r = subprocess.run(argv, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    assert _which(out, refs) == "new" and not _leftovers(out)
    return kills


def _argv_into(step, out: Path) -> list[str]:
    a = list(step.argv)
    a[a.index("--out") + 1] = str(out)
    return _dgcal(*a)


# ------------------------------------------------------------------------------------------------ tests
def _campaign_phase(camp, out: Path, toml: Path, ref: Path, n: int, rng, seen: dict) -> int:
    """Up to `n` kills while campaign `toml` runs into `out` (empty, or holding another campaign's complete
    outputs: the old folders), then the campaign finished and compared with its clean run `ref`."""
    dirs = sorted({s.out_dir for s in plan(load_campaign(toml), out)})
    refs = {"new": {d.name: _files(ref / d.name) for d in dirs}}
    if all(d.exists() for d in dirs):
        refs["old"] = {d.name: _files(d) for d in dirs}
        assert all(_stable(refs["old"][d.name]) != _stable(refs["new"][d.name]) for d in dirs)  # every step changes
    kills = _campaign_kills(camp, out, toml, n, rng, refs, seen)
    _finish_campaign(camp, out, toml)
    _assert_same_results(out, ref, dirs)
    return kills


def test_killed_campaign_resumes_to_the_clean_result(camp):
    """Kills while the edited campaign B runs over campaign A's outputs: never a half or mixed folder,
    leftovers cleaned by the next run, B resumed gives B's clean results."""
    out = camp["root"] / "runs" / "out"
    out.parent.mkdir()
    with open(os.devnull, "w") as null:
        run_campaign(camp["a"], out, log=null)
    seen: dict = {}
    kills = _campaign_phase(camp, out, camp["b"], camp["ref_b"], 3, np.random.default_rng(16), seen)
    print(f"\n{kills} kills of dgcal run; folder states after them: {seen}")
    assert kills >= 2 and seen.get("old") and seen.get("new")


def test_killed_mount_leaves_the_old_or_the_new_folder(camp):
    """kill -9 while `dgcal mount` writes over an earlier mounting folder: the old set or the new one."""
    rng = np.random.default_rng(61)
    steps = {s.name: s for s in plan(load_campaign(camp["b"]), camp["ref_b"])}
    out = camp["root"] / "verbs" / "mount"
    out.parent.mkdir()
    seen: dict = {}
    kills = _verb_kills(_argv_into(steps["mount_proposed"], out), out, camp["ref_b"] / "mount_traditional",
                        camp["ref_b"] / "mount_proposed", 3, rng, seen)
    print(f"\n{kills} kills of dgcal mount; folder states after them: {seen}")
    assert kills >= 1


TOML = """crs = "EPSG:32651"
[camera]
field = "field.csv"
measurements = "field_meas.csv"
image_size = [6000, 4000]
[triangulation]
gcp = "gcp.csv"
measurements = "meas.csv"
[pos]
mode = "lc"
imu = "imu.txt"
events = "events.csv"
gnss = "gnss.csv"
[mount]
method = "joint"
compare = ["two-step"]
[check]
measurements = "meas.csv"
"""


def _fake_verb(calls: list):
    """A stand-in for the verbs: writes the files every step must leave through staged_dir, as the verbs do."""
    from dgcal.fields.io.atomic import staged_dir

    def runner(argv):
        calls.append(argv[0] if argv[0] != "mount" else f"mount_{argv[argv.index('--method') + 1]}")
        with staged_dir(argv[argv.index("--out") + 1]) as d:
            for name in ("camera.json", "eop.csv", "trajectory.csv", "events.csv", "mounting.json", "check.json"):
                (d / name).write_text(" ".join(argv))
        return 0
    return runner


def test_resume_skips_only_whole_recorded_steps(tmp_path):
    """What a resumed run skips: a step recorded as finished whose folder is still the whole one it wrote.
    A deleted output, a folder replaced behind its back, --rerun (a step or a verb) and an edited input rerun
    the steps concerned and the ones after them; staging left by a kill is removed first and a folder set
    aside by a kill between the two renames of its swap is put back before anything is decided."""
    from dgcal.fields.errors import InputError
    from dgcal.fields.io.atomic import staged_dir
    for name in ("field.csv", "field_meas.csv", "gcp.csv", "meas.csv", "imu.txt", "events.csv", "gnss.csv"):
        (tmp_path / name).write_text(f"{name}\n")
    toml, out, calls = tmp_path / "c.toml", tmp_path / "out", []
    toml.write_text(TOML)
    log = open(os.devnull, "w")

    def ran(**kw):
        calls.clear()
        res = run_campaign(toml, out, runner=_fake_verb(calls), log=log, report=False, **kw)
        assert calls == [k for k, v in res["steps"].items() if v == "ran"]
        return calls
    everything = ["camera", "triangulate", "pos", "mount_joint", "mount_two-step", "check"]
    assert ran() == everything
    assert ran() == []
    (out / "check" / "check.json").unlink()                    # an output lost
    assert ran() == ["check"]
    (out / "pos" / "notes.txt").write_text("mine")             # a file added: the folder is still complete
    assert ran() == []
    with staged_dir(out / "mount_joint") as d:                 # the folder replaced by another run of the verb
        (d / "mounting.json").write_text("other")
    assert ran() == ["mount_joint", "check"]
    (out / "triangulation" / "eop.csv").write_text("edited")   # an output edited (another size)
    assert ran() == ["triangulate", "mount_joint", "mount_two-step", "check"]
    assert ran(rerun=["mount"]) == ["mount_joint", "mount_two-step", "check"]
    assert ran(rerun=["pos"]) == ["pos", "mount_joint", "mount_two-step", "check"]
    (tmp_path / "gnss.csv").write_text("gnss.csv\nedited\n")  # an input edited
    assert ran() == ["pos", "mount_joint", "mount_two-step", "check"]
    assert ran(force=True) == everything
    with pytest.raises(InputError, match="--rerun nope: no such step"):
        ran(rerun=["nope"])
    # what kills leave: a staging folder, a partial state file, a folder set aside mid-swap
    (out / ".camera.staging.abc123").mkdir()
    (out / ".dgcal-state.json.k2j4h5g6.part").write_text("{")
    (out / "triangulation").rename(out / ".triangulation.old.xyz789")
    assert ran() == []
    assert not [p for p in out.rglob("*") if LEFTOVER.search(p.name)]
    assert (out / "triangulation" / "eop.csv").is_file()


@pytest.mark.killstress
def test_100_kills(camp):
    """Issue 16's acceptance: 100 random kill -9s during run, camera, triangulate, pos and mount."""
    rng = np.random.default_rng(100)
    root = camp["root"] / "stress"
    out = root / "campaign" / "out"
    out.parent.mkdir(parents=True)
    ref_a = root / "ref_a"     # A's complete outputs: the old folders of the single verbs
    with open(os.devnull, "w") as null:
        run_campaign(camp["a"], ref_a, log=null)
    seen: dict = {}
    kills, phase = 0, 0
    while kills < 40 and phase < 12:       # A into an empty folder, then B over A, A over B, ...
        toml, ref = (camp["a"], ref_a) if phase % 2 == 0 else (camp["b"], camp["ref_b"])
        kills += _campaign_phase(camp, out, toml, ref, min(10, 40 - kills), rng, seen)
        phase += 1
    assert kills == 40
    steps = {s.name: s for s in plan(load_campaign(camp["b"]), camp["ref_b"])}
    for name, folder in (("camera", "camera"), ("triangulate", "triangulation"), ("pos", "pos"),
                         ("mount_proposed", "mount_proposed")):
        o = root / "verbs" / folder
        o.parent.mkdir(parents=True, exist_ok=True)
        kills += _verb_kills(_argv_into(steps[name], o), o, ref_a / folder, camp["ref_b"] / folder, 15, rng, seen,
                             timed=0.4)
    print(f"\n{kills} kills; folder states after them: {seen}")
    assert kills == 100
