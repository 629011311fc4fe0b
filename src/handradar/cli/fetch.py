"""``handradar-fetch dataset=sfinge3d|dhg [out=DIR] [fetch.url=URL]``: an external skeleton dataset."""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from handradar.config import VERSION_BASE, config_dir


@hydra.main(config_path=str(config_dir()), config_name="fetch", version_base=VERSION_BASE)
def main(cfg: DictConfig) -> None:
    from handradar.data.fetch import DATASETS, fetch
    from handradar.errors import HandradarError

    if cfg.dataset not in DATASETS:  # before fetch.url, whose default is looked up by dataset
        print(f"error: unknown dataset {cfg.dataset!r}; expected dataset=one of {', '.join(DATASETS)}",
              file=sys.stderr)
        sys.exit(1)
    out = Path(cfg.out).absolute()
    try:
        result = fetch(cfg.dataset, out, cfg.fetch.url, txt_only=cfg.fetch.txt_only, progress=cfg.fetch.progress)
    except HandradarError as exc:
        print(f"error: {exc} (nothing written to {out})", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt:
        # the fetch works in a temporary folder that is removed on the way out
        print(f"interrupted; nothing written to {out}", file=sys.stderr)
        sys.exit(130)
    print(result.report())
    print(out)


if __name__ == "__main__":
    main()
