"""The honesty table on real data (issue 27): SPP and PPK of the static Septentrio receiver (`../shared/data/
rinex-sept`, `rinex-3034` as base) against its known position, and LC on the car drive (`gnss-imu-drive`) against
the RTK fixes withheld in outages: the rows in the JSON summary under `honesty`, the same table in the HTML page,
and the line saying when there is no reference."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dgcal.cli import main
from dgcal.reports.honesty import verdict

SEPT = ("rinex-sept/SEPT078M1.21O", "rinex-sept/SEPT078M.21P")
REF = ("-3962108.673", "3381309.574", "3668678.638")            # the antenna's known position (data README)
BASE = ("rinex-3034/3034078M1.21O", ("-3959400.631", "3385704.533", "3667523.111"))
DOCS = Path(__file__).resolve().parents[2] / "docs" / "examples"


def _rows(summary: dict) -> dict:
    return {r["quantity"]: r for r in summary["honesty"]["rows"]}


def test_spp_against_the_known_position(shared_data, tmp_path):
    """Per-epoch E/N/U errors over the fixes' sigmas; their RMS is the summary's 3D RMS against --reference. (The
    verdicts follow the SPP's sigma model, which is being reworked: error/sigma RMS 0.32, 0.28, 0.65 at commit
    9baf45a, sigmas too large; the figures are not pinned here.)"""
    obs, nav = (str(shared_data / p) for p in SEPT)
    out = tmp_path / "spp"
    assert main(["pos", "--mode", "spp", "--rinex-obs", obs, "--rinex-nav", nav, "--reference", *REF,
                 "--no-progress", "--out", str(out)]) == 0
    s = json.loads((out / "gnss_summary.json").read_text())
    rows = _rows(s)
    assert list(rows) == ["E", "N", "U"] and {r["n"] for r in rows.values()} == {s["n_fixed"]}
    assert np.sqrt(sum(r["rms_error"] ** 2 for r in rows.values())) == pytest.approx(s["rms_3d_vs_reference_m"])
    for r in rows.values():
        assert 0.05 < r["error_over_sigma_rms"] <= r["max_abs_error_over_sigma"] < 20, r
        assert r["verdict"] == verdict(r["error_over_sigma_rms"], r["max_abs_error_over_sigma"])
    page = (out / "gnss_report.html").read_text()
    assert "Honesty: errors against their sigmas" in page and "<td>known antenna position</td>" in page
    bare = tmp_path / "bare"
    assert main(["pos", "--mode", "spp", "--rinex-obs", obs, "--rinex-nav", nav, "--no-progress", "--no-report",
                 "--out", str(bare)]) == 0
    h = json.loads((bare / "gnss_summary.json").read_text())["honesty"]
    assert h["rows"] == [] and h["notes"][0].startswith("No reference: give the antenna's known position")


def test_ppk_against_the_known_position_by_status(shared_data, tmp_path):
    """Every epoch fixed: E/N/U fixed rows, millimetre errors against millimetre sigmas."""
    obs, nav = (str(shared_data / p) for p in SEPT)
    out = tmp_path / "ppk"
    assert main(["pos", "--mode", "ppk", "--rinex-obs", obs, "--rinex-nav", nav, "--rinex-base",
                 str(shared_data / BASE[0]), "--base-position", *BASE[1], "--reference", *REF, "--no-progress",
                 "--out", str(out)]) == 0
    s = json.loads((out / "gnss_summary.json").read_text())
    rows = _rows(s)
    assert list(rows) == ["E fixed", "N fixed", "U fixed"]
    assert all(r["n"] == s["counts"]["fixed"] and r["rms_error"] < 0.02 and r["median_sigma"] < 0.02
               and r["max_abs_error_over_sigma"] < 5 for r in rows.values())
    assert "<td>U fixed</td>" in (out / "gnss_report.html").read_text()


def _drive_opts(shared_data, t_start=1436038560, t_end=1436038700):
    from dgcal.pos.mode_options import FixInput, ImuInput, InsModeOptions, RinexInput
    d = shared_data / "gnss-imu-drive"
    return InsModeOptions(mode="lc", imu=ImuInput(d / "imu_1934.csv", str(DOCS / "gnss_imu_drive_imu.toml"),
                                                  time_offset_s=-0.125),
                          rover=RinexInput(t_start=t_start, t_end=t_end),
                          fixes=FixInput(d / "gnss_1934_sf.pos", outages=(40.0, 15.0, 45.0)),
                          lever_arm_m=(0.0, -0.05, 0.0), imu_grade=str(DOCS / "gnss_imu_drive_grade.toml"),
                          progress=False)


def test_lc_against_the_withheld_fixes(shared_data, tmp_path):
    """A 140 s window of the drive, 15 s of every 45 s withheld: the rows' RMS errors are pos_summary.json's
    withheld_fixes RMS (N, E, D); the denominators are the trajectory's sigma with the fix's own in quadrature. (At
    commit 9baf45a, with the example's settings, the sigmas in the outages were too small: error/sigma RMS 2.1, 2.9,
    3.4, the whole drive 2.1, 3.0, 0.9; not pinned here.) Without the withheld fixes at hand the report says what it
    lacks."""
    from dgcal.commands.pos import INS_OUTPUTS
    from dgcal.pos.gnss_ins import read_fixes, run_gnss_ins
    from dgcal.reports.pos import pos_honesty, withheld_errors, write_pos_outputs
    opts = _drive_opts(shared_data)
    res = run_gnss_ins(opts)
    withheld = read_fixes(opts)[1]
    write_pos_outputs(tmp_path, res, INS_OUTPUTS, withheld=withheld)
    s = json.loads((tmp_path / "pos_summary.json").read_text())
    rows, w = _rows(s), s["withheld_fixes"]
    assert list(rows) == ["N", "E", "D"] and {r["n"] for r in rows.values()} == {w["n"]}
    assert [round(r["rms_error"], 4) for r in rows.values()] == pytest.approx(w["rms_ned_m"], abs=1e-4)
    err, s_traj, s_fix = withheld_errors(res, withheld)
    z = err / np.sqrt(s_traj ** 2 + s_fix ** 2)
    assert [r["error_over_sigma_rms"] for r in rows.values()] == pytest.approx(np.sqrt(np.mean(z ** 2, axis=0)))
    assert (s_fix > 0).all() and all(r["verdict"] == verdict(r["error_over_sigma_rms"], r["max_abs_error_over_sigma"])
                                     for r in rows.values())
    assert "<td>withheld fixes</td>" in (tmp_path / "report.html").read_text()
    kept_rms_only = pos_honesty(res)            # as the command writes it today: the result lacks the fixes
    assert kept_rms_only["rows"] == [] and "were not kept with the result" in kept_rms_only["notes"][0]
    res.summary.pop("withheld_fixes")
    assert pos_honesty(res)["notes"][0].startswith("No reference: withhold some of the GNSS fixes")
