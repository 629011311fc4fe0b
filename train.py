"""Train gesture classifiers: ``python train.py +experiment=few_shot_5pct`` (presets in experiments/experiment/).

Thin Hydra entry point: the job is :func:`handradar.tasks.train.run`. The last line printed is the
job's run directory (with metrics.json). Sweeps: ``python train.py -m +experiment=A,B seed=1,2,3``.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

import handradar.config  # noqa: F401  (registers the ${hr_root:} resolver used by the config tree)
from handradar.runs.cli import hydra_overrides_checked

USAGE = "python train.py [+experiment=PRESET] [data=recordings data.root=DIR] [key=value ...]"


@hydra_overrides_checked(USAGE)
@hydra.main(config_path="conf", config_name="train", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from handradar.cli import run_job
    from handradar.tasks.train import run

    run_job(run, cfg, usage=USAGE)


if __name__ == "__main__":
    main()
