"""kill -9 of every writing verb into a user's folder, and two runs into one folder (issue 31).

The output folder holds a complete earlier output of the verb (every file changed, with its manifest) and a file of
the user's, so the verb merges its outputs in (the path where a kill could leave a mixture). After each kill the
folder is one of: the old set (its manifest and files unchanged), the new set (the new manifest, every listed file
the new one), or marked incomplete - and then dgcal's readers refuse its files; never a mixture without the mark.
The user's file survives every kill, and a last clean run leaves the new set and no mark. Kills come at a random
moment from the start, while the staging folder is written, or just after the merge began.

A second run into a folder a first run is writing (the first paused while it holds the folder) is refused at once
with one line naming the folder and the first run's process; the first then finishes whole.

The default run kills `field` three times and checks the second-run refusal for it; `-m killstress` runs 30 kills
of each of the twelve writing verbs and the refusal for every one of them (DGCAL_KILL_STATS=FILE: a JSON line of
the states seen per verb).
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.io.atomic import INCOMPLETE, MANIFEST, file_sha256, lock_path, read_manifest
from dgcal.fields.io.text_files import read_text

from test_fuzz_cli import VERBS, _argv, data  # noqa: F401  (data: the verbs' small valid data set, a fixture)

KILLS = int(os.environ.get("DGCAL_KILLS", 30))   # per verb under -m killstress
FOREIGN = "my_notes.txt"           # the user's own file in the output folder
FOREIGN_TEXT = "the user's notes: keep me\n"
# the writing verbs (issue 31): the argv templates of test_fuzz_cli, and flow and simulate on their own data
KILL_VERBS = {
    "camera": VERBS["camera"][0], "triangulate": VERBS["triangulate"][0] + " --accept-poor",
    "pos": "pos --mode spp --rinex-obs {gnss_sim}/sim.obs --rinex-nav {gnss_sim}/nav.rnx --no-progress --out {out}",
    "mount": VERBS["mount"][0], "check": VERBS["check"][0], "export": VERBS["export"][0], "sync": VERBS["sync"][0],
    "georef": VERBS["georef"][0], "field": VERBS["field"][0], "run": VERBS["run"][0],
    "flow": "flow --images {fc}/frames --gnss {fc}/gnss_velocity.csv --camera {fc}/camera.json --no-progress "
            "--out {out}",
    "simulate": "simulate imu --duration 60 --rate 50 --strips 1 --out {out}",
}


@pytest.fixture(scope="module")
def fc(tmp_path_factory) -> Path:
    """A short forward-camera flight for `flow`."""
    d = tmp_path_factory.mktemp("kill_fc")
    r = subprocess.run(_dgcal("simulate", "forward-camera", "--duration", "40", "--fps", "2", "--seed", "1",
                              "--out", d / "fc"), capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    return d / "fc"


@pytest.fixture(scope="module")
def gnss_sim(tmp_path_factory) -> Path:
    """Five minutes of simulated GNSS observations (RINEX) for `pos --mode spp`."""
    d = tmp_path_factory.mktemp("kill_gnss") / "gnss"
    r = subprocess.run(_dgcal("simulate", "gnss", "--out", d), capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    return d


def _files(verb: str, request) -> dict[str, Path]:
    """The verbs' input files (test_fuzz_cli's data set; simulated flights for flow and pos)."""
    extra = {"flow": "fc", "pos": "gnss_sim"}.get(verb)
    return {**request.getfixturevalue("data"), **({extra: request.getfixturevalue(extra)} if extra else {})}


def _dgcal(*argv) -> list[str]:
    return [sys.executable, "-m", "dgcal", *map(str, argv)]


def _verb_argv(verb: str, files: dict, out: Path) -> list[str]:
    return _dgcal(*_argv(KILL_VERBS[verb], files, out))


# ------------------------------------------------------------------------------------------------ folder states
def _listed(folder: Path) -> dict[str, str]:
    """The folder's files listed by its manifest -> SHA-256 (AssertionError when one is missing or differs)."""
    m = read_manifest(folder)
    assert m is not None, f"{folder}: no manifest and no incomplete mark: a mixed or half-written folder"
    got = {}
    for f, e in m["entries"].items():
        p = folder / f
        assert p.is_file(), f"{p}: listed in the manifest but missing (and no incomplete mark)"
        got[f] = file_sha256(p)
        assert got[f] == e["sha256"], f"{p}: not the file its manifest lists (and no incomplete mark)"
    return got


def _manifest_sets(folder: Path) -> dict[str, dict[str, str]]:
    """Each output set under `folder` (the folder itself and, for a campaign, its steps' folders): relative folder ->
    {file listed by its manifest -> SHA-256}."""
    return {m.parent.relative_to(folder).as_posix(): {f: e["sha256"] for f, e in
                                                      read_manifest(m.parent)["entries"].items()}
            for m in sorted(folder.rglob(MANIFEST))}


def _state(out: Path, old: dict, new: dict) -> str:
    """The state of each output set of `out`: 'old', 'new', 'absent' or 'incomplete' (checked: dgcal's readers
    refuse its files), joined by '+' when they differ (a campaign's steps); AssertionError on anything else."""
    assert (out / FOREIGN).read_text() == FOREIGN_TEXT, "the user's file was changed or lost"
    states = []
    for rel in sorted(new):
        d = out / rel
        if (d / INCOMPLETE).exists():
            files = [p for p in sorted(d.iterdir()) if p.is_file() and p.name not in (FOREIGN, INCOMPLETE)]
            for p in files[:5]:
                with pytest.raises(InputError, match="interrupted"):
                    read_text(p)
            states.append("incomplete")
        elif not d.exists():
            states.append("absent")
        else:
            listed, was = _listed(d), old.get(rel, {})
            if listed == was:
                states.append("old")
                continue
            # the new set: its files, none of them the earlier one (which all differ from any run's: a PDF's or a
            # summary's timestamp may make the new ones differ from the reference run's)
            kept = sorted(f for f, h in listed.items() if was.get(f) == h)
            assert sorted(listed) == sorted(new[rel]) and not kept, \
                f"{d}: complete per its manifest but neither the old set nor the new one (earlier files {kept})"
            states.append("new")
    return "+".join(sorted(set(states)))


def _changed_copy(src: Path, dst: Path) -> dict[str, dict[str, str]]:
    """`dst`: the output folder `src` with every file its manifests list changed (and the manifests rewritten for
    them), and the user's file; returns the changed sets (`_manifest_sets`)."""
    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(src, dst)
    for rel, listed in _manifest_sets(src).items():
        d = dst / rel
        entries = {}
        for f in listed:
            p = d / f
            p.write_bytes(p.read_bytes() + b"\n# an earlier run\n")
            entries[f] = {"size": p.stat().st_size, "sha256": file_sha256(p)}
        (d / MANIFEST).write_text(json.dumps({"files": sorted(entries), "entries": entries, "written_unix": 0.0}))
    (dst / FOREIGN).write_text(FOREIGN_TEXT)
    return _manifest_sets(dst)


# ------------------------------------------------------------------------------------------------ killing
def _kill_once(argv: list[str], out: Path, mode: str, delay: float, limit_s: float = 300.0) -> bool:
    """Run `argv` and SIGKILL it `delay` s after: its start ('start'), a staging folder beside `out` appearing
    ('staging') or the incomplete mark in `out` appearing ('merge'). True when killed, False when it finished."""
    stale = set(out.parent.glob(f".{out.name}.staging.*"))
    p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    end = time.monotonic() + limit_s
    while mode != "start" and p.poll() is None and time.monotonic() < end:
        if mode == "staging" and set(out.parent.glob(f".{out.name}.staging.*")) - stale:
            break
        if mode == "merge" and (out / INCOMPLETE).exists():
            break
        time.sleep(0.001)
    time.sleep(delay)
    killed = p.poll() is None
    if killed:
        os.kill(p.pid, signal.SIGKILL)
    err = p.communicate()[1]
    assert killed or p.returncode == 0, f"{' '.join(map(str, argv[2:4]))} failed (exit {p.returncode}): {err[-800:]}"
    return killed


def verb_kills(verb: str, files: dict, root: Path, n: int, rng) -> dict:
    """`n` kills of `verb` writing into a folder holding its earlier (changed) outputs and the user's file; the
    folder's state checked after each; then a clean run. Returns the counts of the states seen."""
    ref = root / f"{verb}_ref"
    shutil.rmtree(ref, ignore_errors=True)
    t0 = time.monotonic()
    r = subprocess.run(_verb_argv(verb, files, ref), capture_output=True, text=True)
    run_s = time.monotonic() - t0
    assert r.returncode == 0, r.stderr[-2000:]
    new = _manifest_sets(ref)
    assert "." in new and all(new.values())
    out = root / f"{verb}_out"
    old = _changed_copy(ref, out)
    argv = _verb_argv(verb, files, out)
    seen = {"kills": 0, "runs": 0}
    while seen["kills"] < n and seen["runs"] < 4 * n:
        mode = ("start", "staging", "merge")[seen["runs"] % 3]
        if mode == "merge" and (out / INCOMPLETE).exists() and verb != "run":
            old = _changed_copy(ref, out)   # a kill's mark gone, so the kill lands in this run's merge
        delay = {"start": rng.uniform(0.3, max(run_s, 0.6)), "staging": rng.uniform(0, 0.3),
                 "merge": rng.uniform(0, 0.01)}[mode]
        killed = _kill_once(argv, out, mode, float(delay))
        seen["runs"] += 1
        seen["kills"] += killed
        state = _state(out, old, new)
        seen[state] = seen.get(state, 0) + 1
        # back to the earlier outputs for the next kill (after an interrupted merge, every other time: the next run
        # then starts from the mark, or from the old folder)
        if verb != "run" and (state == "new" or (state == "incomplete" and rng.random() < 0.5)):
            old = _changed_copy(ref, out)
    r = subprocess.run(argv, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    assert _state(out, old, new) == "new"
    return seen


def second_run_refused(verb: str, files: dict, root: Path) -> str:
    """A run of `verb` into a folder a first run holds (paused with SIGSTOP once it holds it): refused, exit 2, one
    line naming the folder and the first run's process; the first, resumed, finishes with the folder whole."""
    out = root / f"{verb}_twice"
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    (out / FOREIGN).write_text(FOREIGN_TEXT)
    argv = _verb_argv(verb, files, out)
    first = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    key = lock_path(out)
    try:
        end = time.monotonic() + 120
        while time.monotonic() < end and first.poll() is None:
            if key.is_file() and key.read_text().strip() == str(first.pid):
                break
            time.sleep(0.005)
        assert first.poll() is None, f"the first run ended before it held the folder: {first.stderr.read()[-800:]}"
        os.kill(first.pid, signal.SIGSTOP)
        second = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    finally:
        os.kill(first.pid, signal.SIGCONT)
    assert second.returncode == 2, second.stderr[-2000:]
    lines = [ln for ln in second.stderr.splitlines() if ln.strip()]
    msg = lines[-1]
    assert msg.startswith(f"dgcal {argv[3]}: error: ") and str(out) in msg, msg
    assert f"another dgcal run (process {first.pid}) is writing into this folder" in msg, msg
    assert first.wait(300) == 0, first.stderr.read()[-2000:]
    assert read_manifest(out) is not None and not (out / INCOMPLETE).exists()
    _listed(out)
    assert (out / FOREIGN).read_text() == FOREIGN_TEXT
    return msg


# ------------------------------------------------------------------------------------------------ tests
def test_kills_into_a_users_folder_never_leave_a_mixture(request, tmp_path):
    seen = verb_kills("field", _files("field", request), tmp_path, 3, np.random.default_rng(31))
    assert seen["kills"] == 3 and seen.get("incomplete", 0) + seen.get("old", 0) + seen.get("new", 0) >= 3


def test_a_second_run_into_a_folder_is_refused(request, tmp_path):
    msg = second_run_refused("field", _files("field", request), tmp_path)
    assert msg.endswith("wait for it to end or give another output folder")


@pytest.mark.killstress
@pytest.mark.parametrize("verb", sorted(KILL_VERBS))
def test_30_kills_of_each_writing_verb(verb, request, tmp_path):
    """Issue 31's acceptance: 30 kill -9s of each writing verb with a user's file in --out, and the second run
    refused."""
    files = _files(verb, request)
    seen = verb_kills(verb, files, tmp_path, KILLS, np.random.default_rng(sum(map(ord, verb))))
    msg = second_run_refused(verb, files, tmp_path)
    print(f"\n{verb}: {seen}; second run: {msg}")
    out = os.environ.get("DGCAL_KILL_STATS")
    if out:
        with open(out, "a") as fh:
            fh.write(json.dumps({"verb": verb, **seen}) + "\n")
    assert seen["kills"] == KILLS
