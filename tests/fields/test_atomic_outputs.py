"""Output folders appear whole or not at all (dgcal.fields.io.atomic), also when the writer is killed."""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from dgcal.fields.io.atomic import MANIFEST, clean_stale, read_manifest, staged_dir

WRITER = """
import sys, time
from dgcal.fields.io.atomic import staged_dir
out, tag = sys.argv[1], sys.argv[2]
with staged_dir(out) as tmp:
    for i in range(12):
        (tmp / f"f{i:02d}.txt").write_text(tag)
        time.sleep(0.01)
"""


def _state(out):
    """'none', or the tag of a complete, consistent output folder; raises on a mixture."""
    if not out.exists():
        return "none"
    m = read_manifest(out)
    files = sorted(p.name for p in out.iterdir() if p.name != MANIFEST)
    assert m is not None and sorted(m["files"]) == files, files
    tags = {(out / f).read_text() for f in files}
    assert len(tags) == 1, tags
    return tags.pop()


def test_a_new_folder_has_its_manifest_and_a_failure_leaves_the_old_one(tmp_path):
    out = tmp_path / "out"
    with staged_dir(out) as d:
        (d / "a.csv").write_text("1")
        (d / "sub").mkdir()
        (d / "sub" / "b.csv").write_text("2")
    assert sorted(read_manifest(out)["files"]) == ["a.csv", "sub/b.csv"]
    with pytest.raises(RuntimeError):
        with staged_dir(out) as d:
            (d / "a.csv").write_text("new")
            raise RuntimeError("boom")
    assert (out / "a.csv").read_text() == "1"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]      # no staging left


def test_a_users_folder_is_merged_not_replaced(tmp_path):
    (tmp_path / "mine.txt").write_text("keep")
    with staged_dir(tmp_path) as d:
        (d / "eop.csv").write_text("x")
    assert (tmp_path / "mine.txt").read_text() == "keep" and (tmp_path / "eop.csv").exists()
    assert read_manifest(tmp_path)["files"] == ["eop.csv"]


def test_an_interrupted_swap_is_rolled_back(tmp_path):
    out = tmp_path / "out"
    with staged_dir(out) as d:
        (d / "a.csv").write_text("old")
    os.replace(out, tmp_path / ".out.old.abc")          # killed between the two renames
    (tmp_path / ".out.staging.def").mkdir()             # and a staging folder left behind
    clean_stale(out)
    assert (out / "a.csv").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_kill_9_never_leaves_a_mixed_folder(tmp_path):
    out = tmp_path / "out"
    rng = np.random.default_rng(0)
    seen = set()
    for k in range(16):
        p = subprocess.Popen([sys.executable, "-c", WRITER, str(out), f"run{k}"])
        if k < 15:               # killed at once (the first), or at a random moment, or after it finished
            time.sleep(0.0 if k == 0 else float(rng.uniform(0.0, 0.35)))
            p.send_signal(signal.SIGKILL)
        p.wait()                 # the last run ends by itself: however slow the host, one run finishes
        clean_stale(out)        # what the next run does first
        seen.add(_state(out))
        assert not [q for q in tmp_path.iterdir() if q.name.startswith(".")]
    assert "run15" in seen and len(seen) >= 2   # killed and finished runs: every state was consistent


HOLDER = """
import sys, time
from dgcal.fields.io.atomic import staged_dir
with staged_dir(sys.argv[1]) as tmp:
    (tmp / "a.txt").write_text("first")
    print("holding", flush=True)
    time.sleep(float(sys.argv[2]))
"""


def test_a_second_writer_of_one_folder_is_refused_and_the_first_finishes(tmp_path):
    """Two processes on one --out: the second is refused with a one-line error naming the folder and the first's
    process; the first's outputs arrive whole (issue 31: they used to delete each other's staging)."""
    from dgcal.fields.errors import InputError
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-c", HOLDER, str(out), "6"], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "holding"
        with pytest.raises(InputError) as exc:
            with staged_dir(out) as tmp:
                (tmp / "b.txt").write_text("second")
        msg = str(exc.value)
        assert str(out) in msg and "another dgcal run" in msg and str(p.pid) in msg and "\n" not in msg
    finally:
        assert p.wait(timeout=30) == 0
    assert (out / "a.txt").read_text() == "first" and not (out / "b.txt").exists()
    with staged_dir(out) as tmp:             # released: the next run goes through
        (tmp / "b.txt").write_text("second")
    assert (out / "b.txt").is_file() and not (out / "a.txt").exists()


def test_the_lock_is_reentrant_in_a_process_and_its_forks(tmp_path):
    from dgcal.fields.io.atomic import output_lock
    out = tmp_path / "campaign"
    with output_lock(out):
        with staged_dir(out, merge=True) as tmp:       # the campaign's report inside its own locked run
            (tmp / "report.json").write_text("{}")
        pid = os.fork()
        if pid == 0:                                   # a forked step writing for the campaign
            try:
                with staged_dir(out, merge=True) as tmp:
                    (tmp / "child.txt").write_text("x")
                os._exit(0)
            except BaseException:
                os._exit(1)
        assert os.waitpid(pid, 0)[1] == 0
    assert (out / "report.json").is_file() and (out / "child.txt").is_file()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_parent_is_a_one_line_input_error(tmp_path):
    from dgcal.fields.errors import InputError
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(InputError, match="cannot"):
            with staged_dir(ro / "out") as tmp:
                (tmp / "a.txt").write_text("x")
    finally:
        ro.chmod(0o755)


def test_out_that_is_a_file_and_a_full_disk_are_input_errors(tmp_path, monkeypatch):
    """`--out` naming a file, and the disk filling up while the outputs are written, end as one-line input errors
    naming the folder (exit 2), not as internal errors; nothing half-written stays."""
    import errno
    from dgcal.fields.errors import InputError
    f = tmp_path / "file.txt"
    f.write_text("mine")
    with pytest.raises(InputError, match="is a file"):
        with staged_dir(f):
            pass
    assert f.read_text() == "mine"
    out = tmp_path / "out"
    with pytest.raises(InputError) as exc:
        with staged_dir(out) as tmp:
            (tmp / "a.txt").write_text("x")
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp / "b.txt"))
    assert "No space left on device" in str(exc.value) and str(out) in str(exc.value)
    assert not out.exists() and not list(tmp_path.glob(".out.staging.*"))


def test_campaign_args_cannot_move_a_steps_outputs(tmp_path):
    from dgcal.fields.errors import InputError
    from dgcal.steps import Campaign
    c = Campaign.__new__(Campaign)
    c.cfg, c.file = {"mount": {"args": ["--no-reject", "--out", "/elsewhere"]}}, tmp_path / "campaign.toml"
    with pytest.raises(InputError, match="mount.args"):
        c.extra_args("mount")
    c.cfg = {"mount": {"args": ["--no-reject"]}}
    assert c.extra_args("mount") == ["--no-reject"]


def test_an_interrupted_merge_is_refused_by_the_readers(tmp_path, monkeypatch):
    """A user's folder gets new files one by one: killed midway it holds new files beside old ones, and every dgcal
    reader refuses its files until the step runs again (issue 31); a finished merge leaves no trace of that."""
    from dgcal.fields.errors import InputError
    from dgcal.fields.io.atomic import INCOMPLETE
    from dgcal.fields.io.text_files import read_text
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("the user's")
    with staged_dir(out) as tmp:
        (tmp / "camera.json").write_text("{}")
        (tmp / "poses.csv").write_text("old")
    assert not (out / INCOMPLETE).exists() and read_text(out / "poses.csv") == "old"
    real = os.replace
    calls = []

    def dies_after_one(src, dst):
        calls.append(dst)
        if len(calls) == 2:
            raise KeyboardInterrupt          # the kill, between two moves
        return real(src, dst)

    monkeypatch.setattr(os, "replace", dies_after_one)
    with pytest.raises(KeyboardInterrupt):
        with staged_dir(out) as tmp:
            (tmp / "camera.json").write_text('{"new": 1}')
            (tmp / "poses.csv").write_text("new")
    monkeypatch.setattr(os, "replace", real)
    assert (out / INCOMPLETE).exists()
    with pytest.raises(InputError, match="interrupted"):
        read_text(out / "poses.csv")
    with staged_dir(out) as tmp:                # the step run again: complete, readable
        (tmp / "camera.json").write_text('{"new": 2}')
        (tmp / "poses.csv").write_text("newer")
    assert read_text(out / "poses.csv") == "newer" and not (out / INCOMPLETE).exists()
