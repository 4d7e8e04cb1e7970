"""`dgcal simulate pos` + `dgcal pos --mode tc|lc` end to end on a short simulated flight; input errors."""
from __future__ import annotations

import json

import numpy as np
import pytest


from dgcal.fields.errors import InputError  # noqa: E402
from dgcal.fields.io.formats import read_trajectory  # noqa: E402


def _dgcal(argv) -> int:
    from dgcal.cli import main
    return main(argv)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    d = tmp_path_factory.mktemp("simpos")
    rc = _dgcal(["simulate", "pos", "--out", str(d), "--seed", "5", "--duration", "200", "--rate", "50"])
    assert rc == 0
    return d


def _pos_args(d, out, mode="tc", extra=()):
    t = json.loads((d / "truth.json").read_text())
    return (["pos", "--mode", mode, "--rinex-obs", str(d / "obs.rnx"), "--rinex-nav", str(d / "nav.rnx"),
             "--imu", str(d / "imu.csv"), "--events", str(d / "events.csv"), "--imu-grade", t["imu_grade"],
             "--lever-arm", *[str(v) for v in t["lever_arm_gnss_m"]], "--code-sigma", "0.3",
             "--doppler-sigma", "0.1", "--set", "model_errors=false", "--no-progress", "--out", str(out)]
            + list(extra))


def test_simulated_dataset_files(dataset):
    for name in ("imu.csv", "obs.rnx", "nav.rnx", "events.csv", "truth.json", "truth_trajectory.csv",
                 "truth_events.csv"):
        assert (dataset / name).is_file(), name
    t = json.loads((dataset / "truth.json").read_text())
    assert t["kind"] == "pos" and t["outage"]["max_sats"] == 3
    assert t["outage"]["t1_gps"] - t["outage"]["t0_gps"] == pytest.approx(60.0)


@pytest.mark.parametrize("mode", ["tc", "lc"])
def test_cli_writes_trajectory_and_events(dataset, tmp_path, mode):
    out = tmp_path / mode
    assert _dgcal(_pos_args(dataset, out, mode, ["--set", "rate=5"] + (["--set", "forward=true"] if mode == "tc"
                                                                        else []))) == 0
    for name in ("trajectory.csv", "events.csv", "report.html", "pos_summary.json"):
        assert (out / name).is_file(), name
    # the forward solution is opt-in (a tenth of the run; what the trajectory and events need comes without it)
    assert (out / "trajectory_forward.csv").is_file() == (mode == "tc")
    header = (out / "trajectory.csv").read_text().splitlines()[0].split(",")
    assert header == ["gps_week", "gps_sow", "lat", "lon", "h", "vn", "ve", "vd", "roll", "pitch", "heading",
                      "s_lat_m", "s_lon_m", "s_h_m", "s_roll", "s_pitch", "s_heading"]
    assert (out / "events.csv").read_text().splitlines()[0].startswith("image,gps_week,gps_sow,lat,lon,h")
    tr = read_trajectory(out / "trajectory.csv")
    assert np.median(np.diff(tr.t)) == pytest.approx(0.2)
    ev = read_trajectory(out / "events.csv")
    truth = read_trajectory(dataset / "truth_events.csv")
    assert list(ev.image) == list(truth.image)
    from dgcal.fields.crs import geodetic_to_ecef
    dp = geodetic_to_ecef(ev.lat, ev.lon, ev.h) - geodetic_to_ecef(truth.lat, truth.lon, truth.h)
    assert np.sqrt(np.mean(np.sum(dp ** 2, axis=1))) < 1.0
    d = ev.rph - truth.rph
    d[:, 2] = (d[:, 2] + 180) % 360 - 180
    assert np.all(np.sqrt(np.mean(d[:, :2] ** 2, axis=0)) < 0.08)
    assert np.all(ev.sigma > 0)
    # heading is weakly observable in 3 minutes: judge it against its own sigma
    assert np.all(np.sqrt(np.mean((d / ev.sigma[:, 3:]) ** 2, axis=0)) < 2.5)
    html = (out / "report.html").read_text()
    assert "data:image/png;base64" in html and ("Innovations" in html) == (mode == "tc")


def test_cli_lc_from_gnss_csv(dataset, tmp_path):
    """LC from the gnss.csv of --mode spp (the file route of the loosely coupled input)."""
    assert _dgcal(["pos", "--mode", "spp", "--rinex-obs", str(dataset / "obs.rnx"), "--rinex-nav",
                   str(dataset / "nav.rnx"), "--systems", "GE", "--no-progress", "--out", str(tmp_path / "spp")]) == 0
    t = json.loads((dataset / "truth.json").read_text())
    argv = ["pos", "--mode", "lc", "--gnss", str(tmp_path / "spp" / "gnss.csv"), "--imu", str(dataset / "imu.csv"),
            "--events", str(dataset / "events.csv"), "--imu-grade", "adis16488", "--lever-arm",
            *[str(v) for v in t["lever_arm_gnss_m"]], "--no-progress", "--out", str(tmp_path / "lc")]
    assert _dgcal(argv) == 0
    ev = read_trajectory(tmp_path / "lc" / "events.csv")
    truth = read_trajectory(dataset / "truth_events.csv")
    from dgcal.fields.crs import geodetic_to_ecef
    dp = geodetic_to_ecef(ev.lat, ev.lon, ev.h) - geodetic_to_ecef(truth.lat, truth.lon, truth.h)
    assert np.sqrt(np.mean(np.sum(dp ** 2, axis=1))) < 3.0


def test_event_outside_the_flight_names_the_events_file(dataset, tmp_path):
    lines = (dataset / "events.csv").read_text().splitlines()
    week, sow = lines[-1].split(",")[1:3]
    lines.append(f"LATE.JPG,{week},{float(sow) + 3600:.6f}")
    bad = tmp_path / "events_bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    args = _pos_args(dataset, tmp_path / "o", "tc")
    args[args.index("--events") + 1] = str(bad)
    with pytest.raises(InputError) as exc:
        from dgcal.pos.pipeline import run_pos
        import argparse
        from dgcal.commands import pos as cmd
        p = argparse.ArgumentParser()
        cmd.add_arguments(p)
        run_pos(cmd.pos_options(p.parse_args(args[1:])))
    msg = str(exc.value)
    assert "events_bad.csv" in msg and f":{len(lines)}" in msg
    assert not (tmp_path / "o" / "trajectory.csv").exists()


def test_bad_settings_and_missing_inputs(dataset, tmp_path):
    from dgcal.pos.mode_options import ImuInput, InsModeOptions
    from dgcal.pos.pipeline import run_pos
    with pytest.raises(InputError) as exc:
        run_pos(InsModeOptions(mode="tc", events=dataset / "events.csv"))
    assert exc.value.field == "imu.path"
    with pytest.raises(InputError) as exc:
        run_pos(InsModeOptions(mode="tc", imu=ImuInput(dataset / "imu.csv"), events=dataset / "events.csv",
                               imu_grade="potato"))
    assert exc.value.field == "imu_grade"
    assert _dgcal(["pos", "--mode", "tc", "--imu", str(dataset / "imu.csv"), "--events",
                   str(dataset / "events.csv"), "--out", str(tmp_path / "y")]) == 2
    for bad in ("nonsense=3", "use_doppler=maybe"):
        assert _dgcal(_pos_args(dataset, tmp_path / "z", "tc", ["--set", bad])) == 2
    assert not (tmp_path / "z").exists()


def test_imu_time_offset_estimated(dataset, tmp_path, capsys):
    """A 50 ms logging delay given wrongly as zero... here: the IMU tags moved by +50 ms with --imu-time-offset; the
    estimate brings them back (-50 ms within 3 sigma) and is reported in the summary and on the console."""
    out = tmp_path / "toff"
    assert _dgcal(_pos_args(dataset, out, "tc", ["--set", "rate=5", "--imu-time-offset", "0.05",
                                                 "--estimate-imu-time-offset"])) == 0
    o = json.loads((out / "pos_summary.json").read_text())["imu_time_offset"]
    est, sig = 1e-3 * o["offset_ms"], 1e-3 * o["sigma_ms"]
    print(f"\nestimated {1e3 * est:+.1f} +- {1e3 * sig:.1f} ms (truth -50 ms)")
    assert 0 < sig <= 0.02
    assert abs(est + 0.05) <= 3 * sig
    assert len(o["trials"]) >= 6
    assert "IMU time offset estimated" in capsys.readouterr().err
    assert "IMU-GNSS time offset (estimated)" in (out / "report.html").read_text()
