"""Error types that name the offending file and the problem (expected vs found)."""

from __future__ import annotations

from pathlib import Path


def printable(text: str) -> str:
    """``text`` with the bytes of a name that is not valid UTF-8 written as ``\\xNN``.

    Python keeps such bytes of a file name as lone surrogates (surrogateescape), which UTF-8 output
    (the console, logs, HDF5 strings) refuses; valid text is returned unchanged.
    """
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:
        pass
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:  # a surrogate that is no escaped byte (e.g. from a JSON "\\ud800")
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


class HandradarError(Exception):
    """Base class of every error raised for bad user input."""


class FormatError(HandradarError, ValueError):
    """A file does not follow its format; the message names the file and the problem."""

    def __init__(self, path: str | Path | None, problem: str, *, line: int | None = None) -> None:
        self.path = None if path is None else Path(path)
        self.problem = problem
        self.line = line
        where = "<input>" if path is None else printable(str(path))
        if line is not None:
            where = f"{where}:{line}"
        super().__init__(f"{where}: {problem}")


class UsageError(HandradarError, ValueError):
    """A command-line option has a value of the wrong form; the message names the key and the value.

    Console entry points answer it with their usage line and exit status 2 (handradar.runs.cli).
    """


class TooFewRows(HandradarError, ValueError):
    """The data hold too few rows for a job; the message states the minimum (rows per gesture, gestures)."""
