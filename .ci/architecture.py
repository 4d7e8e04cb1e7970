#!/usr/bin/env python3
"""Architecture checks of docs/architecture.md: the layer order (import-linter), no private names imported
from another module, no bare `fields`/`calib`/... imports, every module listed in docs/architecture.md. Exit
status 0 when all hold, 1 otherwise.

import-linter analyses a package by walking its folder; dgcal's sub-packages live in the top-level folders
(setuptools `package-dir`), so the check runs on a mirror of the tree in the installed layout
(`dgcal/fields`, `dgcal/calib`, ...) made of hard links (or copies) in a temporary folder.

    python .ci/architecture.py [ROOT]     # ROOT defaults to the checkout holding this file
    python .ci/architecture.py --write-module-table    # regenerate the module table of docs/architecture.md
"""
from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

SUBPACKAGES = ("fields", "calib", "bundle", "pos", "reports", "sim")   # folders that are dgcal.<name>
CODE_DIRS = SUBPACKAGES + ("dgcal",)


def mirror(root: Path, dest: Path) -> Path:
    """The tree of `root` in the installed layout under `dest` (dest/dgcal/...); returns dest."""
    def copy(src: Path, dst: Path) -> None:
        try:
            shutil.copytree(src, dst, copy_function=os.link, ignore=shutil.ignore_patterns("__pycache__"))
        except OSError:   # another file system: plain copies
            shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__"), dirs_exist_ok=True)
    copy(root / "dgcal", dest / "dgcal")
    for name in SUBPACKAGES:
        copy(root / name, dest / "dgcal" / name)
    return dest


def layer_contracts(root: Path, tree: Path) -> tuple[bool, str]:
    """Run import-linter with root's pyproject.toml on a mirrored tree; (kept, report)."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    exe = Path(sys.executable).with_name("lint-imports")
    cmd = [str(exe) if exe.exists() else "lint-imports", "--no-cache", str(root / "pyproject.toml")]
    out = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    return out.returncode == 0, (out.stdout + out.stderr).strip()


def import_violations(root: Path) -> list[str]:
    """Private names imported from another module, and bare imports of dgcal's sub-packages."""
    problems = []
    files = [p for d in CODE_DIRS for p in (root / d).rglob("*.py")]
    others = [p for d in ("tests", "bench") for p in (root / d).rglob("*.py")]
    for path in sorted(files) + sorted(others):
        is_code = path in files
        src = path.read_text(encoding="utf-8")
        tree = ast.parse(src, filename=str(path))
        rel = path.relative_to(root)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                mods = [node.module]
            else:
                continue
            for mod in mods:
                if mod.split(".")[0] in SUBPACKAGES:
                    problems.append(f"{rel}:{node.lineno}: bare import of {mod} (use dgcal.{mod})")
            if is_code and isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("dgcal."):
                target = node.module
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__"):
                        # a private name is its module's own: what another module needs is made public
                        problems.append(f"{rel}:{node.lineno}: private name {a.name} of {target} imported")
    return problems


MAP = Path("docs") / "architecture.md"
BEGIN, END = "<!-- modules:begin -->", "<!-- modules:end -->"


def module_rows(root: Path) -> list[tuple[str, str]]:
    """(path, first sentence of its docstring) of every module and documented package of the code folders."""
    rows = []
    for top in ("fields", "calib", "bundle", "pos", "reports", "sim", "dgcal"):
        for path in sorted((root / top).rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            rel = path.relative_to(root)
            doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
            if path.name == "__init__.py":
                if not doc:
                    continue
                name = f"{rel.parent}/"
            else:
                name = str(rel)
            first = " ".join(doc.split("\n\n")[0].split()).replace("|", "/")
            rows.append((name, first if len(first) <= 160 else first[:157].rsplit(" ", 1)[0] + " ..."))
    return rows


def write_module_table(root: Path) -> None:
    """Regenerate the "where does X live" table of docs/architecture.md from the modules' docstrings."""
    doc = (root / MAP).read_text(encoding="utf-8")
    table = "| module | holds |\n|---|---|\n" + "\n".join(f"| `{n}` | {d} |" for n, d in module_rows(root))
    a, b = doc.index(BEGIN) + len(BEGIN), doc.index(END)
    (root / MAP).write_text(doc[:a] + "\n" + table + "\n" + doc[b:], encoding="utf-8")


def unmapped_modules(root: Path) -> list[str]:
    """Modules missing from the table of docs/architecture.md."""
    doc = (root / MAP).read_text(encoding="utf-8")
    return [f"{n} is not in {MAP} (run .ci/architecture.py --write-module-table)"
            for n, _ in module_rows(root) if f"`{n}`" not in doc]


def main(argv: list[str]) -> int:
    if "--write-module-table" in argv:
        argv = [a for a in argv if a != "--write-module-table"]
        write_module_table(Path(argv[1]).resolve() if len(argv) > 1 else Path(__file__).resolve().parents[1])
    root = Path(argv[1]).resolve() if len(argv) > 1 else Path(__file__).resolve().parents[1]
    ok = True
    with tempfile.TemporaryDirectory(prefix="dgcal-arch-") as tmp:
        kept, report = layer_contracts(root, mirror(root, Path(tmp)))
    if not kept:
        ok = False
        print(report)
    problems = import_violations(root) + unmapped_modules(root)
    for p in problems:
        print(p)
    ok &= not problems
    print("architecture: layers kept, imports clean" if ok else "architecture: VIOLATIONS (see above)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
