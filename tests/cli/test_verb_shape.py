"""Every verb has one shape (argparse in dgcal/commands, options -> library -> writer), the simulators'
command line lives in dgcal.simulators, and the campaign is built from the steps the verbs declare."""
import ast
import importlib
import pkgutil
import subprocess
import sys
from pathlib import Path

import dgcal.commands
import dgcal.sim
import dgcal.simulators
from dgcal.campaign import CHAIN

ROOT = Path(__file__).resolve().parents[2]
LIBRARY = ("fields", "calib", "bundle", "pos", "reports", "sim")


def test_no_argparse_below_the_command_line():
    for d in LIBRARY:
        for path in (ROOT / d).rglob("*.py"):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    assert all(a.name != "argparse" for a in node.names), path
                elif isinstance(node, ast.ImportFrom):
                    assert node.module != "argparse", path


def test_simulators_are_sub_commands_and_sim_keeps_the_library():
    names = {m.name for m in pkgutil.iter_modules(dgcal.simulators.__path__)}
    assert names == {"block", "camera_field", "campaign", "flight", "forward_camera", "gnss", "imu", "logger",
                     "lowcost", "mounting", "pos", "robot", "rover"}
    for name in names:
        mod = importlib.import_module(f"dgcal.simulators.{name}")
        assert mod.NAME and mod.HELP and callable(mod.add_arguments) and callable(mod.run)
        assert mod.DESCRIPTION.strip()  # --help shows the simulator's own module documentation
    for info in pkgutil.iter_modules(dgcal.sim.__path__):
        src = (Path(dgcal.sim.__path__[0]) / f"{info.name}.py").read_text(encoding="utf-8")
        top = {n.name for n in ast.parse(src).body if isinstance(n, ast.FunctionDef)}
        assert not top & {"add_arguments", "run"}, info.name


def test_simulate_help_shows_the_simulators_documentation():
    out = subprocess.run([sys.executable, "-m", "dgcal", "simulate", "logger", "--help"], capture_output=True,
                         text=True, check=True).stdout
    assert "crystal-clocked logger" in out and "--duration" in out


def test_campaign_verbs_declare_their_steps():
    assert [v.NAME for v in CHAIN] == ["camera", "triangulate", "pos", "mount", "check"]
    for v in CHAIN:
        assert isinstance(v.SECTION, str) and callable(v.campaign_steps)
        outputs = getattr(v, "INS_OUTPUTS", None) or v.OUTPUTS
        assert outputs and all(isinstance(k, str) and isinstance(f, str) for k, f in outputs.items())
    for info in pkgutil.iter_modules(dgcal.commands.__path__):
        mod = importlib.import_module(f"dgcal.commands.{info.name}")
        assert callable(mod.add_arguments) and callable(mod.run), info.name
