"""`dgcal pos --set KEY=VALUE`: parsed from the fields of the chosen mode's options (dgcal.pos.mode_options); a key of
another mode or an unknown key exits 2 naming it (and the mode it belongs to); bad values, non-finite numbers and
impossible ratios are refused (issues 28, 31). The checks come before any file is read; library errors name
option fields and the command line names its flags."""
from __future__ import annotations

import pytest

from dgcal.cli import main
from dgcal.fields.errors import InputError
from dgcal.flags import flags_in_errors
from dgcal.pos.gnss.spp_mode import SppModeOptions
from dgcal.pos.mode_options import MODE_OPTIONS, InsModeOptions, PpkModeOptions, UkfModeOptions
from dgcal.settings import apply_settings, setting_fields

PPK = ["pos", "--mode", "ppk", "--rinex-obs", "r.rnx", "--rinex-nav", "n.rnx", "--rinex-base", "b.rnx",
       "--base-position", "-3959400.6", "3385704.5", "3667523.1"]
TC = ["pos", "--mode", "tc", "--rinex-obs", "r.rnx", "--rinex-nav", "n.rnx", "--imu", "imu.csv"]
LC = ["pos", "--mode", "lc", "--gnss", "g.csv", "--imu", "imu.csv"]
UKF = ["pos", "--mode", "ukf", "--gnss", "g.csv", "--imu", "imu.csv"]
SPP = ["pos", "--mode", "spp", "--rinex-obs", "r.rnx", "--rinex-nav", "n.rnx"]


def _others(mode):
    return {m: (c(mode=m) if m in ("tc", "lc") else c()) for m, c in MODE_OPTIONS.items() if m != mode}


@pytest.mark.parametrize("argv, key, owner", [
    (TC + ["--set", "alpha=0.5"], "alpha", "ppk/ukf"),               # a UKF (and PPK) key in tc
    (TC + ["--set", "iono_ppm=50"], "iono_ppm", "base station"),      # a double-difference key without a base
    (PPK + ["--set", "skip_s=99"], "skip_s", "ukf"),
    (PPK + ["--set", "huber_k=2"], "huber_k", "tc/lc/ukf"),
    (LC + ["--set", "hold_after=5"], "hold_after", "ppk"),
    (SPP + ["--set", "rate=5"], "rate", "tc/lc/ukf"),
    (UKF + ["--set", "ratio_threshold=2"], "ratio_threshold", "ppk"),
])
def test_a_setting_of_another_mode_exits_2_naming_it(argv, key, owner, tmp_path, capsys):
    assert main(argv + ["--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--set" in err[0] and key in err[0] and owner in err[0], err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("argv", [SPP, PPK, TC, LC, UKF])
def test_an_unknown_key_exits_2_naming_it_in_every_mode(argv, tmp_path, capsys):
    assert main(argv + ["--set", "no_such_key=1", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no_such_key" in err[0] and "unknown setting" in err[0] and "--set" in err[0], err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("extra", [["--set", "ratio_threshold=nan"], ["--set", "phase_sigma_m=inf"],
                                   ["--ar-ratio", "nan"], ["--ar-ratio", "0.5"], ["--set", "ratio_threshold=0.5"],
                                   ["--set", "hold=maybe"], ["--set", "min_lock=2.5"], ["--set", "hold_after"]])
def test_non_finite_impossible_or_malformed_values_are_refused(extra, tmp_path, capsys):
    try:
        rc = main(PPK + extra + ["--out", str(tmp_path / "out")])
    except SystemExit as exc:                 # argparse's own refusal of an option's value
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err
    assert any(w in err for w in ("nan", "inf", "0.5", "maybe", "2.5", "KEY=VALUE")), err
    assert not (tmp_path / "out").exists()


def test_settings_are_typed_fields_of_the_modes_options():
    """Bare keys reach the first group that has them, GROUP.KEY any group, old names their new fields; values take
    the field's type (bool words, whole numbers, finite floats, none for optional numbers)."""
    tc = InsModeOptions(mode="tc")
    tc.base.rinex = "b.rnx"
    apply_settings(tc, ["rate=5", "dd_code=false", "huber_k=none", "max_iterations=12", "ppk.alpha=0.01",
                        "phase_sigma_m=0.004", "model_errors=off", "imu_max_gap_s=2"], _others("tc"))
    assert tc.output.rate_hz == 5.0 and tc.dd.use_code is False and tc.smoother.huber_k is None
    assert tc.smoother.max_iterations == 12 and tc.ppk.alpha == 0.01 and tc.spp.model_errors is False
    assert tc.dd.phase_sigma_m == 0.004 and tc.ppk.phase_sigma_m == PpkModeOptions().ppk.phase_sigma_m
    assert tc.imu_checks.max_gap_s == 2.0
    ukf = apply_settings(UkfModeOptions(), ["skip_s=5", "alpha=0.3", "compare=false"], _others("ukf"))
    assert ukf.ukf_run.skip_s == 5.0 and ukf.ukf.alpha == 0.3 and ukf.ukf_run.compare is False
    spp = apply_settings(SppModeOptions(), ["raim_alpha=0.01", "max_gdop=10"], _others("spp"))
    assert spp.spp.raim_alpha == 0.01 and spp.spp.max_gdop == 10.0
    # every scalar field of every group is a key; arrays and tuples are given by their own flags
    keys = setting_fields(InsModeOptions(mode="tc").settings_groups(every=True))
    assert "smoother.use_doppler" in keys and "lever_arm_b" not in keys and "dd.iono_ppm" in keys
    assert "iono_ppm" not in setting_fields(InsModeOptions(mode="tc").settings_groups())


def test_library_errors_name_fields_and_the_command_line_its_flags():
    """The library names the options' fields; `flags_in_errors` turns them into the verb's flags; errors of files
    keep their file, line and field."""
    from dgcal.pos.ppk_mode import run_ppk
    with pytest.raises(InputError) as exc:
        run_ppk(PpkModeOptions())
    assert exc.value.field == "rinex_obs"
    with pytest.raises(InputError) as exc, flags_in_errors({"base.position_ecef": "--base-position"}):
        raise InputError("off", field="base.position_ecef")
    assert exc.value.field == "--base-position" and "--base-position" in str(exc.value)
    with pytest.raises(InputError) as exc, flags_in_errors({"rinex_obs": "--rinex-obs"}):
        raise InputError("required", field="rinex_obs")
    assert exc.value.field == "--rinex-obs"
    with pytest.raises(InputError) as exc, flags_in_errors({"gps_sow": "--sow"}):
        raise InputError("bad", "file.csv", 3, "gps_sow")
    assert exc.value.field == "gps_sow" and exc.value.path == "file.csv"


def test_a_missing_input_names_the_flag(tmp_path, capsys):
    assert main(["pos", "--mode", "ppk", "--rinex-obs", "r.rnx", "--rinex-nav", "n.rnx",
                 "--out", str(tmp_path / "o")]) == 2
    assert "--rinex-base" in capsys.readouterr().err


@pytest.mark.parametrize("mode", ["tc", "lc", "ukf"])
def test_glonass_in_tc_or_with_a_base_station_is_refused_naming_the_field(mode):
    """GLONASS serves lc and ukf through their SPP fixes, not tc nor a base station's double differences: a Python
    caller's options with R in the systems of tc, or of lc/ukf with a base station, are refused naming the field,
    before any file is read (the --systems flag drops R with a warning); lc/ukf without a base pass that check."""
    from dataclasses import replace

    from dgcal.pos.gnss_ins import run_gnss_ins
    opts = (UkfModeOptions() if mode == "ukf" else InsModeOptions(mode=mode))
    opts.imu = replace(opts.imu, path="imu.csv")
    opts.spp = replace(opts.spp, systems="GR")
    opts.base = replace(opts.base, rinex="base.rnx")
    with pytest.raises(InputError, match="GLONASS") as exc:
        run_gnss_ins(opts)
    assert exc.value.field == "spp.systems"
    opts.base = replace(opts.base, rinex=None)
    with pytest.raises(InputError) as exc:
        run_gnss_ins(opts)
    assert ("GLONASS" in str(exc.value)) == (mode == "tc")


def test_campaign_pos_step_with_a_ubx_rover_needs_no_navigation_file(tmp_path):
    """[pos] rinex_obs = a u-blox UBX log: its own ephemerides serve, rinex_nav may be left out; a RINEX rover still
    needs one (named as the campaign field)."""
    import shutil
    from pathlib import Path

    from dgcal.commands.pos import campaign_steps
    from dgcal.steps import Campaign
    ubx = tmp_path / "rover.ubx"
    shutil.copy(Path(__file__).parents[1] / "pos" / "gnss" / "data" / "walk_0827_60s.ubx", ubx)
    (tmp_path / "rover.obs").write_text(f"{'3.04':>9}{'':11}{'OBSERVATION DATA':<20}{'M':<20}RINEX VERSION / TYPE\n")
    cfg = {"_path": tmp_path / "c.toml", "_base": tmp_path, "crs": "EPSG:32613",
           "pos": {"mode": "tc", "imu": "imu.csv", "events": "events.csv", "rinex_obs": "rover.ubx"}}
    c = Campaign(cfg, tmp_path / "out")
    campaign_steps(c)
    argv = c.steps[-1].argv
    assert argv[argv.index("--rinex-obs") + 1] == str(ubx) and "--rinex-nav" not in argv
    cfg["pos"]["rinex_obs"] = "rover.obs"
    with pytest.raises(InputError, match="needs 'rinex_nav'") as exc:
        campaign_steps(Campaign(cfg, tmp_path / "out2"))
    assert exc.value.field == "pos.rinex_nav"
