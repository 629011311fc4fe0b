"""The one error handler of every console entry point: a single line on stderr and a conventional exit status.

- :class:`~handradar.errors.HandradarError` (bad input: the message names the file and the problem):
  ``error: <message>`` and exit status 1;
- :class:`OSError` (an output folder that is a file or read-only, a full disk, ...): ``error: <path>:
  <OS reason>`` and exit status 1;
- a missing mandatory config value (``???``): a usage line naming the missing keys, exit status 2;
- Ctrl-C (SIGINT) and SIGTERM (what ``timeout``, SLURM and container runtimes send): ``interrupted;
  nothing written to <target>`` and exit status 130 / 143 (128 + the signal number, the shell convention).

SIGTERM is turned into :class:`Terminated`, a :class:`KeyboardInterrupt`, so that every clean-up a
Ctrl-C runs (atomic writes removing their temporary file) also runs on SIGTERM.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import InterpolationToMissingValueError, MissingMandatoryValue

from handradar.errors import HandradarError

T = TypeVar("T")

EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 128 + signal.SIGINT  # 130
EXIT_TERMINATED = 128 + signal.SIGTERM  # 143
MISSING = "???"


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread where Ctrl-C raises KeyboardInterrupt."""


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """While inside, SIGTERM raises :class:`Terminated` in the main thread (elsewhere: no change).

    Later SIGTERMs are ignored while the first unwinds, so that its clean-up runs to the end
    (SIGKILL still stops the process); the previous handler is restored on the way out.
    """
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return

    def handler(signum: int, frame: Any) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def missing_keys(cfg: DictConfig | None, exc: BaseException) -> list[str]:
    """Config keys still at ``???`` (in config order); the key ``exc`` names when the config has none."""
    keys: list[str] = []

    def walk(node: Any, prefix: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, f"{prefix}{k}.")
        elif isinstance(node, list):
            for i, v in enumerate(node):
                walk(v, f"{prefix}{i}.")
        elif node == MISSING:
            keys.append(prefix[:-1])

    if cfg is not None:
        walk(OmegaConf.to_container(cfg, resolve=False), "")
    if not keys:
        keys.append(getattr(exc, "full_key", None) or str(exc).splitlines()[0])
    return keys


def _missing_value(exc: BaseException) -> BaseException | None:
    """The missing-config-value error that is ``exc`` or its explicit cause (``raise ... from``), if any."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (MissingMandatoryValue, InterpolationToMissingValueError)):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__  # not __context__: an error raised while handling another is its own
    return None


def os_error_line(exc: OSError) -> str:
    """``<path>: <OS reason>`` for an OSError (both paths for a rename)."""
    reason = exc.strerror or str(exc)
    if exc.filename is None:
        return reason
    if exc.filename2 is not None:
        return f"{exc.filename} -> {exc.filename2}: {reason}"
    return f"{exc.filename}: {reason}"


def _in_multirun() -> bool:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def _with_note(message: str, note: str | None) -> str:
    """``message`` with ``(note)`` at the end of its first line (messages may carry a report below)."""
    if not note:
        return message
    first, sep, rest = message.partition("\n")
    colon = ":" if first.endswith(":") else ""  # "... could be ingested:" introduces the report below
    return f"{first.removesuffix(':')} ({note}){colon}{sep}{rest}"


def run_cli(job: Callable[[], T], cfg: DictConfig | None = None, *, usage: str, target: str | None = None,
            resumable: bool = False, errors: tuple[type[Exception], ...] = (),
            reraise_in_multirun: bool = False) -> T:
    """Run ``job()`` and turn its failures into one line on stderr and an exit status (module docstring).

    usage: the command line shown when a mandatory config value is missing (without ``usage: ``).
    target: config key of the output path; error and interrupt lines say that nothing was written
    there (or, with ``resumable``, that its completed parts are kept: a re-run resumes from them).
    errors: further exception types reported like HandradarError (one line, exit status 1).
    reraise_in_multirun: inside a Hydra multirun, let every failure propagate, so that Hydra's job
    report records it and the other jobs go on.
    """
    def note() -> str | None:
        try:
            value = None if cfg is None or target is None else OmegaConf.select(cfg, target, throw_on_missing=False)
            if value is None or value == MISSING:
                return None
            path = Path(str(value)).resolve()
        except Exception:  # the note is a courtesy: never let it hide the error being reported
            return None
        return f"completed parts are kept in {path}" if resumable else f"nothing written to {path}"

    def fail(line: str, status: int) -> None:
        print(line, file=sys.stderr, flush=True)
        sys.exit(status)

    try:
        with sigterm_as_interrupt():
            return job()
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM as Terminated
        if reraise_in_multirun and _in_multirun():
            raise
        term = isinstance(exc, Terminated)
        where = note()
        fail(f"interrupted{' (SIGTERM)' if term else ''}" + (f"; {where}" if where else ""),
             EXIT_TERMINATED if term else EXIT_INTERRUPTED)
    except Exception as exc:
        if reraise_in_multirun and _in_multirun():
            raise
        missing = _missing_value(exc)  # first: omegaconf's interpolation errors are ValueErrors too
        if missing is not None:
            keys = missing_keys(cfg, missing)
            fail(f"usage: {usage}\nerror: missing value for {', '.join(keys)} "
                 f"(give {' '.join(k + '=...' for k in keys)})", EXIT_USAGE)
        if isinstance(exc, (HandradarError, *errors)):
            fail(_with_note(f"error: {exc}", note()), EXIT_ERROR)
        if isinstance(exc, OSError):
            fail(_with_note(f"error: {os_error_line(exc)}", note()), EXIT_ERROR)
        raise
    raise AssertionError("unreachable: fail() exits")
