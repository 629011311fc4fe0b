"""Console entry points (thin Hydra apps) and the error handling train.py and diagnose.py share."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

from omegaconf import DictConfig


def run_job(job: Callable[[DictConfig], Path], cfg: DictConfig) -> None:
    """Run ``job(cfg)`` and print the path it returns as the last line.

    A handradar error (bad input, named file and problem) ends a single run with a one-line message
    and exit status 1; in a multirun it propagates, so that Hydra's job report records it and the
    other jobs go on.
    """
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    from handradar.errors import HandradarError

    try:
        path = job(cfg)
    except HandradarError as exc:
        if HydraConfig.get().mode == RunMode.MULTIRUN:
            raise
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)
    print(path, flush=True)
