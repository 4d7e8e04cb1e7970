"""The one exception type for bad user input; its message names the file, line and field."""
from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad input data: the message is one line naming the file, line and field at fault."""

    def __init__(self, message: str, path: str | Path | None = None, line: int | None = None,
                 field: str | None = None):
        where = ""
        if path is not None:
            where = str(path)
            if line is not None:
                where += f":{line}"
            where += ": "
        if field is not None:
            message = f"field '{field}': {message}"
        super().__init__(where + message)
        self.path, self.line, self.field = path, line, field


class ResultError(InputError):
    """A result that cannot be trusted from these inputs (no convergence, sigma0 far from 1, images left out):
    the message gives the figures that failed; the command exits non-zero and writes nothing."""
