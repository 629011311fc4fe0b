"""Stage-by-stage progress of a long job on the log: ``[i/n] stage``, the elapsed time and what comes next."""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterator, Sequence

log = logging.getLogger(__name__)


def clock_text(seconds: float) -> str:
    """``m:ss`` (``h:mm:ss`` from an hour on) of a duration in seconds."""
    s = int(round(seconds))
    h, rest = divmod(s, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


class Stages:
    """The planned stages of a job, announced as they start and finish.

    ``with stages("name"):`` logs ``[i/n] name (elapsed m:ss; then: next)`` at the start and
    ``[i/n] name done in N s`` at the end; ``durations`` keeps each stage's seconds. A stage
    outside the plan is announced without a number.
    """

    def __init__(self, names: Sequence[str], *, logger: logging.Logger = log,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.names = list(names)
        self.log = logger
        self.clock = clock
        self.t0 = clock()
        self.durations: dict[str, float] = {}

    def elapsed(self) -> float:
        return self.clock() - self.t0

    def _label(self, name: str) -> str:
        return f"[{self.names.index(name) + 1}/{len(self.names)}] {name}" if name in self.names else name

    def _next(self, name: str) -> str:
        if name not in self.names:
            return ""
        i = self.names.index(name)
        return f"; then: {self.names[i + 1]}" if i + 1 < len(self.names) else "; last stage"

    @contextlib.contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        self.log.info("%s (elapsed %s%s)", self._label(name), clock_text(self.elapsed()), self._next(name))
        t = self.clock()
        yield
        self.durations[name] = self.clock() - t
        self.log.info("%s done in %.0f s", self._label(name), self.durations[name])
