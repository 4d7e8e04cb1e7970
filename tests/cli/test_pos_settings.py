"""`dgcal pos --set KEY=VALUE`: a key of another mode exits 2 naming it and the mode it belongs to; bad numbers and
ratios are refused (issue 28, issue 31). The check comes before any file is read."""
from __future__ import annotations

import pytest

from dgcal.cli import main
from dgcal.pos.pipeline import PosOptions, check_settings_mode, mode_settings

PPK = ["pos", "--mode", "ppk", "--rinex-obs", "r.rnx", "--rinex-nav", "n.rnx", "--rinex-base", "b.rnx",
       "--base-position", "-3959400.6", "3385704.5", "3667523.1"]
TC = ["pos", "--mode", "tc", "--rinex-obs", "r.rnx", "--rinex-nav", "n.rnx", "--imu", "imu.csv"]


@pytest.mark.parametrize("argv, key, owner", [
    (TC + ["--set", "alpha=0.5"], "alpha", "ukf/ppk"),               # a UKF (and PPK) key in tc
    (TC + ["--set", "iono_ppm=50"], "iono_ppm", "with --rinex-base"),  # a double-difference key without a base
    (PPK + ["--set", "skip_s=99"], "skip_s", "ukf"),
    (PPK + ["--set", "huber_k=2"], "huber_k", "tc/lc/ukf"),
    (["pos", "--mode", "lc", "--gnss", "g.csv", "--imu", "imu.csv", "--set", "hold_after=5"], "hold_after", "ppk"),
    (["pos", "--mode", "spp", "--rinex-obs", "r.rnx", "--rinex-nav", "n.rnx", "--set", "rate=5"], "rate", "spp"),
])
def test_a_setting_of_another_mode_exits_2_naming_it(argv, key, owner, tmp_path, capsys):
    assert main(argv + ["--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--set" in err[0] and key in err[0] and owner in err[0], err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("extra", [["--set", "ratio_threshold=nan"], ["--set", "phase_sigma_m=inf"],
                                   ["--ar-ratio", "nan"], ["--ar-ratio", "0.5"]])
def test_non_finite_or_impossible_numbers_are_refused(extra, tmp_path, capsys):
    try:
        rc = main(PPK + extra + ["--out", str(tmp_path / "out")])
    except SystemExit as exc:                 # argparse's own refusal of an option's value
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err
    assert "nan" in err or "inf" in err or "0.5" in err


def test_every_mode_knows_its_own_keys():
    assert "hold_after" in mode_settings("ppk") and "alpha" in mode_settings("ukf")
    assert "iono_ppm" in mode_settings("tc", with_base=True) and "iono_ppm" not in mode_settings("tc")
    assert mode_settings("spp") == set()
    check_settings_mode(PosOptions(mode="tc", settings=("rate=5", "dd_code=false"), rinex_base="b.rnx"))
    check_settings_mode(PosOptions(mode="ukf", settings=("skip_s=5", "rate=20")))
