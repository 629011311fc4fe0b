"""Would another candidate, or other grid values, explain a withheld effect? (``python -m benchmarks.candidate_scan``)

A probe for designing candidates, on the truth side of the gap benchmark (it reads the worlds'
truth, which no diagnosis may): for one case of a gap benchmark preset, every variant given
(``{effect: {param: value}}``, JSON) is scored in-sample on all the case's rows, on top of the
baseline simulator at a fixed RCS exponent:

- gap_closed of the variant against the case's world, and against the effect-free world's (the
  generic check: a candidate of the effect should close nothing where the effect is absent);
- r: the Pearson correlation over every pixel of the variant's change (variant - baseline) with the
  world's change (case - effect-free world, both over the case's windows: see
  handradar.gap.benchmark.truth_side).

``--grids`` scans every vocabulary effect over its documented fitting grid instead of ``--variants``
and reports each effect at its best grid point by gap_closed on the case.

``--halves N`` adds, for split seeds 0..N-1, the gap_closed over the evaluation half that a
single-split diagnosis with ``diagnose.seed`` = that seed scores (``diagnose.calibration_fraction``;
handradar.data.splits.stratified_partition): how far a verdict at one split can stray from the
all-rows figure (the third held-out world's effect-free control: occlusion +0.018 on all 240 rows,
+0.015 to +0.030 over six evaluation halves).

In-sample and best-of-grid, so an upper bound on what a diagnosis would credit; a variant worth
landing must also hold on the worlds it was not designed on (``+experiment=gap_benchmark world=heldout benchmark.size=36``,
``..._heldout2``). Besides the vocabulary's effects, the variants may use the probe effects of
benchmarks/probe_effects.py (candidates tried and not landed).

    python -m benchmarks.candidate_scan +experiment=gap_benchmark benchmark.size=36 --case multipath \\
        --variants '[{"multipath": {"scale": 0.1}}, {"multipath": {"scale": 1.0}}]'
    python -m benchmarks.candidate_scan +experiment=gap_benchmark world=heldout2 benchmark.size=36 --case palm \\
        --variants '[{"palm": {}}, {"palm_lobe": {"rcs0_m2": 0.03, "m": 1.0}}]'
    python -m benchmarks.candidate_scan +experiment=gap_benchmark benchmark.size=36 --case nothing --grids
    python -m benchmarks.candidate_scan +experiment=gap_benchmark world=heldout3 --case nothing --exponent 0.1 \\
        --variants '[{"occlusion": {"transmission": 0.0}}]' --halves 6
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from hydra import compose, initialize_config_dir

import benchmarks.probe_effects  # noqa: F401  (registers the probe effects)
from handradar.config import VERSION_BASE, config_dir
from handradar.data.splits import stratified_partition
from handradar.gap.benchmark import (
    CONTROL_NOTHING,
    BenchmarkWorlds,
    cases,
    change_correlation,
    spectrograms,
    window_starts,
)
from handradar.gap.data import load_dataset
from handradar.gap.engine import VariantEngine
from handradar.gap.fit import effect_grid
from handradar.metrics import gap_closed, per_example_ssim
from handradar.sim.factory import SimFactory
from handradar.vocab import EFFECTS


def closed(before: np.ndarray, after: np.ndarray) -> float:
    """handradar.metrics.gap_closed over the rows given; nan where the baseline leaves no gap."""
    return gap_closed(before, after) if before.mean() < 1.0 else float("nan")


def scan(path: Path, clean: Path | None, sim_cfg, variants: list[dict], exponent: float,
         noise_draws: int = 1, halves: int = 0, calibration_fraction: float = 0.5) -> list[dict]:
    """gap_closed of each variant on the dataset ``path`` (in-sample, all rows) and, with ``clean`` (the
    effect-free world at the same windows), r of its change with the world's change. ``noise_draws``:
    a noise variant's draws averaged in power, as the diagnosis's ``diagnose.noise_draws``; ``halves``:
    also the gap_closed over the evaluation half of split seeds 0..halves-1 (``on_halves``)."""
    data = load_dataset(path)
    factory = SimFactory.from_config(sim_cfg, data.radar, data.chain, skeleton_rate_hz=data.skeleton_rate_hz)
    engine = VariantEngine(factory.replace(rcs_exponent=exponent, noise_draws=noise_draws), factory.effects, data.rows)
    specs = torch.as_tensor(engine.spectrograms([{}, *variants]))
    measured = torch.as_tensor(data.measured)
    before = per_example_ssim(measured, specs[0])
    evaluation = [stratified_partition(data.labels, (calibration_fraction, 1.0 - calibration_fraction), seed,
                                       every_part=True)[1] for seed in range(halves)]
    world = None if clean is None else measured - spectrograms(clean)
    out = []
    for v, spec in zip(variants, specs[1:]):
        after = per_example_ssim(measured, spec)
        row = {"variant": v, "gap_closed": closed(before, after),
               "on_halves": [closed(before[ev], after[ev]) for ev in evaluation]}
        if world is not None:
            row["r"] = change_correlation(world, spec - specs[0])
        out.append(row)
    return out


def best_per_effect(rows: list[dict]) -> dict[str, dict]:
    """Each effect's row at its best gap_closed (rows of single-effect variants, in order)."""
    best: dict[str, dict] = {}
    for row in rows:
        (name,) = row["variant"]
        if name not in best or row["gap_closed"] > best[name]["gap_closed"]:
            best[name] = row
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("overrides", nargs="*", help="diagnose.py overrides, e.g. +experiment=gap_benchmark benchmark.size=36")
    ap.add_argument("--case", required=True, help="the benchmark case (a withheld effect) whose world is scanned")
    ap.add_argument("--variants", help="JSON list of variants, [{effect: {param: value}}, ...]")
    ap.add_argument("--grids", action="store_true", help="every vocabulary effect over its documented grid")
    ap.add_argument("--exponent", type=float, default=0.25, help="the baseline's RCS exponent (step 0's usual fit)")
    ap.add_argument("--halves", type=int, default=0,
                    help="also gap_closed on the evaluation half of split seeds 0..N-1 (single-split diagnoses)")
    args = ap.parse_args()
    if args.grids == (args.variants is not None):
        raise SystemExit("candidate_scan: give either --variants JSON or --grids")
    try:
        variants = [{n: g} for n in EFFECTS for g in effect_grid(n)] if args.grids else json.loads(args.variants)
    except json.JSONDecodeError as err:
        raise SystemExit(f"candidate_scan: --variants is not JSON ({err})") from None
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("diagnose", overrides=args.overrides)
    worlds = BenchmarkWorlds.from_config(cfg)
    draws, fraction = int(cfg.diagnose.noise_draws), float(cfg.diagnose.calibration_fraction)
    try:
        (case,) = cases([args.case])
    except ValueError as err:
        raise SystemExit(f"candidate_scan: {err}") from None
    path = worlds.dataset(case)
    if case.name == CONTROL_NOTHING:  # the case is the effect-free world: no change to match, no second world
        on_case, on_clean = scan(path, None, cfg.sim, variants, args.exponent, draws, args.halves, fraction), None
    else:
        clean = worlds.clean(window_starts(path).tolist())
        on_case = scan(path, clean, cfg.sim, variants, args.exponent, draws, args.halves, fraction)
        on_clean = scan(worlds.clean(), None, cfg.sim, variants, args.exponent, draws)
    rows = list(best_per_effect(on_case).values()) if args.grids else on_case
    clean_of = {json.dumps(r["variant"], sort_keys=True): r for r in on_clean or []}
    seed_columns = "".join(f" seed {s} |" for s in range(args.halves))
    print(f"| case | variant | gap_closed, case | r with the world's change | gap_closed, effect-free world |{seed_columns}")
    print("|---|---|---|---|---|" + "---|" * args.halves)
    for row in rows:
        other = clean_of.get(json.dumps(row["variant"], sort_keys=True))
        print(f"| {args.case} | `{json.dumps(row['variant'])}` | {row['gap_closed']:+.3f} | "
              f"{'-' if 'r' not in row else format(row['r'], '+.3f')} | "
              f"{'-' if other is None else format(other['gap_closed'], '+.3f')} |"
              + "".join(f" {g:+.3f} |" for g in row["on_halves"]), flush=True)


if __name__ == "__main__":
    main()
