"""The campaign runner without running the chain: the argv of every step parses with the real verbs, bad
campaign files fail with errors naming file and field, fingerprints follow contents, failing steps stop
the run without being recorded as done."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from dgcal.campaign import Step, load_campaign, plan, run_campaign
from dgcal.cli import build_parser
from dgcal.fields.errors import InputError
from dgcal.fields.io.atomic import staged_dir

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
imu_grade = "adis16488"
lever_arm_gnss = [0.05, 0.0, -0.35]
[mount]
method = "proposed"
compare = ["traditional", "iso"]
measurements = "meas_gcp.csv"
[check]
measurements = "meas_gcp.csv"
"""


def _campaign(tmp_path: Path, text: str = TOML) -> Path:
    for name in ("field.csv", "field_meas.csv", "gcp.csv", "meas.csv", "imu.txt", "events.csv", "gnss.csv",
                 "meas_gcp.csv"):
        (tmp_path / name).write_text(f"{name}\n")
    p = tmp_path / "campaign.toml"
    p.write_text(text)
    return p


def test_every_step_argv_parses_with_the_real_verbs(tmp_path):
    steps = plan(load_campaign(_campaign(tmp_path)), tmp_path / "out")
    assert [s.name for s in steps] == ["camera", "triangulate", "pos", "mount_proposed", "mount_traditional",
                                       "mount_iso", "check"]
    parser = build_parser()
    for s in steps:
        args = parser.parse_args(s.argv)  # SystemExit on an unknown option or a missing required one
        assert args.verb == s.argv[0]
    byname = {s.name: s for s in steps}
    a = parser.parse_args(byname["pos"].argv)
    assert a.mode == "lc" and a.lever_arm == [0.05, 0.0, -0.35] and a.imu_grade == "adis16488"
    a = parser.parse_args(byname["check"].argv)
    # traditional first: the reference of the improvement rates
    assert [p.parent.name for p in a.mounting] == ["mount_traditional", "mount_proposed", "mount_iso"]
    a = parser.parse_args(byname["mount_iso"].argv)
    assert a.method == "iso" and a.measurements.name == "meas_gcp.csv" and a.camera.name == "camera.json"
    assert byname["mount_iso"].after == ["camera", "triangulate", "pos"]


def test_external_camera_eop_and_trajectory_skip_their_steps(tmp_path):
    text = """crs = "EPSG:32651"
[camera]
camera_json = "cam.json"
[triangulation]
eop = "eop.csv"
gcp = "gcp.csv"
[pos]
trajectory = "traj.csv"
events = "events.csv"
[mount]
method = "traditional"
"""
    steps = plan(load_campaign(_campaign(tmp_path, text)), tmp_path / "out")
    assert [s.name for s in steps] == ["mount_traditional"]
    assert "traj.csv" in " ".join(steps[0].argv) and "eop.csv" in " ".join(steps[0].argv)


@pytest.mark.parametrize("text,field", [
    ("[camera]\nfield = 'f.csv'\n", "crs"),
    ('crs = "EPSG:32651"\n[pos]\nmode = "xx"\nimu = "i"\nevents = "e"\n', "pos.mode"),
    ('crs = "EPSG:32651"\n[camera]\nfield = "f.csv"\nmeasurements = "m.csv"\nimage_size = [6000]\n',
     "camera.image_size"),
    ('crs = "EPSG:32651"\n[pos]\nimu = "i"\n', "pos.events"),
    ('crs = "EPSG:32651"\n[triangulation]\neop = "e.csv"\n[pos]\ntrajectory = "t.csv"\nevents = "e.csv"\n'
     '[mount]\nmethod = "magic"\n', "mount.method"),
])
def test_bad_campaign_names_the_field(tmp_path, text, field):
    p = tmp_path / "c.toml"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        plan(load_campaign(p), tmp_path / "out")
    assert e.value.field == field
    assert "c.toml" in str(e.value)


def test_not_toml_and_missing_files(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("crs = \n")
    with pytest.raises(InputError, match="not valid TOML"):
        load_campaign(p)
    with pytest.raises(InputError, match="not found"):
        load_campaign(tmp_path / "nope.toml")
    c = _campaign(tmp_path)
    (tmp_path / "imu.txt").unlink()
    with pytest.raises(InputError, match="input of step pos not found") as e:
        run_campaign(c, tmp_path / "out", runner=lambda argv: 0, report=False)
    assert "imu.txt" in str(e.value)


def test_fingerprint_follows_content_not_time(tmp_path):
    f = tmp_path / "a.csv"
    f.write_text("x\n1\n")
    s = Step("s", ["verb", "--x"], [f], [])
    fp = s.fingerprint()
    f.write_text("x\n1\n")  # same bytes, new modification time
    assert s.fingerprint() == fp
    f.write_text("x\n2\n")
    assert s.fingerprint() != fp
    assert Step("s", ["verb", "--y"], [f], []).fingerprint() != s.fingerprint()


def test_failing_step_stops_and_is_not_recorded(tmp_path):
    c = _campaign(tmp_path)
    out = tmp_path / "out"
    ran = []

    def runner(argv):
        ran.append(argv[0])
        if argv[0] == "pos":
            return 2
        with staged_dir(argv[argv.index("--out") + 1]) as d:   # as the verbs write: a folder with its manifest
            for name in ("camera.json", "eop.csv"):
                (d / name).write_text("x")
        return 0

    with pytest.raises(InputError, match="step pos failed"):
        run_campaign(c, out, runner=runner, report=False, log=open("/dev/null", "w"))
    assert ran == ["camera", "triangulate", "pos"]
    ran.clear()
    with pytest.raises(InputError, match="step pos failed"):
        run_campaign(c, out, runner=runner, report=False, log=open("/dev/null", "w"))
    assert ran == ["pos"]  # camera and triangulate were done and are kept

    def crash(argv):
        raise ZeroDivisionError("boom")

    with pytest.raises(InputError, match="step pos crashed"):
        run_campaign(c, out, runner=crash, report=False, log=open("/dev/null", "w"))


def test_cli_run_reports_one_line_and_exit_2(tmp_path):
    r = subprocess.run([sys.executable, "-m", "dgcal", "run", str(tmp_path / "missing.toml"), "--out",
                        str(tmp_path / "o")], capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "missing.toml" in r.stderr
    c = _campaign(tmp_path)
    r = subprocess.run([sys.executable, "-m", "dgcal", "run", str(c), "--out", str(tmp_path / "o"), "--dry-run"],
                       capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.count("[") == 7 and "dgcal check --mounting" in r.stdout
