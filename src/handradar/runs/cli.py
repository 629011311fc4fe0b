"""The one error handler of every console entry point: a single line on stderr and a conventional exit status.

- :class:`~handradar.errors.HandradarError` (bad input: the message names the file and the problem):
  ``error: <message>`` and exit status 1;
- :class:`OSError` (an output folder that is a file or read-only, a full disk, ...): ``error: <path>:
  <OS reason>`` and exit status 1;
- a missing mandatory config value (``???``), or an option of the wrong form (:class:`~handradar.errors.
  UsageError`, e.g. ``strict=off``): the usage line and the key, exit status 2;
- a command-line override Hydra's lexer cannot read (a non-ASCII letter, a bracket in an unquoted
  path): the argument and how to quote it, exit status 2 (:func:`hydra_overrides_checked`, before Hydra runs);
- Ctrl-C (SIGINT) and SIGTERM (what ``timeout``, SLURM and container runtimes send): ``interrupted;
  nothing written to <target>`` and exit status 130 / 143 (128 + the signal number, the shell convention).

SIGTERM is turned into :class:`Terminated`, a :class:`KeyboardInterrupt`, so that every clean-up a
Ctrl-C runs (atomic writes removing their temporary file) also runs on SIGTERM.
"""

from __future__ import annotations

import contextlib
import functools
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import InterpolationToMissingValueError, MissingMandatoryValue

from handradar.errors import HandradarError, UsageError

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
        if isinstance(exc, UsageError):
            fail(f"usage: {usage}\nerror: {exc}", EXIT_USAGE)
        if isinstance(exc, (HandradarError, *errors)):
            fail(_with_note(f"error: {exc}", note()), EXIT_ERROR)
        if isinstance(exc, OSError):
            fail(_with_note(f"error: {os_error_line(exc)}", note()), EXIT_ERROR)
        raise
    raise AssertionError("unreachable: fail() exits")


TRUE_FALSE = {"true": True, "false": False}


def bool_option(key: str, value: object) -> bool:
    """``value`` of the boolean option ``key``: true or false only (Hydra reads ``true``/``false`` in any
    case as booleans). Any other value raises UsageError naming both: ``strict=off`` would otherwise be
    the non-empty string "off", which Python takes as true."""
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.lower() in TRUE_FALSE:  # quoted, or from an interpolation
        return TRUE_FALSE[value.lower()]
    if isinstance(value, np.bool_):  # from a Python caller
        return bool(value)
    raise UsageError(f"{key} must be true or false, found {value!r:.60}")


def shell_quoted(override: str) -> str:
    """``override`` with its value quoted for Hydra, inside shell quotes: ``"root='/a b'"``."""
    key, sep, value = override.partition("=")
    if not sep:
        return f"'{override}'"
    if "'" in value:
        return f"'{key}=\"{value}\"'"
    return f"\"{key}='{value}'\""


def unparsable_override(argv: Sequence[str]) -> str | None:
    """A one-line error for the first command-line override Hydra's grammar cannot read, with how to
    quote it; None when every override parses (or Hydra's parser cannot be loaded)."""
    try:
        from hydra._internal.utils import get_args_parser
        from hydra.core.override_parser.overrides_parser import OverridesParser
        from hydra.errors import OverrideParseException
    except ImportError:  # another Hydra: let it report
        return None
    try:
        overrides = get_args_parser().parse_known_args(list(argv))[0].overrides
    except SystemExit:  # a malformed flag: Hydra's own parser will say so
        return None
    parser = OverridesParser.create()
    for override in overrides:
        try:
            parser.parse_overrides([override])
        except OverrideParseException as exc:
            reason = str(exc).splitlines()[0]
            lexer = "LexerNoViableAltException" in reason
            why = ("Hydra reads an unquoted value of ASCII letters, digits and a few signs only" if lexer
                   else f"Hydra's override grammar: {reason}")
            return (f"cannot read the argument {override!r} ({why}); quote the value for Hydra inside the "
                    f"shell's quotes: {shell_quoted(override)}")
    return None


def hydra_overrides_checked(usage: str) -> Callable[[Callable[..., T]], Callable[..., T]]:
    """Decorate a ``@hydra.main`` entry point: before Hydra runs, an override its lexer cannot read
    ends in the usage line, the argument and how to quote it, exit status 2 (Hydra would print its
    lexer error, which never says to quote). Calls with arguments (a passed config) go straight through."""
    def wrap(main: Callable[..., T]) -> Callable[..., T]:
        @functools.wraps(main)
        def checked(*args: Any, **kwargs: Any) -> T:
            if not args and not kwargs:
                line = unparsable_override(sys.argv[1:])
                if line is not None:
                    print(f"usage: {usage}\nerror: {line}", file=sys.stderr, flush=True)
                    sys.exit(EXIT_USAGE)
            return main(*args, **kwargs)
        return checked
    return wrap
