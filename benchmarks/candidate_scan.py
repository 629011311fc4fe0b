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

In-sample and best-of-grid, so an upper bound on what a diagnosis would credit; a variant worth
landing must also hold on the worlds it was not designed on (``+experiment=gap_benchmark_36_heldout``,
``..._heldout2``). Besides the vocabulary's effects, the variants may use the probe effects of
benchmarks/probe_effects.py (candidates tried and not landed).

    python -m benchmarks.candidate_scan +experiment=gap_benchmark_36 --case multipath \\
        --variants '[{"multipath": {"scale": 0.1}}, {"multipath": {"scale": 1.0}}]'
    python -m benchmarks.candidate_scan +experiment=gap_benchmark_36_heldout2 --case palm \\
        --variants '[{"palm": {}}, {"palm_lobe": {"rcs0_m2": 0.03, "m": 1.0}}]'
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir
from hydra.utils import get_method, instantiate
from omegaconf import OmegaConf

import benchmarks.probe_effects  # noqa: F401  (registers the probe effects)
from handradar.config import VERSION_BASE, config_dir
from handradar.gap.benchmark import (
    CONTROL_NOTHING,
    Case,
    case_world,
    cases,
    spectrograms,
    window_starts,
)
from handradar.gap.data import load_dataset
from handradar.gap.engine import VariantEngine
from handradar.metrics import per_example_ssim
from handradar.sim.factory import SimFactory


def scan(path: Path, clean: Path | None, sim_cfg, variants: list[dict], exponent: float) -> list[dict]:
    """gap_closed of each variant on the dataset ``path`` (in-sample, all rows) and, with ``clean``
    (the effect-free world at the same windows), r of its change with the world's change."""
    data = load_dataset(path)
    factory = SimFactory.from_config(sim_cfg, data.radar, data.chain, skeleton_rate_hz=data.skeleton_rate_hz)
    specs = torch.as_tensor(VariantEngine(factory.replace(rcs_exponent=exponent), factory.effects, data.rows)
                            .spectrograms([{}, *variants]))
    measured = torch.as_tensor(data.measured)
    before = float(per_example_ssim(measured, specs[0]).mean())
    world = None if clean is None else (measured - spectrograms(clean)).flatten().double()
    out = []
    for v, spec in zip(variants, specs[1:]):
        after = float(per_example_ssim(measured, spec).mean())
        row = {"variant": v, "gap_closed": (after - before) / (1.0 - before) if before < 1.0 else float("nan")}
        if world is not None:
            row["r"] = float(torch.corrcoef(torch.stack([world, (spec - specs[0]).flatten().double()]))[0, 1])
        out.append(row)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("overrides", nargs="*", help="diagnose.py overrides, e.g. +experiment=gap_benchmark_36")
    ap.add_argument("--case", required=True, help="the benchmark case (a withheld effect) whose world is scanned")
    ap.add_argument("--variants", required=True, help="JSON list of variants, [{effect: {param: value}}, ...]")
    ap.add_argument("--exponent", type=float, default=0.25, help="the baseline's RCS exponent (step 0's usual fit)")
    args = ap.parse_args()
    variants = json.loads(args.variants)
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("diagnose", overrides=args.overrides)
    bench = cfg.benchmark
    radar, chain = instantiate(cfg.radar), instantiate(cfg.chain)
    build_world = get_method(str(bench.builder))
    world = OmegaConf.to_container(OmegaConf.merge(cfg.get("world") or {}, bench.get("world") or {}), resolve=True)
    strengths = OmegaConf.to_container(bench.strengths, resolve=True) if bench.get("strengths") is not None else {}
    cache = Path(cfg.paths.cache_dir) / "world"
    case = next((c for c in cases([args.case]) if c.name == args.case), None)
    if case is None:
        raise SystemExit(f"candidate_scan: unknown case {args.case!r}")
    clean_cfg = case_world(world, Case(CONTROL_NOTHING, (), "none"))
    path = build_world(case_world(world, case, strengths), radar, chain, cache)
    clean = build_world(clean_cfg, radar, chain, cache, window_starts_s=window_starts(path).tolist())
    print("| world | variant | gap_closed, case | r with the world's change | gap_closed, effect-free world |")
    print("|---|---|---|---|---|")
    on_case = scan(path, clean, cfg.sim, variants, args.exponent)
    on_clean = scan(build_world(clean_cfg, radar, chain, cache), None, cfg.sim, variants, args.exponent)
    for a, b in zip(on_case, on_clean):
        print(f"| {args.case} | `{json.dumps(a['variant'])}` | {a['gap_closed']:+.3f} | {a['r']:+.3f} | "
              f"{b['gap_closed']:+.3f} |", flush=True)


if __name__ == "__main__":
    main()
