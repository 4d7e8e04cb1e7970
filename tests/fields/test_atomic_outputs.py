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
