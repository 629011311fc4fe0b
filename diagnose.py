"""Sim-to-real gap diagnosis: ``python diagnose.py data.root=DIR [sim.effects=[noise]]``.

Thin Hydra entry point (config conf/diagnose.yaml); the job is ``cfg.job``:
:func:`handradar.gap.job.run` by default, :func:`handradar.gap.benchmark.run` with
``+experiment=gap_benchmark``.
A diagnosis writes gap_report.json (docs/architecture.md, "Gap report"), gap_report.md and figures
into the run folder and logs an MLflow run; the last line printed is the report's path (the
benchmark's: its compact record, record.json).
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

import handradar.config  # noqa: F401  (registers the ${hr_root:} resolver used by the config tree)
from handradar.runs.cli import hydra_overrides_checked

USAGE = "python diagnose.py data.root=DIR | data=world | +experiment=gap_benchmark [key=value ...]"


@hydra_overrides_checked(USAGE)
@hydra.main(config_path="conf", config_name="diagnose", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from hydra.utils import get_method

    from handradar.cli import run_job

    run_job(get_method(str(cfg.job)), cfg, usage=USAGE)


if __name__ == "__main__":
    main()
