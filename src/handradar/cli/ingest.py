"""``handradar-ingest root=DIR out=FILE.h5``: recordings -> HDF5 dataset."""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from handradar.config import VERSION_BASE, config_dir
from handradar.runs.cli import run_cli

USAGE = "handradar-ingest root=DIR out=FILE.h5 [strict=true] [allow_truncated=true] [iq_swap=true] [key=value ...]"


@hydra.main(config_path=str(config_dir()), config_name="ingest", version_base=VERSION_BASE)
def main(cfg: DictConfig) -> None:
    from hydra.utils import instantiate

    from handradar.data.ingest import ingest

    def job():
        out = Path(cfg.out).resolve()
        # the dataset is written through a temporary file that is removed on the way out
        summary = ingest(cfg.root, out, instantiate(cfg.chain), skeleton_rate_hz=cfg.skeleton_rate_hz,
                         strict=cfg.strict, allow_truncated=cfg.allow_truncated,
                         coverage_tolerance_s=cfg.coverage_tolerance_s, iq_swap=cfg.iq_swap,
                         doppler_flip=cfg.doppler_flip)
        return summary, out

    summary, out = run_cli(job, cfg, usage=USAGE, target="out")
    print(summary.report())
    print(out)


if __name__ == "__main__":
    main()
