"""The architecture of docs/architecture.md holds: layers, private names, one namespace, packages listed."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _checker():
    spec = importlib.util.spec_from_file_location("dgcal_architecture_check", ROOT / ".ci" / "architecture.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_tree_keeps_its_layers_and_import_rules():
    out = subprocess.run([sys.executable, str(ROOT / ".ci" / "architecture.py")], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_an_upward_import_breaks_the_layer_contract(tmp_path):
    arch = _checker()
    tree = arch.mirror(ROOT, tmp_path / "tree")
    kept, _ = arch.layer_contracts(ROOT, tree)
    assert kept
    # the base layer importing a report: a deliberate violation in the mirror (the checkout is untouched)
    bad = tree / "dgcal" / "fields" / "upward.py"
    bad.write_text("from dgcal.reports import html\n")
    kept, report = arch.layer_contracts(ROOT, tree)
    assert not kept
    assert "dgcal.fields.upward -> dgcal.reports.html" in report
    bad.unlink()
    kept, _ = arch.layer_contracts(ROOT, tree)
    assert kept


def test_private_and_bare_imports_are_found(tmp_path):
    arch = _checker()
    for d in arch.CODE_DIRS + ("tests", "bench"):
        (tmp_path / d).mkdir()
    (tmp_path / "pos" / "a.py").write_text("from dgcal.sim.gnss import _load_nav\n")
    (tmp_path / "tests" / "t.py").write_text("from calib.camera.models import Fraser7\n")
    problems = arch.import_violations(tmp_path)
    assert any("private name _load_nav" in p for p in problems)
    assert any("bare import of calib.camera.models" in p for p in problems)
    assert len(problems) == 2


def test_every_package_folder_is_installed_under_dgcal():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    found = set()
    for init in ROOT.glob("*/**/__init__.py"):
        rel = init.parent.relative_to(ROOT)
        if rel.parts[0] in _checker().CODE_DIRS:
            parts = rel.parts if rel.parts[0] == "dgcal" else ("dgcal",) + rel.parts
            found.add(".".join(parts))
    assert listed == found
    assert cfg["package-dir"] == {"dgcal": "dgcal", **{f"dgcal.{n}": n for n in _checker().SUBPACKAGES}}


def test_only_the_dgcal_namespace_is_importable_outside_the_checkout(tmp_path):
    code = ("import importlib.util as u, dgcal.calib.camera.models, dgcal.fields.errors;"
            "print([n for n in ('fields','calib','bundle','pos','reports','sim') if u.find_spec(n)])")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
