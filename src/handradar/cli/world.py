"""``handradar-world out=DIR [world.* overrides]``: write reference-world recordings."""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from handradar.config import VERSION_BASE, config_dir
from handradar.runs.cli import hydra_overrides_checked, run_cli

USAGE = "handradar-world out=DIR [limit=N] [overwrite=true] [world.*=value ...]"


@hydra_overrides_checked(USAGE)
@hydra.main(config_path=str(config_dir()), config_name="world", version_base=VERSION_BASE)
def main(cfg: DictConfig) -> None:
    from hydra.utils import instantiate

    from handradar.provenance import write_source
    from handradar.runs.hydra import invocation
    from handradar.runs.tables import LOCAL, published_command
    from handradar.world import write_world_recordings

    def job():
        out = Path(cfg.out).resolve()
        folders = write_world_recordings(cfg.world, instantiate(cfg.radar), out, limit=cfg.limit,
                                         overwrite=cfg.overwrite)
        # a result on these recordings names them by this command (make tables), never by their folder
        write_source(out, f"{published_command(invocation() or 'handradar-world', skip=('out',))} out={LOCAL}")
        return folders, out

    # each recording appears complete or not at all, and a re-run keeps the finished ones
    folders, out = run_cli(job, cfg, usage=USAGE, target="out", resumable=True, errors=(ValueError,))
    print(f"{len(folders)} recordings in {out}")
    print(out)


if __name__ == "__main__":
    main()
