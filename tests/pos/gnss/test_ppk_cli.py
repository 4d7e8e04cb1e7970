"""`dgcal pos --mode ppk` bad input: one-line errors or warnings, nothing half-written; geodetic base position."""
import json

import numpy as np

from dgcal.cli import main

ROVER = "rinex-sept/SEPT078M1.21O"
NAV = "rinex-sept/SEPT078M.21P"
BASE = "rinex-3034/3034078M1.21O"
BASE_ECEF = [-3959400.631, 3385704.533, 3667523.111]


def _args(shared_data, out, base=None, *extra):
    return ["pos", "--mode", "ppk", "--rinex-obs", str(shared_data / ROVER), "--rinex-nav", str(shared_data / NAV),
            "--rinex-base", str(base or shared_data / BASE), "--out", str(out), "--no-progress", *extra]


def test_bad_base_inputs_are_one_line_errors(shared_data, tmp_path, capsys):
    # a base file of another day: no common epochs
    text = (shared_data / BASE).read_text().replace("> 2021 03 19 12", "> 2021 03 18 12")
    other = tmp_path / "other_day.21O"
    other.write_text(text)
    out = tmp_path / "o1"
    assert main(_args(shared_data, out, other, "--base-position", *map(str, BASE_ECEF))) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "other_day.21O" in err and "no common epochs" in err and "another day" in err
    assert not (out / "gnss.csv").exists()
    # no base epoch near the rover's (same day, an hour later)
    later = tmp_path / "later.21O"
    later.write_text((shared_data / BASE).read_text().replace("> 2021 03 19 12", "> 2021 03 19 13"))
    assert main(_args(shared_data, tmp_path / "o2", later, "--base-position", *map(str, BASE_ECEF))) == 2
    assert "no common epochs" in capsys.readouterr().err
    # a base position 300 m off the base's own SPP
    wrong = [BASE_ECEF[0] + 300.0, BASE_ECEF[1], BASE_ECEF[2]]
    out = tmp_path / "o3"
    assert main(_args(shared_data, out, None, "--base-position", *map(str, wrong))) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--base-position" in err and "SPP" in err
    assert not (out / "gnss.csv").exists()
    # missing base file option
    assert main(["pos", "--mode", "ppk", "--rinex-obs", str(shared_data / ROVER), "--rinex-nav",
                 str(shared_data / NAV), "--out", str(tmp_path / "o4")]) == 2
    assert "--rinex-base" in capsys.readouterr().err


def test_header_position_warns_and_geodetic_position_matches(shared_data, tmp_path, capsys):
    from dgcal.fields.crs import ecef_to_geodetic
    out = tmp_path / "hdr"
    assert main(_args(shared_data, out, None, "--ppk-solution", "forward")) == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "APPROX POSITION" in err
    s = json.loads((out / "gnss_summary.json").read_text())
    assert s["base_position_source"].startswith("header") and s["warnings"]
    lat, lon, h = ecef_to_geodetic(np.array(BASE_ECEF))
    out2 = tmp_path / "llh"
    assert main(_args(shared_data, out2, None, "--ppk-solution", "forward", "--base-position-llh",
                      f"{lat:.10f}", f"{lon:.10f}", f"{h:.4f}", "--reference", "-3962108.673", "3381309.574",
                      "3668678.638")) == 0
    s2 = json.loads((out2 / "gnss_summary.json").read_text())
    np.testing.assert_allclose(s2["base_ecef_m"], BASE_ECEF, atol=1e-3)
    assert s2["warnings"] == [] and s2["fix_rate"] >= 0.8 and s2["error_fixed"]["rms_3d_m"] < 0.02
    assert s2["orbits"] == "broadcast"   # which orbits were used, in the summary (precise: test_gnss_precise)


def test_a_base_position_metres_off_is_refused_or_warned(shared_data, tmp_path, capsys):
    """A base 10 m east of its coordinates would put every rover position 10 m off with millimetre sigmas: refused
    (one line naming --base-position and the sigma of the base's own SPP); 6 m is a warning; the real 3034 base's
    published coordinates (2 m from its SPP) pass silently."""
    from dgcal.fields.crs import ecef_to_geodetic
    from dgcal.fields.frames import R_ecef_to_enu
    lat, lon, _ = ecef_to_geodetic(np.array(BASE_ECEF))
    east = R_ecef_to_enu(lat, lon)[0]
    out = tmp_path / "ten"
    assert main(_args(shared_data, out, None, "--base-position", *map(str, np.array(BASE_ECEF) + 10.0 * east),
                      "--no-report")) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--base-position" in err and "sigma" in err and "SPP" in err
    assert not out.exists()
    out = tmp_path / "six"
    assert main(_args(shared_data, out, None, "--base-position", *map(str, np.array(BASE_ECEF) + 6.0 * east),
                      "--no-report")) == 0
    assert "warning" in capsys.readouterr().err
    assert json.loads((out / "gnss_summary.json").read_text())["warnings"]
    assert main(_args(shared_data, tmp_path / "ok", None, "--base-position", *map(str, BASE_ECEF), "--no-report")) == 0
    assert "warning" not in capsys.readouterr().err
