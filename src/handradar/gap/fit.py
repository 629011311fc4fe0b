"""Fitting candidate effects on the calibration rows: the documented grid, then optional gradient steps.

    grid_fit(engine, candidates, idx, measured) -> {effect: GridFit}
        one pass over the rows scores every grid point of every candidate (mean SSIM)
    refine(engine, name, values, idx, measured, steps, lr) -> dict[str, float]
        Adam on the effect's parameters (step sizes a fraction ``lr`` of each parameter's range),
        projected into bounds after each step; used for effects with ``fit == "grad"``
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from handradar.gap.engine import VariantEngine, merge
from handradar.gap.stats import per_example_ssim
from handradar.models.losses import fast_ssim_loss
from handradar.sim.effects import REGISTRY


@dataclass
class GridFit:
    """Scores of one candidate's grid on the calibration rows (mean SSIM per grid point)."""

    effect: str
    grid: list[dict[str, float]]
    scores: list[float]
    best: dict[str, float] = field(default_factory=dict)
    best_score: float = float("nan")
    refined: bool = False

    def as_dict(self) -> dict:
        return {"grid": [{**g, "ssim": s} for g, s in zip(self.grid, self.scores)], "best": self.best,
                "best_ssim": self.best_score, "refined": self.refined}


def grid_fit(engine: VariantEngine, candidates: Sequence[str], idx: np.ndarray, measured: np.ndarray,
             progress: Callable[[int], None] | None = None) -> dict[str, GridFit]:
    """Every grid point of every candidate on rows ``idx`` in one pass; the best point per candidate."""
    variants, owners = [], []
    for name in candidates:
        for point in REGISTRY[name].grid():
            variants.append({name: point})
            owners.append(name)
    specs = engine.spectrograms(variants, idx, progress=progress)
    target = torch.as_tensor(measured[idx])
    fits = {name: GridFit(name, [], []) for name in candidates}
    for v, name, spec in zip(variants, owners, specs):
        f = fits[name]
        f.grid.append(dict(v[name]))
        f.scores.append(float(per_example_ssim(target, torch.as_tensor(spec)).mean()))
    for f in fits.values():
        j = int(np.argmax(f.scores))
        f.best, f.best_score = dict(f.grid[j]), f.scores[j]
    return fits


def refine(engine: VariantEngine, name: str, values: dict[str, float], idx: np.ndarray, measured: np.ndarray, *,
           steps: int, lr: float) -> dict[str, float]:
    """Gradient steps on 1 - mean SSIM over rows ``idx`` from ``values``; returns the final values."""
    sim = engine.build(merge(engine.base, {name: values}))
    eff = sim.effect(name)
    specs = eff.params
    eff.requires_grad_(True)
    opt = torch.optim.Adam([{"params": [getattr(eff, k)], "lr": lr * (p.high - p.low)} for k, p in specs.items()])
    target = torch.as_tensor(measured)
    for _ in range(steps):
        opt.zero_grad()
        for e in sim.effects:  # the same noise draws at every step
            if hasattr(e, "reset_rng"):
                e.reset_rng()
        for rows, spec in engine.signals(sim, {name: values}, idx):
            loss = fast_ssim_loss(spec.float(), target[rows]) * (len(rows) / len(idx))
            loss.backward()
        if all(getattr(eff, k).grad is None for k in specs):
            break  # the effect does not reach the spectrogram through a gradient (nothing to refine)
        opt.step()
        eff.clamp_()
    eff.requires_grad_(False)
    return eff.values()
