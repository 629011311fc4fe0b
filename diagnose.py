"""Sim-to-real gap diagnosis: ``python diagnose.py data.root=DIR [sim.effects=[noise]]``.

Thin Hydra entry point (config conf/diagnose.yaml); the job is :func:`handradar.gap.app.run`.
Writes gap_report.json (DESIGN section 8), gap_report.md and figures into the run folder and logs
an MLflow run; the last line printed is the report's path. ``+experiment=gap_benchmark`` runs the
withheld-effect benchmark instead (its last line: the results markdown).
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

import handradar.config  # noqa: F401  (registers the ${hr_root:} resolver used by the config tree)


@hydra.main(config_path="conf", config_name="diagnose", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    from handradar.errors import HandradarError
    from handradar.gap.app import run

    try:
        path = run(cfg)
    except HandradarError as exc:
        if HydraConfig.get().mode == RunMode.MULTIRUN:
            raise
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)
    print(path, flush=True)


if __name__ == "__main__":
    main()
