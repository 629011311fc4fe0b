"""``handradar-fetch dataset=sfinge3d|dhg|xia2021 [out=DIR] [fetch.url=URL]``: an external dataset."""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from handradar.config import VERSION_BASE, config_dir
from handradar.runs.cli import hydra_overrides_checked, run_cli

USAGE = "handradar-fetch dataset=sfinge3d|dhg|xia2021 [out=DIR] [fetch.url=URL] [fetch.txt_only=false]"


@hydra_overrides_checked(USAGE)
@hydra.main(config_path=str(config_dir()), config_name="fetch", version_base=VERSION_BASE)
def main(cfg: DictConfig) -> None:
    from handradar.data.fetch import DATASETS, fetch
    from handradar.errors import HandradarError

    def job():
        if cfg.dataset not in DATASETS:  # before fetch.url, whose default is looked up by dataset
            raise HandradarError(f"unknown dataset {cfg.dataset!r}; expected dataset=one of {', '.join(DATASETS)}")
        out = Path(cfg.out).absolute()
        # the fetch works in a temporary folder beside the target, removed on the way out
        return fetch(cfg.dataset, out, cfg.fetch.url, txt_only=cfg.fetch.txt_only, progress=cfg.fetch.progress), out

    result, out = run_cli(job, cfg, usage=USAGE, target="out")
    print(result.report())
    print(out)


if __name__ == "__main__":
    main()
