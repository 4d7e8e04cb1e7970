"""`dgcal simulate pos` (rover.rnx, base.rnx) + `dgcal pos --mode tc --rinex-base ...` end to end; bad base input."""
from __future__ import annotations

import json
import shlex

import numpy as np
import pytest

from dgcal.cli import main
from dgcal.fields.crs import geodetic_to_ecef
from dgcal.fields.io.formats import read_trajectory
from dgcal.pos.gnss.carrier import carrier_observations
from dgcal.pos.gnss.rinex_obs import read_obs_file
from dgcal.pos.ins.interpolate import interpolate_trajectory



@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    d = tmp_path_factory.mktemp("simcarrier")
    assert main(["simulate", "pos", "--out", str(d), "--seed", "4", "--duration", "200", "--rate", "50"]) == 0
    return d


def _carrier_args(d, out, *extra):
    t = json.loads((d / "truth.json").read_text())
    argv = shlex.split(t["command_carrier"])[1:]          # the exact command line of truth.json
    argv = [str(d / a) if (d / a).is_file() else a for a in argv]
    argv[argv.index("--out") + 1] = str(out)
    return argv + ["--no-progress", *extra]


def test_rover_and_base_files(dataset):
    t = json.loads((dataset / "truth.json").read_text())
    for name in ("rover.rnx", "base.rnx", "obs.rnx", "nav.rnx", "imu.csv", "events.csv"):
        assert (dataset / name).is_file(), name
    base = np.array(t["carrier"]["base_ecef_m"])
    assert 6.3e6 < np.linalg.norm(base) < 6.4e6
    ro = carrier_observations(read_obs_file(dataset / "rover.rnx"), "GE", 2)
    bo = carrier_observations(read_obs_file(dataset / "base.rnx"), "GE", 2)
    # dual frequency code + phase on both receivers, the loss-of-lock flags of the simulated slips kept
    assert ro.n_slots == 2 and np.isfinite(ro.L[:, :, 1]).any() and np.isfinite(bo.L[:, :, 1]).any()
    flagged = sum(s["flagged"] for s in t["carrier"]["slips"])
    assert int((ro.lli & 1).sum()) >= flagged
    # the outages: 3 satellites kept for a minute, none for 10 s
    o = [x for x in t["carrier"]["outages"] if x["max_sats"] == 3][0]
    k = (ro.t_gps > o["t0_gps"] + 1) & (ro.t_gps < o["t1_gps"] - 1)
    assert np.all(np.isfinite(ro.L[k, :, 0]).sum(axis=1) == 3)


def test_tc_with_base_end_to_end(dataset, tmp_path):
    out = tmp_path / "tc"
    assert main(_carrier_args(dataset, out)) == 0
    for name in ("trajectory.csv", "events.csv", "pos_summary.json", "report.html"):
        assert (out / name).is_file(), name
    s = json.loads((out / "pos_summary.json").read_text())
    c = s["carrier"]
    assert c["base_position_source"] == "base.position_ecef" and c["base_minus_spp_m"] < 5.0
    assert c["ppk_fix_rate"] > 0.5 and c["keyframes_with_phase"] >= 0.9 * s["keyframes"]
    assert "ddp" in s["residuals"] and "ddc" in s["residuals"]
    # against the true trajectory (IMU), 10 Hz
    est, tru = read_trajectory(out / "trajectory.csv"), read_trajectory(dataset / "truth_trajectory.csv")
    ok = (est.t > tru.t[0]) & (est.t < tru.t[-1])
    st = interpolate_trajectory(tru, est.t[ok])
    e = np.linalg.norm(np.asarray(geodetic_to_ecef(est.lat[ok], est.lon[ok], est.h[ok])).reshape(-1, 3) - st.p_ecef,
                       axis=1)
    assert ok.sum() > 1000 and np.sqrt(np.mean(e ** 2)) < 0.05


def test_bad_base_inputs(dataset, tmp_path, capsys):
    # a base of another day: no common epochs, one line naming the base file, nothing written
    text = (dataset / "base.rnx").read_text()
    other = tmp_path / "base_other_day.rnx"
    lines = []
    for ln in text.splitlines(True):
        if ln.startswith("> "):
            parts = ln.split()
            ln = ln.replace(f"{parts[1]} {parts[2]} {parts[3]}", f"{parts[1]} {parts[2]} {int(parts[3]) - 1:02d}", 1)
        lines.append(ln)
    other.write_text("".join(lines))
    argv = _carrier_args(dataset, tmp_path / "o1")
    argv[argv.index("--rinex-base") + 1] = str(other)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "base_other_day.rnx" in err and "another day" in err
    assert not (tmp_path / "o1" / "trajectory.csv").exists()
    # a base position 300 m off the base's own SPP
    argv = _carrier_args(dataset, tmp_path / "o2")
    i = argv.index("--base-position") + 1
    argv[i] = str(float(argv[i]) + 300.0)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--base-position" in err and "SPP" in err
    assert not (tmp_path / "o2").exists() or not any((tmp_path / "o2").iterdir())


def test_no_report_in_every_mode(dataset, tmp_path):
    """`--no-report` leaves the HTML report out of ppk, tc and lc (and spp) and writes every other file."""
    t = json.loads((dataset / "truth.json").read_text())
    ppk = [str(dataset / a) if (dataset / a).is_file() else a for a in shlex.split(t["command_ppk"])[1:]]
    ppk[ppk.index("--out") + 1] = str(tmp_path / "ppk")
    assert main(ppk + ["--no-progress", "--no-report"]) == 0
    assert sorted(p.name for p in (tmp_path / "ppk").iterdir() if not p.name.startswith(".")) == ["gnss.csv",
                                                                                        "gnss_summary.json"]
    out = tmp_path / "tc"
    assert main(_carrier_args(dataset, out, "--no-report")) == 0
    names = {p.name for p in out.iterdir()}
    assert {"trajectory.csv", "events.csv", "pos_summary.json"} <= names and "report.html" not in names
    lc = tmp_path / "lc"
    assert main(["pos", "--mode", "lc", "--imu", str(dataset / "imu.csv"), "--gnss", str(tmp_path / "ppk" / "gnss.csv"),
                 "--events", str(dataset / "events.csv"), "--imu-grade", t["imu_grade"], "--lever-arm",
                 *map(str, t["lever_arm_gnss_m"]), "--out", str(lc), "--no-progress", "--no-report"]) == 0
    names = {p.name for p in lc.iterdir()}
    assert "trajectory.csv" in names and "report.html" not in names


def test_simulate_pos_as_an_airframe_sees_the_sky(tmp_path, capsys):
    """`dgcal simulate pos` options of issue 26: airframe mask, slips while banked, half cycles, no Doppler; refused
    out of range."""
    d = tmp_path / "air"
    assert main(["simulate", "pos", "--out", str(d), "--seed", "1", "--duration", "150", "--rate", "50",
                 "--airframe-mask", "10", "--turn-slip-rate", "0.02", "--half-cycles", "0.5", "--no-doppler"]) == 0
    t = json.loads((d / "truth.json").read_text())
    assert t["carrier_airframe_mask_deg"] == 10.0 and t["carrier_doppler"] is False
    ro = carrier_observations(read_obs_file(d / "rover.rnx"), "GE", 2)
    assert not np.isfinite(ro.D).any() and ((ro.lli & 2) > 0).any()
    assert len(t["carrier"]["slips"]) > t.get("n_slips", 6)          # the random ones and those drawn in banks
    assert main(["simulate", "pos", "--out", str(tmp_path / "bad"), "--half-cycles", "2"]) == 2
    assert "--half-cycles" in capsys.readouterr().err and not (tmp_path / "bad").exists()
