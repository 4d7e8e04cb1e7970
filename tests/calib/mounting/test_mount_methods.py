"""The mounting-method registry: names a user understands (two-step, joint, iso), the seed paper's names as
aliases in Python, on the command line and in a campaign file; mounting.json echoes the name given."""
import json

import numpy as np
import pytest

from dgcal.calib.mounting.methods import (ALIASES, DEFAULT_METHOD, METHODS, calibrate_mounting, canonical_method,
                                          mounting_method)
from dgcal.campaign import load_campaign, plan
from dgcal.cli import main
from dgcal.fields.crs import MapGrid
from dgcal.fields.errors import InputError
from dgcal.sim.mounting import simulate_mounting, write_mounting_sim


@pytest.fixture(scope="module")
def sim():
    return simulate_mounting(4)


def test_registry_names_and_aliases():
    assert list(METHODS) == ["two-step", "joint", "iso"]
    assert ALIASES == {"traditional": "two-step", "proposed": "joint"}
    assert DEFAULT_METHOD == "joint"
    assert mounting_method("traditional") is METHODS["two-step"] and mounting_method("Proposed") is METHODS["joint"]
    assert canonical_method("proposed") == "joint" and canonical_method("iso") == "iso"
    with pytest.raises(InputError, match="'method'") as e:
        mounting_method("magic")
    assert "two-step" in str(e.value) and "traditional" in str(e.value)


def test_aliases_give_the_same_calibration_and_echo_the_name(sim):
    c, grid = sim.calibration, MapGrid(sim.crs)
    for alias, name in (("traditional", "two-step"), ("proposed", "joint")):
        a = calibrate_mounting(c.eop, grid, c.traj, c.events, alias)
        b = calibrate_mounting(c.eop, grid, c.traj, c.events, name)
        assert a.method == alias and b.method == name
        assert a.method_canonical == b.method_canonical == name
        np.testing.assert_array_equal(a.lever_arm_m, b.lever_arm_m)
        assert a.delay_s == b.delay_s
        assert a.to_json()["method_canonical"] == name
    d = calibrate_mounting(c.eop, grid, c.traj, c.events)  # the default is the joint method
    assert d.method_canonical == "joint" and abs(d.delay_s - sim.delay_s) < 0.002
    with pytest.raises(InputError, match="image measurements"):
        calibrate_mounting(c.eop, grid, c.traj, c.events, "iso")


def test_cli_method_names_and_aliases(sim, tmp_path):
    write_mounting_sim(sim, tmp_path / "sim")
    c = tmp_path / "sim" / "calibration"
    base = ["mount", "--eop", str(c / "eop.csv"), "--crs", sim.crs, "--trajectory", str(c / "trajectory.csv"),
            "--events", str(c / "events.csv")]
    out = {}
    for m in ("proposed", "joint", "two-step", None):
        d = tmp_path / f"m_{m}"
        assert main(base + (["--method", m] if m else []) + ["--out", str(d)]) == 0
        out[m] = json.loads((d / "mounting.json").read_text())
        for f in ("mounting.json", "report.html", "epochs.csv"):
            assert (d / f).is_file()
    assert out["proposed"]["method"] == "proposed" and out["proposed"]["method_canonical"] == "joint"
    assert out["joint"]["method"] == "joint" and out[None]["method"] == "joint"
    assert out["two-step"]["method_canonical"] == "two-step" and out["two-step"]["delay_s"] == 0.0
    assert out["proposed"]["delay_s"] == out["joint"]["delay_s"] == out[None]["delay_s"]
    assert main(base + ["--method", "magic", "--out", str(tmp_path / "bad")]) == 2
    assert not (tmp_path / "bad").exists()


CAMPAIGN = """crs = "EPSG:32651"
[camera]
camera_json = "cam.json"
[triangulation]
eop = "eop.csv"
gcp = "gcp.csv"
measurements = "meas.csv"
[pos]
trajectory = "traj.csv"
events = "events.csv"
[mount]
method = "{method}"
compare = {compare}
pos_common_fraction = 1.0
[check]
"""


def test_campaign_takes_new_names_and_aliases(tmp_path):
    for name in ("cam.json", "eop.csv", "gcp.csv", "meas.csv", "traj.csv", "events.csv"):
        (tmp_path / name).write_text("x\n")
    p = tmp_path / "c.toml"
    p.write_text(CAMPAIGN.format(method="joint", compare='["iso", "traditional"]'))
    steps = plan(load_campaign(p), tmp_path / "out")
    assert [s.name for s in steps] == ["mount_joint", "mount_iso", "mount_traditional", "check"]
    by = {s.name: s for s in steps}
    assert "--pos-common-fraction" in by["mount_joint"].argv and "--pos-common-fraction" in by["mount_iso"].argv
    assert "--pos-common-fraction" not in by["mount_traditional"].argv
    chk = by["check"].argv
    mounts = chk[chk.index("--mounting") + 1:chk.index("--camera")]
    assert [m.split("/")[-2] for m in mounts] == ["mount_traditional", "mount_joint", "mount_iso"]  # two-step first
    p.write_text(CAMPAIGN.format(method="two-step", compare="[]").replace("pos_common_fraction = 1.0\n", ""))
    assert [s.name for s in plan(load_campaign(p), tmp_path / "out")] == ["mount_two-step", "check"]
    p.write_text(CAMPAIGN.format(method="median", compare="[]"))
    with pytest.raises(InputError) as e:
        plan(load_campaign(p), tmp_path / "out")
    assert e.value.field == "mount.method"
