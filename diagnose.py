"""Sim-to-real gap diagnosis: ``python diagnose.py data.root=DIR [sim.effects=[noise]]``.

Thin Hydra entry point (config conf/diagnose.yaml); the job is :func:`handradar.gap.app.run`.
Writes gap_report.json (DESIGN section 8), gap_report.md and figures into the run folder and logs
an MLflow run; the last line printed is the report's path. ``+experiment=gap_benchmark`` runs the
withheld-effect benchmark instead (its last line: the results markdown).
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

import handradar.config  # noqa: F401  (registers the ${hr_root:} resolver used by the config tree)

USAGE = "python diagnose.py data.root=DIR | data=world | +experiment=gap_benchmark [key=value ...]"


@hydra.main(config_path="conf", config_name="diagnose", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from handradar.cli import run_job
    from handradar.gap.app import run

    run_job(run, cfg, usage=USAGE)


if __name__ == "__main__":
    main()
