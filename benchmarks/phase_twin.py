"""Can any candidate reproduce a withheld effect row by row? (``python -m benchmarks.phase_twin``)

A truth-side probe of the gap benchmark (it reads the worlds' settings, which no diagnosis may). For
every radar-side case of a preset, the world is built again with one shared setting moved by a
sub-millimetre amount that no skeleton tracker resolves (default: every finger 0.5 mm thicker), at
the case's windows, with and without the effect. Then:

- the world's change on the simulator (handradar.gap.benchmark.effect_reference): gap_closed of the
  step-0-calibrated baseline plus exactly the case's change, row by row;
- the twin's change on the simulator: the same with the twin's change (twin case - twin
  effect-free world) in its place. This is what a candidate with the world's own physics closes
  when it knows the geometry only to that sub-millimetre amount. With several ``--deltas`` the
  twins' mean change: towards the effect's expected change over the unresolved geometry, what a
  candidate that reproduces the effect's expectation would be credited with;
- r between the two changes, and 1 - SSIM between the effect-free world and its (first) twin: how
  much the sub-millimetre change alone moves the data.

The coherent sum of reflections whose relative ranges are known only to a fraction of the 3.9 mm
wavelength has its interference pattern drawn at random: an effect whose change is mostly such a
pattern leaves nothing that a candidate can reproduce row by row (README, "How visible each effect is").

    python -m benchmarks.phase_twin +experiment=gap_benchmark benchmark.size=36
    python -m benchmarks.phase_twin +experiment=gap_benchmark world=heldout2 benchmark.size=36 --deltas 0.00025,0.0005,0.00075,0.001
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from benchmarks.world_signatures import calibrated_baseline
from handradar.config import VERSION_BASE, config_dir
from handradar.gap.benchmark import (
    BenchmarkWorlds,
    cases,
    change_correlation,
    spectrograms,
    window_starts,
)
from handradar.metrics import bootstrap_gap_closed, per_example_ssim

RADAR_SIDE = ("occlusion", "palm", "forearm", "multipath", "antenna_pattern", "iq_imbalance")


def _ci(b) -> str:
    return f"{b.estimate:+.3f} [{b.ci95[0]:+.3f}, {b.ci95[1]:+.3f}]"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("overrides", nargs="*", help="diagnose.py overrides, e.g. +experiment=gap_benchmark benchmark.size=36")
    ap.add_argument("--setting", default="scene.finger_radius_m", help="the shared world setting moved (dotted)")
    ap.add_argument("--deltas", default="0.0005", help="how far it moves (the setting's unit); several, comma-separated: "
                                                        "the twins' mean change")
    ap.add_argument("--cases", default=",".join(RADAR_SIDE), help="comma-separated radar-side cases")
    args = ap.parse_args()
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("diagnose", overrides=args.overrides)
    worlds = BenchmarkWorlds.from_config(cfg)
    value = worlds.setting(args.setting)
    twins = [worlds.with_setting(args.setting, value + float(d)) for d in args.deltas.split(",")]
    diag = OmegaConf.to_container(cfg.diagnose, resolve=True)
    print(f"twins: {args.setting} {value:g} -> {', '.join(f'{t.setting(args.setting):g}' for t in twins)}")
    print("| case | rows | world's change on the simulator | the twin's change on the simulator | r, twin's change vs "
          "the world's | effect-free world vs its twin, 1 - SSIM (mean) |")
    print("|---|---|---|---|---|---|")
    for case in cases(args.cases.split(",")):
        path = worlds.dataset(case)
        starts = window_starts(path).tolist()
        measured, clean = spectrograms(path), spectrograms(worlds.clean(starts))
        change = torch.stack([spectrograms(t.dataset(case, starts)) - spectrograms(t.clean(starts)) for t in twins]).mean(0)
        twin_clean = spectrograms(twins[0].clean(starts))
        baseline = torch.as_tensor(calibrated_baseline(cfg.sim, diag, path, case.truth)[0])
        before = per_example_ssim(measured, baseline)
        own = bootstrap_gap_closed(before, per_example_ssim(measured, (baseline + measured - clean).clamp(0, 1)))
        other = bootstrap_gap_closed(before, per_example_ssim(measured, (baseline + change).clamp(0, 1)))
        moved = 1.0 - np.asarray(per_example_ssim(clean, twin_clean))
        print(f"| {case.name} | {len(measured)} | {_ci(own)} | {_ci(other)} | "
              f"{change_correlation(measured - clean, change):+.3f} | {moved.mean():.4f} |", flush=True)


if __name__ == "__main__":
    main()
