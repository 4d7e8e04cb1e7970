import subprocess
import sys

from dgcal.cli import build_parser


def test_help_lists_every_verb_and_simulator_without_importing_them():
    code = ("import sys; from dgcal.cli import build_parser\n"
            "p = build_parser(['mount', '--help'])\n"
            "h = p.format_help()\n"
            "heavy = [m for m in ('gtsam', 'pycolmap', 'cv2', 'scipy.signal', 'dgcal.sim.imu') if m in sys.modules]\n"
            "print(heavy); print(h)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines()[0] == "[]"
    for verb in ("camera", "triangulate", "pos", "mount", "check", "export", "compare", "run", "demo", "sync",
                 "simulate"):
        assert f"    {verb}" in out, verb


def test_the_chosen_verb_and_simulator_get_their_options():
    a = build_parser(["simulate", "logger", "--out", "x", "--seed", "3"]).parse_args(
        ["simulate", "logger", "--out", "x", "--seed", "3"])
    assert a.verb == "simulate" and a.what == "logger" and a.seed == 3 and callable(a._sim_run)
    full = build_parser()  # every verb loaded: what the campaign runner's argv check uses
    assert full.parse_args(["simulate", "camera-field", "--out", "y"]).what == "camera-field"


def test_an_unexpected_failure_is_one_line_and_exit_3(monkeypatch, capsys):
    import dgcal.commands.compare as compare_verb
    from dgcal.cli import main as cli_main

    def broken(args):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(compare_verb, "run", broken)
    rc = cli_main(["compare", "a.json", "b.json"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 3 and len(err) == 1
    assert "internal error: ZeroDivisionError" in err[0] and "--debug" in err[0]
