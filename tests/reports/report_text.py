"""What a reader sees on a report page, checked: the visible text (no figures' base64, no style), its tables, and
the problems issue 30 lists — raw snake_case keys, e± number notation, Python list/dict reprs, numeric columns
without a unit in their header."""
from __future__ import annotations

import re
from html.parser import HTMLParser

RAW_KEY = re.compile(r"(?<![\w./\\-])[a-z][a-z0-9]*_[a-z0-9_]*[a-z0-9](?![\w.(/\\-])")
E_NOTATION = re.compile(r"\d\.?\d*[eE][+-]?\d+\b")
REPR = re.compile(r"\[\s*[-+]?\d|\[\s*'|\{'|\barray\(|\bnp\.float|\bNone\b|\bnan\b|\binf\b")
BARE = {"True", "False", "None", "nan", "inf", "-inf"}   # Python's words as a cell's whole text
NUMBER = re.compile(r"^[+-]?\d+(\.\d+)?$")
DECIMAL = re.compile(r"^[+-]?\d+\.\d+$")
# headers of decimal columns that need no unit: ratios and dimensionless statistics
UNITLESS = re.compile(r"\(|σ0|sigma0|ratio|/σ|/ σ|/sigma|χ²|NIS|PDOP|correlation|^r$", re.I)
ALLOWED_RAW = {"R_cam_to_body", "R_nominal"}


class _Page(HTMLParser):
    """The page's visible text and its tables (rows of cells; each cell (is_header, text))."""

    def __init__(self):
        super().__init__()
        self.text: list[str] = []
        self.tables: list[list[list[tuple[bool, str]]]] = []
        self._skip = 0
        self._cell: list[str] | None = None
        self._is_th = False

    def handle_starttag(self, tag, attrs):
        if tag in ("style", "script", "title"):
            self._skip += 1
        elif tag == "table":
            self.tables.append([])
        elif tag == "tr" and self.tables:
            self.tables[-1].append([])
        elif tag in ("td", "th"):
            self._cell, self._is_th = [], tag == "th"

    def handle_endtag(self, tag):
        if tag in ("style", "script", "title"):
            self._skip -= 1
        elif tag in ("td", "th") and self._cell is not None and self.tables and self.tables[-1]:
            self.tables[-1][-1].append((self._is_th, " ".join(self._cell).strip()))
            self._cell = None

    def handle_data(self, data):
        if self._skip:
            return
        self.text.append(data)
        if self._cell is not None:
            self._cell.append(data.strip())


def parse(page: str) -> _Page:
    p = _Page()
    p.feed(page)
    return p


def problems(page: str) -> list[str]:
    """Everything on `page` (HTML text) a surveyor should not see; empty when the page is clean."""
    p = parse(page)
    text = " ".join(p.text)
    out = []
    for m in RAW_KEY.finditer(text):
        if m.group(0) not in ALLOWED_RAW and not re.search(r"R_cam_to_body|_to_", m.group(0)):
            out.append(f"raw key {m.group(0)!r}: …{text[max(0, m.start() - 40):m.end() + 40]}…")
    for m in E_NOTATION.finditer(text):
        out.append(f"e notation {m.group(0)!r}: …{text[max(0, m.start() - 40):m.end() + 20]}…")
    for m in REPR.finditer(text):
        out.append(f"Python repr {m.group(0)!r}: …{text[max(0, m.start() - 40):m.end() + 40]}…")
    for t in p.tables:
        out += _table_problems(t)
        out += [f"Python value {c!r} in a table" for r in t for _, c in r if c in BARE]
    return out


def _table_problems(rows: list[list[tuple[bool, str]]]) -> list[str]:
    """A column of decimal numbers needs a unit (or a unitless statistic) in its header; a key/value row with a
    decimal value needs one in its name."""
    out = []
    if not rows:
        return out
    head = rows[0]
    if len(head) > 1 and all(is_th for is_th, _ in head):     # a header row
        if "unitless" in head[0][1]:                           # a matrix: correlations, a rotation
            return out
        for j, (_, name) in enumerate(head):
            cells = [r[j][1] for r in rows[1:] if j < len(r) and not r[j][0]]
            if any(DECIMAL.match(c) for c in cells) and not UNITLESS.search(name):
                out.append(f"column {name!r} has numbers but no unit: {cells[:3]}")
    else:                                                      # key/value rows
        for r in rows:
            if len(r) == 2 and r[0][0] and DECIMAL.match(r[1][1]) and not UNITLESS.search(r[0][1]):
                out.append(f"row {r[0][1]!r} has a number but no unit: {r[1][1]}")
    return out
