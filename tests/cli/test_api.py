"""The public API: every listed name imports from dgcal.api and from the package, and the README lists them."""
import subprocess
import sys
from pathlib import Path

import dgcal
from dgcal import api

ROOT = Path(__file__).resolve().parents[2]


def test_every_api_name_is_importable_and_the_same_object_on_the_package():
    for name in api.__all__:
        assert getattr(dgcal, name) is getattr(api, name), name
    assert set(api.__all__) <= set(dir(dgcal))


def test_the_issue_names_are_there():
    from dgcal.api import (MapGrid, calibrate_camera, calibrate_mounting, dg_eop, read_any_measurements,  # noqa: F401
                           read_camera, run_pos, triangulate, write_camera)


def test_importing_the_package_stays_light():
    code = "import sys, dgcal; print(int('dgcal.api' in sys.modules), int('scipy' in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["0", "0"]


def test_readme_lists_the_api():
    readme = (ROOT / "README.md").read_text()
    missing = [n for n in api.__all__ if f"`{n}`" not in readme]
    assert not missing, missing


def test_write_camera_round_trips_each_format(tmp_path):
    cam = api.Fraser7((4000, 3000), [3500.0, 2000, 1500, -0.05, 0.01, 0.001, 1e-4, -2e-4, 0.0, 0.0])
    for suffix in (".json", ".yaml", ".txt", ".xml"):
        err = api.write_camera(tmp_path / f"cam{suffix}", cam)
        back = api.read_camera(tmp_path / f"cam{suffix}", "fraser7")
        uv = cam.project([[0.3, -0.2, 1.0], [-0.4, 0.3, 1.0]])
        assert abs(back.project([[0.3, -0.2, 1.0], [-0.4, 0.3, 1.0]]) - uv).max() < max(1e-6, 2 * err), suffix


def test_pycolmap_then_dgcal_reports_do_not_abort():
    # importing dgcal first (as the CLI does) loads zlib before pycolmap: PNG figures are safe
    code = ("import dgcal, pycolmap\n"
            "from dgcal.reports.html import HtmlReport, new_figure\n"
            "fig, ax = new_figure(3, 2); ax.plot([0, 1], [0, 1]); r = HtmlReport('x'); r.figure(fig, 'c')\n"
            "import zlib; zlib.compress(bytes(1_000_000)); print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-500:]
    # the other order cannot be repaired afterwards: dgcal says so instead of letting the process abort later
    out = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-c", "import pycolmap, dgcal"],
                         capture_output=True, text=True)
    assert out.returncode != 0 and "import dgcal (or zlib) before pycolmap" in out.stderr
