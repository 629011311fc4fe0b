"""``handradar-ingest root=DIR out=FILE.h5``: recordings -> HDF5 dataset."""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from handradar.config import VERSION_BASE, config_dir
from handradar.runs.cli import hydra_overrides_checked, run_cli

USAGE = "handradar-ingest root=DIR out=FILE.h5 [strict=true] [allow_truncated=true] [iq_swap=true] [key=value ...]"


@hydra_overrides_checked(USAGE)
@hydra.main(config_path=str(config_dir()), config_name="ingest", version_base=VERSION_BASE)
def main(cfg: DictConfig) -> None:
    from hydra.utils import instantiate

    from handradar.data.ingest import ingest

    def job():
        out = None if cfg.check is True else str(cfg.out)  # check=true: the quality report only
        # the dataset is written through a temporary file that is removed on the way out; out is passed as
        # given (a final '/' names a folder) and the flags as read (ingest accepts true or false only)
        summary = ingest(cfg.root, out, instantiate(cfg.chain), skeleton_rate_hz=cfg.skeleton_rate_hz,
                         strict=cfg.strict, allow_truncated=cfg.allow_truncated,
                         coverage_tolerance_s=cfg.coverage_tolerance_s, iq_swap=cfg.iq_swap,
                         doppler_flip=cfg.doppler_flip, check=cfg.check)
        return summary, None if out is None else Path(out).resolve()

    summary, out = run_cli(job, cfg, usage=USAGE, target="out")
    print(summary.report())
    if out is not None:
        print(out)


if __name__ == "__main__":
    main()
