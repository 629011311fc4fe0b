"""Error types that name the offending file and the problem (expected vs found)."""

from __future__ import annotations

from pathlib import Path


class HandradarError(Exception):
    """Base class of every error raised for bad user input."""


class FormatError(HandradarError, ValueError):
    """A file does not follow its format; the message names the file and the problem."""

    def __init__(self, path: str | Path | None, problem: str, *, line: int | None = None) -> None:
        self.path = None if path is None else Path(path)
        self.problem = problem
        self.line = line
        where = "<input>" if path is None else str(path)
        if line is not None:
            where = f"{where}:{line}"
        super().__init__(f"{where}: {problem}")
