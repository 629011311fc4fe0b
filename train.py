"""Train gesture classifiers: ``python train.py +experiment=few_shot_5pct`` (presets in experiments/experiment/).

Thin Hydra entry point: the job is :func:`handradar.tasks.train.run`. The last line printed is the
job's run directory (with metrics.json). Sweeps: ``python train.py -m +experiment=A,B seed=1,2,3``.
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

import handradar.config  # noqa: F401  (registers the ${hr_root:} resolver used by the config tree)


@hydra.main(config_path="conf", config_name="train", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    from handradar.errors import HandradarError
    from handradar.tasks.train import run

    try:
        run_dir = run(cfg)
    except HandradarError as exc:
        if HydraConfig.get().mode == RunMode.MULTIRUN:
            raise  # recorded by the multirun report; the other jobs go on
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)
    print(run_dir, flush=True)


if __name__ == "__main__":
    main()
