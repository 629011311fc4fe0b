"""Judge step 0's opt-in generic settings on a benchmark world's effect-free rows.

    python -m experiments.generic_settings [OVERRIDE ...]     e.g. world=scatterers benchmark.size=240
    python -m experiments.generic_settings --summary          every kept record in one table

Composes diagnose.py's ``+experiment=gap_benchmark`` preset with the overrides and builds (or reuses
from the cache) the world's effect-free case. For each setting of SETTINGS, step 0 alone (no
candidate) runs cross-fitted with the preset's folds, the setting's values tried with every RCS
exponent, and is compared with step 0 on the exponents alone on the same out-of-fold rows: mean
SSIM of each, and the share of the gap the setting closes with its paired-bootstrap 95 % CI.

The rule, fixed before any run: a setting helps a world where that CI's lower bound is above 0.
Writes results/gap_benchmark/generic_settings/<world>_<size>.json (with command, as published, commit, machine)
and prints a markdown table.
"""

from __future__ import annotations

import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from handradar.atomic import atomic_write_text
from handradar.config import VERSION_BASE, config_dir
from handradar.gap.benchmark import BenchmarkWorlds
from handradar.gap.data import load_dataset
from handradar.gap.job import fit_simulator
from handradar.metrics import bootstrap_gap_closed, per_example_ssim
from handradar.provenance import REPO_ROOT, code_version, machine
from handradar.runs.tables import published_command

# each opt-in setting with the values its documentation suggests (conf/diagnose.yaml); the records also hold
# the two judged with them and removed, bone_extents [0, 0.5, 1] and doppler_spreads [0, 0.5, 1, 2]
SETTINGS: dict[str, list[float]] = {"metacarpal_gains": [1.0, 0.75, 0.5, 0.25, 0.0],
                                    "coherences": [1.0, 0.5, 0.0]}
PRESET = ["+experiment=gap_benchmark"]
RESULTS = REPO_ROOT / "results" / "gap_benchmark" / "generic_settings"


def step0(data, sim: dict, diagnose: dict, cache_dir: Path) -> tuple[np.ndarray, np.ndarray, dict]:
    """Step 0 alone: the out-of-fold rows, their per-row SSIM under the calibrated baseline, and the
    calibration (what each fold picked)."""
    diag, _ = fit_simulator(data, sim, diagnose, cache_dir=cache_dir, effects=False)
    return diag.evaluation, per_example_ssim(diag.measured, diag.baseline), diag.report["baseline"]["calibration"]


def judge(overrides: list[str]) -> dict:
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("diagnose", overrides=[*PRESET, *overrides])
    worlds = BenchmarkWorlds.from_config(cfg)
    data = load_dataset(worlds.clean())
    sim = OmegaConf.to_container(cfg.sim, resolve=True)
    base_diag = OmegaConf.to_container(cfg.diagnose, resolve=True)
    cache_dir = Path(cfg.paths.cache_dir) / "gap"
    t0 = time.perf_counter()
    rows, before, calibration = step0(data, sim, base_diag, cache_dir)
    out = {"rows": len(data), "exponents_only": {"ssim": float(before.mean()), "calibration": calibration},
           "settings": {}}
    for name, values in SETTINGS.items():
        rows_k, after, cal_k = step0(data, sim, {**base_diag, name: values}, cache_dir)
        if not np.array_equal(rows, rows_k):
            raise RuntimeError(f"{name}: the out-of-fold rows differ from the exponents-only run's")
        boot = bootstrap_gap_closed(before, after, n_boot=int(base_diag.get("n_boot", 2000)),
                                    seed=int(base_diag.get("seed", 0)))
        out["settings"][name] = {"values": values, "ssim": float(after.mean()), "gap_closed": boot.estimate,
                                 "ci95": list(boot.ci95), "helps": bool(boot.ci95[0] > 0), "calibration": cal_k}
        print(f"{name}: SSIM {before.mean():.4f} -> {after.mean():.4f}, gap closed {boot.estimate:+.4f} "
              f"[{boot.ci95[0]:+.4f}, {boot.ci95[1]:+.4f}]", flush=True)
    out["seconds"] = time.perf_counter() - t0
    return out


def _setting(name: str) -> str:
    """The simulator setting of a diagnose list (``coherences`` -> ``coherence``), removed ones included."""
    from handradar.gap.report import GENERIC_SETTINGS

    return GENERIC_SETTINGS[name][0] if name in GENERIC_SETTINGS else name.removesuffix("s")


def picks(calibration: dict, setting: str) -> str:
    """What step 0 picked for ``setting`` in each fold (the folds' list), e.g. '0.5, 0'."""
    return ", ".join(f"{f[setting]:g}" for f in calibration.get("folds") or [calibration] if setting in f)


def markdown(result: dict) -> str:
    lines = [f"Effect-free case, {result['rows']} recordings, step 0 cross-fitted; exponents alone: "
             f"SSIM {result['exponents_only']['ssim']:.4f}.", "",
             "| setting | values | out-of-fold SSIM | gap closed [95 % CI] | picked per fold | helps |",
             "|---|---|---|---|---|---|"]
    for name, r in result["settings"].items():
        lo, hi = r["ci95"]
        lines.append(f"| `diagnose.{name}` | {r['values']} | {r['ssim']:.4f} | {r['gap_closed']:+.4f} "
                     f"[{lo:+.4f}, {hi:+.4f}] | {picks(r['calibration'], _setting(name))} | "
                     f"{'yes' if r['helps'] else 'no'} |")
    return "\n".join(lines) + "\n"


def summary_markdown(folder: Path) -> str:
    """Every record of ``folder`` in one table: per world and size, the gap each setting closes out of fold."""
    def order(p: Path) -> tuple:  # the tuning world first, then by name, the larger size first
        world, size = p.stem.rsplit("_", 1)
        return world != "default", world, -int(size)

    records = {p.stem: json.loads(p.read_text()) for p in sorted(folder.glob("*.json"), key=order)}
    names = list(dict.fromkeys(n for r in records.values() for n in r["settings"]))
    lines = ["| world, recordings | exponents alone: SSIM | " + " | ".join(f"`{n}`" for n in names) + " |",
             "|---|---|" + "---|" * len(names)]
    for label, r in records.items():
        cells = []
        for n in names:
            c = r["settings"].get(n)
            cells.append("–" if c is None else f"{c['gap_closed']:+.3f} [{c['ci95'][0]:+.3f}, {c['ci95'][1]:+.3f}]"
                         + (" **helps**" if c["helps"] else ""))
        world, size = label.rsplit("_", 1)
        lines.append(f"| {world}, {size} | {r['exponents_only']['ssim']:.4f} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> Path:
    if argv == ["--summary"]:
        print(summary_markdown(RESULTS), end="")
        return RESULTS
    result = judge(argv)
    overrides = dict(a.split("=", 1) for a in argv if "=" in a)
    label = f"{overrides.get('world', 'default')}_{overrides.get('benchmark.size', '240')}"
    result.update(command=published_command(shlex.join(["python", "-m", "experiments.generic_settings", *argv])),
                  commit=code_version(), machine=machine())
    path = RESULTS / f"{label}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(result, indent=1) + "\n")
    print(markdown(result), end="")
    print(path)
    return path


if __name__ == "__main__":
    from handradar.runs.cli import run_cli

    run_cli(lambda: main(sys.argv[1:]), usage="python -m experiments.generic_settings [OVERRIDE ...] | --summary")
