"""How visible is each withheld effect, in the radar data and to the simulator? (``python -m benchmarks.world_signatures``)

The truth-side columns of the gap benchmark's table (handradar.gap.benchmark.truth_side), for every
case of a gap benchmark preset, without diagnosing anything:

- the radar signature: 1 - SSIM between the case's world and the effect-free world, row by row over
  the case's windows (mean / median);
- the world's change on the simulator: gap_closed [95 % CI] of the baseline simulator plus exactly
  the world's change, row by row (handradar.gap.benchmark.effect_reference): the reference for what
  a candidate of the effect can be credited with. The baseline here is step 0's generic
  calibration on every row (the benchmark uses its diagnosis's baseline on the evaluation rows);
- r: the Pearson correlation, over every pixel, of the candidate's change (at its default
  parameters here; the benchmark uses the fitted candidate) with the world's.

Printed beside them, for comparison: the signature with each world's own windows (what the
benchmark's tables reported before the two were aligned) and how many rows the effect moved to
another window. The chain picks each row's window from its radar data, so an effect that changes
the data can move it by tenths of a second, and two rows over other stretches of the motion differ
by far more than the effect.

    python -m benchmarks.world_signatures +experiment=gap_benchmark benchmark.size=36
    python -m benchmarks.world_signatures +experiment=gap_benchmark world=heldout2 benchmark.size=36
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from handradar.config import VERSION_BASE, config_dir
from handradar.gap.benchmark import (
    CONTROL_NOTHING,
    BenchmarkWorlds,
    cases,
    spectrograms,
    truth_side,
)
from handradar.gap.data import load_dataset
from handradar.gap.engine import VariantEngine
from handradar.gap.fit import calibrate_settings, generic_grid
from handradar.gap.report import GENERIC_SETTINGS
from handradar.metrics import per_example_ssim
from handradar.sim.factory import SimFactory
from handradar.vocab import EFFECTS


def calibrated_baseline(sim_cfg, diag: dict, path: Path, effect: str) -> tuple[np.ndarray, np.ndarray | None]:
    """(N, doppler, columns) spectrograms of every row of ``path``: the baseline simulator, step 0's
    generic settings calibrated on every row (the diagnosis's grids), and the baseline plus the
    candidate ``effect`` at its default parameters (None: not a candidate of the vocabulary)."""
    data = load_dataset(path)
    factory = SimFactory.from_config(sim_cfg, data.radar, data.chain, skeleton_rate_hz=data.skeleton_rate_hz)
    idx = np.arange(len(data))
    grid = generic_grid({name: diag.get(name) for name in GENERIC_SETTINGS})
    best, _ = calibrate_settings(factory, factory.effects, data.rows, idx, data.measured, grid)
    variants = [{}, {effect: {}}] if effect in EFFECTS else [{}]
    specs = VariantEngine(factory.replace(**best), factory.effects, data.rows).spectrograms(variants, idx)
    return specs[0], (specs[1] if len(specs) > 1 else None)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("overrides", nargs="*", help="diagnose.py overrides, e.g. +experiment=gap_benchmark benchmark.size=36")
    args = ap.parse_args()
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("diagnose", overrides=args.overrides)
    worlds = BenchmarkWorlds.from_config(cfg)
    diag = OmegaConf.to_container(cfg.diagnose, resolve=True)
    clean = worlds.clean()
    print("| case | rows | windows moved | radar signature, case's windows (mean / median) | radar signature, each "
          "world's own windows (mean / median) | world's change on the simulator: gap_closed [95 % CI] | "
          "candidate's change vs the world's, r (candidate at its default parameters) |")
    print("|---|---|---|---|---|---|---|")
    for case in cases(list(cfg.benchmark.cases)):
        if case.name == CONTROL_NOTHING:
            continue
        t0 = time.perf_counter()
        path = worlds.dataset(case)
        baseline, candidate = calibrated_baseline(cfg.sim, diag, path, case.truth)
        res = truth_side(worlds, path, clean, baseline=baseline, rows=np.arange(len(baseline)), candidate=candidate)
        own = 1.0 - np.asarray(per_example_ssim(spectrograms(clean), spectrograms(path)))
        ref = ("-" if "reference_gap_closed" not in res else
               f"{res['reference_gap_closed']:+.3f} [{res['reference_ci95'][0]:+.3f}, {res['reference_ci95'][1]:+.3f}]")
        print(f"| {case.name} | {len(own)} | {res['windows_moved']} | {res['signature_mean']:.4f} / "
              f"{res['signature_median']:.4f} | {own.mean():.4f} / {np.median(own):.4f} | {ref} | "
              f"{'-' if 'change_correlation' not in res else format(res['change_correlation'], '.3f')} |"
              f"  <!-- {time.perf_counter() - t0:.0f} s -->", flush=True)


if __name__ == "__main__":
    main()
