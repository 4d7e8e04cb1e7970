"""The one exception type for bad user input; its message names the file, line and field."""
from __future__ import annotations

from pathlib import Path


def one_line(text: str) -> str:
    """`text` on one line: line breaks (and the blanks around them) become one space; other control characters
    (a file's bytes quoted in a message) are shown escaped."""
    out = []
    for part in str(text).replace("\r\n", "\n").replace("\r", "\n").split("\n"):
        out.append(part.strip() if out else part.rstrip())
    s = " ".join(p for p in out if p) if len(out) > 1 else out[0]
    return "".join(c if c.isprintable() or c == " " else repr(c)[1:-1] for c in s)


class InputError(ValueError):
    """Bad input data: the message is one line naming the file, line and field at fault."""

    def __init__(self, message: str, path: str | Path | None = None, line: int | None = None,
                 field: str | None = None):
        self.reason = message   # the message without the location (to raise it again for another file)
        where = ""
        if path is not None:
            where = str(path)
            if line is not None:
                where += f":{line}"
            where += ": "
        if field is not None:
            message = f"field '{field}': {message}"
        super().__init__(one_line(where + str(message)))
        self.path, self.line, self.field = path, line, field


class ResultError(InputError):
    """A result that cannot be trusted from these inputs (no convergence, sigma0 far from 1, images left out):
    the message gives the figures that failed; the command exits non-zero and writes nothing."""
