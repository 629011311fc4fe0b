"""Hydra job helpers: the job's output folder, its command line and a callback that reports every job of a multirun.

:func:`output_dir` is the folder Hydra made for the running job, :func:`command_line` the command
that reproduces it. :class:`JobReport`: Hydra's launchers already run the remaining jobs when one raises (the exception is stored in the
job's return); this callback makes the outcome visible: each job appends a line to
``<sweep dir>/jobs.jsonl`` (number, overrides, status, run dir, error) as it ends, in its own
process (so joblib and SLURM workers report too), and the end of the multirun prints a summary
and writes ``<sweep dir>/jobs_summary.txt``. Hydra's sweeper re-raises a failed job's exception
before ``on_multirun_end``, so the summary is also registered to print at interpreter exit.
"""

from __future__ import annotations

import atexit
import json
import logging
import shlex
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from hydra.core.utils import JobReturn, JobStatus
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig

from handradar.atomic import file_lock

log = logging.getLogger(__name__)
REPORT = "jobs.jsonl"


class JobReport(Callback):
    def __init__(self) -> None:
        self._summarised = False

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        atexit.register(self._summary, Path(config.hydra.sweep.dir))

    def on_job_end(self, config: DictConfig, job_return: JobReturn, **kwargs: Any) -> None:
        hydra = config.hydra
        if hydra.mode != RunMode.MULTIRUN:
            return
        failed = job_return.status == JobStatus.FAILED
        error = job_return._return_value if failed else None
        entry = {"num": int(hydra.job.num), "overrides": list(job_return.overrides or []),
                 "status": "FAILED" if failed else "COMPLETED", "run_dir": str(hydra.runtime.output_dir),
                 "error": None if error is None else f"{type(error).__name__}: {error}"}
        sweep = Path(hydra.sweep.dir)
        sweep.mkdir(parents=True, exist_ok=True)
        with file_lock(sweep / f"{REPORT}.lock"):
            with open(sweep / REPORT, "a") as fh:
                fh.write(json.dumps(entry) + "\n")
        if failed:
            log.error("job %d (%s) FAILED: %s", entry["num"], " ".join(entry["overrides"]), entry["error"])

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        self._summary(Path(config.hydra.sweep.dir))

    def _summary(self, sweep: Path) -> None:
        if self._summarised:
            return
        self._summarised = True
        path = sweep / REPORT
        entries = [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.is_file() else []
        entries.sort(key=lambda e: e["num"])
        failed = [e for e in entries if e["status"] != "COMPLETED"]
        lines = [f"multirun: {len(entries) - len(failed)} of {len(entries)} jobs completed, {len(failed)} failed ({sweep})"]
        for e in entries:
            lines.append(f"  #{e['num']} {e['status']:9s} {' '.join(e['overrides'])}  {e['run_dir']}"
                         + (f"\n      {e['error']}" if e["error"] else ""))
        text = "\n".join(lines)
        (sweep / "jobs_summary.txt").write_text(text + "\n")
        print(text, flush=True)


def output_dir() -> Path:
    """The running Hydra job's output folder (``hydra.runtime.output_dir``)."""
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)


def command_line(script: str, skip: Iterable[str] = ()) -> str | None:
    """``python SCRIPT`` with the running Hydra job's command-line overrides, shell-quoted; overrides of a
    key in ``skip`` (e.g. where outputs go) are left out. None outside a Hydra job (nothing to tell)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return None
    skip = set(skip)
    kept = [o for o in HydraConfig.get().overrides.task if o.split("=", 1)[0].lstrip("+~") not in skip]
    return " ".join(["python", script, *map(shlex.quote, kept)])


def group_choice(group: str) -> str | None:
    """The option the running Hydra job chose for config ``group`` (e.g. ``world`` -> ``heldout2``);
    None outside a Hydra job or when the group is not in its defaults."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return None
    choice = HydraConfig.get().runtime.choices.get(group)
    return None if choice is None else str(choice)


def invocation(skip: Iterable[str] = ()) -> str | None:
    """The running Hydra job as a command: ``python train.py <overrides>`` for a script, ``<entry point>
    <overrides>`` for a console entry point (:func:`command_line`); None outside a Hydra job."""
    import sys

    script = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else "python"
    cmd = command_line(script, skip)
    return cmd if cmd is None or script.endswith(".py") else cmd.removeprefix("python ")
