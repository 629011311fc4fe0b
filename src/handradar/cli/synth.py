"""``handradar-synth source=sfinge3d|dhg|leap|motions source.root=DIR out=FILE.h5 [synth.weights=CKPT]``
(motions: no source.root)."""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from handradar.config import VERSION_BASE, config_dir
from handradar.runs.cli import hydra_overrides_checked, run_cli

USAGE = "handradar-synth source=sfinge3d|dhg|leap|motions source.root=DIR out=FILE.h5 [synth.weights=CKPT] [key=value ...]"


@hydra_overrides_checked(USAGE)
@hydra.main(config_path=str(config_dir()), config_name="synth", version_base=VERSION_BASE)
def main(cfg: DictConfig) -> None:
    from hydra.utils import instantiate

    from handradar.synthesis.providers import synthesize_source

    skipped: list | None = None if cfg.synth.strict else []

    def job():
        out = Path(cfg.out).resolve()
        synthesize_source(cfg.source, out, radar=instantiate(cfg.radar), chain=instantiate(cfg.chain),
                          sim=cfg.sim, weights=cfg.synth.weights,
                          skeleton_rate_hz=cfg.synth.skeleton_rate_hz, n_jobs=cfg.synth.n_jobs,
                          cache_dir=cfg.synth.cache_dir, skipped=skipped)
        return out

    out = run_cli(job, cfg, usage=USAGE, target="out", errors=(ValueError,))
    if skipped:
        print(f"skipped {len(skipped)} unreadable sequence(s):")
        for name, reason in skipped[:20]:
            print(f"  {name}: {reason}")
    print(out)


if __name__ == "__main__":
    main()
