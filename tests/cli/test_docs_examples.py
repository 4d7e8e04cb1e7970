"""Every example of README.md, docs/lowcost_payload.md and docs/timesync.md runs as written (issues 15, 30).

Each ```python block is executed in a fresh namespace in its own temporary working directory; it makes its own
inputs with dgcal's simulators and asserts what it shows, so a broken call or a wrong claim fails here. Each
```sh block's `dgcal ...` lines are run in order through `dgcal.cli.main` in a temporary directory and must exit
0; lines that need the user's own files (not written by an earlier `dgcal simulate` line of the block), or that
take minutes (`dgcal demo`, whose campaign tests/cli/test_campaign_acceptance.py runs), are listed in
USER_FILE_LINES and not run — only parsed, so they still match the current CLI — and that list is itself checked
against the docs. The README must show every verb of `dgcal --help` in a block run here.
"""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from dgcal.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
FILES = ("lowcost_payload.md", "timesync.md", "README.md")

# (doc, a substring naming the line) -> why the line cannot run here: it reads the user's own files
USER_FILE_LINES = {
    ("lowcost_payload.md", "--trajectory traj.csv"):
        "needs the user's camera.json, pixels.csv, traj.csv, events.csv, mounting.json and dem.tif",
    ("README.md", "dgcal demo --out"):
        "the full demo campaign takes minutes; tests/cli/test_campaign_acceptance.py runs the same campaign",
}

_FENCE = re.compile(r"^```(\w*)[ \t]*\n(.*?)^```[ \t]*$", re.S | re.M)


def doc_path(doc: str) -> Path:
    """README.md at the repository's root, the others in docs/."""
    return ROOT / doc if doc == "README.md" else DOCS / doc


def blocks(doc: str, lang: str) -> list[str]:
    """The fenced blocks of one language in a doc, in order."""
    return [body for tag, body in _FENCE.findall(doc_path(doc).read_text(encoding="utf-8")) if tag == lang]


def dgcal_lines(block: str) -> list[str]:
    """The `dgcal ...` command lines of a sh block (backslash continuations joined, comments kept for shlex)."""
    out, cur = [], ""
    for raw in block.splitlines():
        line = raw.rstrip()
        if cur:
            cur += " " + line.strip()
        elif line.strip().startswith("dgcal "):
            cur = line.strip()
        else:
            continue
        if cur.endswith("\\"):
            cur = cur[:-1].rstrip()
            continue
        out.append(cur)
        cur = ""
    assert not cur, f"unterminated continuation: {cur!r}"
    return out


def _user_file_reason(doc: str, line: str) -> str | None:
    for (d, key), why in USER_FILE_LINES.items():
        if d == doc and key in line:
            return why
    return None


PY_CASES = [pytest.param(doc, i, id=f"{doc}:python{i}") for doc in FILES for i in range(len(blocks(doc, "python")))]
SH_CASES = [pytest.param(doc, i, id=f"{doc}:sh{i}") for doc in FILES for i in range(len(blocks(doc, "sh")))]


def test_the_docs_have_examples():
    for doc in FILES:
        assert blocks(doc, "python"), f"{doc} has no python example"
        assert any(dgcal_lines(b) for b in blocks(doc, "sh")), f"{doc} has no dgcal command line"


@pytest.mark.parametrize("doc,index", PY_CASES)
def test_python_example(doc, index, tmp_path, monkeypatch):
    code = blocks(doc, "python")[index]
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": f"docs_example_{index}"}
    exec(compile(code, f"{doc_path(doc)}:python block {index}", "exec"), namespace)  # the docs' own code


def test_readme_shows_every_verb():
    """Each verb of the CLI has a line in a README sh block (run by test_sh_example or listed in USER_FILE_LINES)."""
    parser = build_parser(None)
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    shown = {shlex.split(ln, comments=True)[1] for b in blocks("README.md", "sh") for ln in dgcal_lines(b)}
    assert set(sub.choices) <= shown, sorted(set(sub.choices) - shown)


@pytest.mark.parametrize("doc,index", SH_CASES)
def test_sh_example(doc, index, tmp_path, monkeypatch, capsys):
    lines = dgcal_lines(blocks(doc, "sh")[index])
    if not lines:
        pytest.skip("no dgcal command in this block")
    monkeypatch.chdir(tmp_path)
    ran, left_out = 0, []
    for line in lines:
        why = _user_file_reason(doc, line)
        if why is not None:  # not run, but it must still be a valid command line of the current CLI
            argv = shlex.split(line, comments=True)[1:]
            args = build_parser(argv).parse_args(argv)
            assert callable(getattr(args, "_run", None)), line
            left_out.append(f"{line!r}: {why}")
            continue
        try:
            rc = main(shlex.split(line, comments=True)[1:])
        except SystemExit as exc:  # argparse: an option the CLI does not know
            rc = exc.code
        err = capsys.readouterr().err
        assert rc == 0, f"{line!r} exited {rc}:\n{err[-2000:]}"
        ran += 1
    if not ran:
        pytest.skip("; ".join(left_out))


def test_user_file_lines_are_current():
    """Every entry of USER_FILE_LINES names exactly one dgcal line of its doc (no stale or ambiguous marks)."""
    for (doc, key) in USER_FILE_LINES:
        hits = [ln for b in blocks(doc, "sh") for ln in dgcal_lines(b) if key in ln]
        assert len(hits) == 1, (doc, key, hits)
