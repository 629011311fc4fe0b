"""Console entry points (thin Hydra apps) and the error handling train.py and diagnose.py share."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from omegaconf import DictConfig


def run_job(job: Callable[[DictConfig], Path], cfg: DictConfig, *, usage: str | None = None) -> None:
    """Run ``job(cfg)`` and print the path it returns as the last line.

    Errors go through :func:`handradar.runs.cli.run_cli`: a handradar error (bad input, named file
    and problem) or an OS error ends a single run with a one-line message and exit status 1, a
    missing mandatory config value with ``usage`` and exit status 2, Ctrl-C / SIGTERM with exit
    status 130 / 143. In a multirun every failure propagates, so that Hydra's job report records it
    and the other jobs go on.
    """
    import sys

    from handradar.runs.cli import run_cli

    quiet_libraries()
    path = run_cli(lambda: job(cfg), cfg, usage=usage or f"{Path(sys.argv[0]).name} key=value ...",
                   reraise_in_multirun=True)
    print(path, flush=True)


def quiet_libraries() -> None:
    """Keep a job's own log readable: Lightning's per-fit banners (devices, tips) and MLflow's database
    set-up lines only from WARNING (a ``MLFLOW_LOGGING_LEVEL`` the user set wins)."""
    import logging
    import os

    logging.getLogger("lightning.pytorch").setLevel(logging.WARNING)
    if "MLFLOW_LOGGING_LEVEL" not in os.environ:
        os.environ["MLFLOW_LOGGING_LEVEL"] = "WARNING"  # read when mlflow is first imported
        logging.getLogger("mlflow").setLevel(logging.WARNING)  # ... in case it already was
