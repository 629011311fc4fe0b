"""``handradar-ingest root=DIR out=FILE.h5``: recordings -> HDF5 dataset."""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from handradar.config import VERSION_BASE, config_dir
from handradar.errors import HandradarError


@hydra.main(config_path=str(config_dir()), config_name="ingest", version_base=VERSION_BASE)
def main(cfg: DictConfig) -> None:
    from hydra.utils import instantiate

    from handradar.data.ingest import ingest

    out = Path(cfg.out).resolve()
    try:
        summary = ingest(cfg.root, out, instantiate(cfg.chain), skeleton_rate_hz=cfg.skeleton_rate_hz,
                         strict=cfg.strict, allow_truncated=cfg.allow_truncated,
                         coverage_tolerance_s=cfg.coverage_tolerance_s)
    except HandradarError as exc:
        print(f"error: {exc}\nnothing written to {out}", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt:
        # the dataset is written through a temporary file that is removed on the way out
        print(f"interrupted; nothing written to {out}", file=sys.stderr)
        sys.exit(130)
    print(summary.report())
    print(out)


if __name__ == "__main__":
    main()
