"""Every numeric option is checked where it is read (dgcal.arg_types): a negative sigma, a significance level
outside (0, 1), NaN or inf, an elevation mask beyond 90 degrees is a usage error naming the option (exit 2),
never a silent result (issue 31)."""
from __future__ import annotations

import pytest

from dgcal.cli import main


@pytest.mark.parametrize("argv, flag", [
    (["field", "--sigma-xy", "-1"], "--sigma-xy"),
    (["compare", "--alpha", "2"], "--alpha"),
    (["georef", "--height", "nan"], "--height"),
    (["georef", "--sigma-px", "0"], "--sigma-px"),
    (["pos", "--elev-mask", "95"], "--elev-mask"),
    (["pos", "--code-sigma", "inf"], "--code-sigma"),
    (["pos", "--t-start", "nan"], "--t-start"),
    (["mount", "--pos-common-fraction", "1.5"], "--pos-common-fraction"),
    (["triangulate", "--sigma-px", "-0.5"], "--sigma-px"),
    (["camera", "--max-frames", "0"], "--max-frames"),
    (["sync", "--tau", "-1"], "--tau"),
    (["check", "--pos-correlation-time", "-5"], "--pos-correlation-time"),
    (["simulate", "campaign", "--delay", "nan"], "--delay"),
])
def test_an_out_of_range_number_is_a_usage_error_naming_the_option(argv, flag, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert flag in err and ("must be" in err or "finite" in err), err


def test_a_number_in_range_passes_the_check():
    import dgcal.arg_types as arg_types
    assert arg_types.positive("0.5") == 0.5 and arg_types.probability("0.01") == 0.01
    assert arg_types.fraction("1") == 1.0 and arg_types.elevation_deg("0") == 0.0 and arg_types.positive_int("3") == 3
    assert arg_types.finite("-1e3") == -1000.0 and arg_types.non_negative("0") == 0.0


@pytest.mark.parametrize("verb", ["gnss", "pos"])
def test_simulators_constellations_are_letters_of_gecjr(verb, capsys):
    """`dgcal simulate gnss|pos --systems`: one checked type (dgcal.arg_types.constellations) for both."""
    from dgcal import arg_types
    assert arg_types.constellations("grg") == ("G", "R")
    with pytest.raises(SystemExit) as exc:
        main(["simulate", verb, "--out", "x", "--systems", "GX"])
    assert exc.value.code == 2 and "--systems" in capsys.readouterr().err
