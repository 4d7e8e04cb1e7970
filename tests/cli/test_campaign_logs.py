"""A campaign step's own output goes to its log file (the libraries' lines too); the campaign shows its warnings
and, when it fails, its error line and the log's path."""
from __future__ import annotations

import io
import os
import sys

import pytest
from test_campaign_runner import _campaign

from dgcal.campaign import run_campaign
from dgcal.fields.errors import InputError
from dgcal.fields.io.atomic import staged_dir


def _runner(fail: str | None = None):
    def runner(argv):
        print(f"dgcal {argv[0]}: warning: something {argv[0]} noticed", file=sys.stderr)
        os.write(2, b"a compiled library writes here\n")   # below Python's streams, as COLMAP or gtsam do
        if argv[0] == fail:
            print(f"dgcal {argv[0]}: error: bad.csv, line 3, field x: not a number", file=sys.stderr)
            return 2
        with staged_dir(argv[argv.index("--out") + 1]) as d:
            for name in ("camera.json", "eop.csv"):
                (d / name).write_text("x")
        return 0
    return runner


@pytest.mark.parametrize("jobs", [1, 2])
def test_step_output_in_its_log_and_warnings_shown(tmp_path, jobs):
    out, log = tmp_path / "out", io.StringIO()
    with pytest.raises(InputError, match="step pos failed"):   # camera and triangulate run before it
        run_campaign(_campaign(tmp_path), out, runner=_runner(fail="pos"), report=False, log=log, jobs=jobs)
    text = (out / "logs" / "camera.log").read_text()
    assert "a compiled library writes here" in text and "warning: something camera noticed" in text
    said = log.getvalue()
    assert "[camera] dgcal camera: warning: something camera noticed" in said
    assert "a compiled library writes here" not in said
    assert f"log {out / 'logs' / 'camera.log'}" in said


def test_failed_step_names_its_error_and_log(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(InputError) as exc:
        run_campaign(_campaign(tmp_path), out, runner=_runner(fail="pos"), report=False, log=io.StringIO())
    msg = str(exc.value)
    assert "step pos failed (exit 2): dgcal pos: error: bad.csv, line 3, field x: not a number" in msg
    assert str(out / "logs" / "pos.log") in msg
