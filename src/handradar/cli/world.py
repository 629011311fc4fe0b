"""``handradar-world out=DIR [world.* overrides]``: write reference-world recordings."""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from handradar.config import VERSION_BASE, config_dir
from handradar.errors import HandradarError


@hydra.main(config_path=str(config_dir()), config_name="world", version_base=VERSION_BASE)
def main(cfg: DictConfig) -> None:
    from hydra.utils import instantiate

    from handradar.world import write_world_recordings

    out = Path(cfg.out).resolve()
    try:
        folders = write_world_recordings(cfg.world, instantiate(cfg.radar), out, limit=cfg.limit,
                                         overwrite=cfg.overwrite)
    except (HandradarError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)
    print(f"{len(folders)} recordings in {out}")
    print(out)


if __name__ == "__main__":
    main()
