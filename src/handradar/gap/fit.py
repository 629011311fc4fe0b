"""Fitting on the calibration rows: the baseline's generic calibration, then candidate effects on
their grids, then optional gradient steps.

    effect_grid(name, overrides=None) -> [{param: value}]
        the effect's documented grid (Effect.grid()), any parameter's values replaced by
        ``overrides[name][param]`` (bounds checked)
    in_vocabulary_order(names) -> [name]
        effect names in the vocabulary's order (handradar.vocab.EFFECTS), then any others sorted
    calibrate_settings(build, base, rows, idx, measured, grid [{setting: value}]) -> (best point, [mean SSIM])
        the aspect exponent of the cylinder RCS (handradar.sim.rcs) that makes the baseline simulator
        closest to the measured rows
    fit_baseline_effects(build, base, rows, idx, measured, grids=None) -> (fitted base, {effect: GridFit})
        the parameters of the effects already in the baseline, each on its grid given the others
    grid_fit(engine, candidates, idx, measured, grids=None) -> {effect: GridFit}
        one pass over the rows scores every grid point of every candidate (mean SSIM; a grid point
        whose spectrograms are not finite scores -inf)
    pool_fits([{effect: GridFit}], rows) -> {effect: GridFit}
        the same grids' scores pooled over fits on different rows (weighted by their row counts)
    refine(engine, name, values, idx, measured, steps, lr) -> dict[str, float]
        Adam on the effect's parameters (step sizes a fraction ``lr`` of each parameter's range),
        projected into bounds after each step; used for effects with ``fit == "grad"``
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from handradar.gap.engine import RowSet, SpectrogramCache, VariantEngine, merge
from handradar.gap.report import GENERIC_SETTINGS
from handradar.metrics import fast_ssim_loss, per_example_ssim
from handradar.sim.effects import REGISTRY
from handradar.sim.factory import SimFactory
from handradar.vocab import EFFECTS


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


def effect_grid(name: str, overrides: Mapping[str, Mapping[str, Sequence[float]]] | None = None) -> list[dict[str, float]]:
    """The fitting grid of effect ``name``: its documented grid with the values of any parameter in
    ``overrides[name]`` replaced (e.g. a raised radar: {"multipath": {"height_m": [0.1, 0.2]}})."""
    try:
        return REGISTRY[name].grid((overrides or {}).get(name))
    except ValueError as err:
        raise ValueError(f"diagnose.grids.{err}") from None


def in_vocabulary_order(names: Iterable[str]) -> list[str]:
    """``names`` in the vocabulary's order (handradar.vocab.EFFECTS), then effects outside it sorted."""
    names = set(names)
    return [n for n in (*EFFECTS, *sorted(names - set(EFFECTS))) if n in names]


def _mean_ssim(target: torch.Tensor, spec: np.ndarray) -> float:
    """Mean SSIM of simulated rows against measured ones; -inf when the simulation is not finite
    (a candidate that breaks the simulator must not win, nor make the ranking undefined)."""
    if not np.all(np.isfinite(spec)):
        return float("-inf")
    return float(per_example_ssim(target, torch.as_tensor(spec)).mean())


def generic_grid(values: Mapping[str, Sequence[float] | None]) -> list[dict[str, float]]:
    """Step 0's grid: every combination of the generic settings' values (``values``: the diagnosis's
    lists by GENERIC_SETTINGS name, None: the paper's value). The RCS exponent is in every point;
    another setting only when more than the paper's value is tried."""
    axes = []
    for name, (setting, paper, _) in GENERIC_SETTINGS.items():
        vals = [float(v) for v in (values.get(name) or [paper])]
        if setting == "rcs_exponent" or vals != [paper]:
            axes.append([(setting, v) for v in vals])
    return [dict(point) for point in itertools.product(*axes)]


def calibrate_settings(build: SimFactory, base: Mapping, rows: RowSet, idx: np.ndarray, measured: np.ndarray,
                       grid: Sequence[Mapping[str, float]], *, batch_size: int = 8,
                       progress: Callable[[int], None] | None = None,
                       cache: SpectrogramCache | None = None) -> tuple[dict[str, float], list[float]]:
    """The generic simulator settings (of ``grid``: e.g. ``{"rcs_exponent": 0.5, "metacarpal_gain": 0.5}``
    per point) under which the baseline simulator scores the highest mean SSIM on rows ``idx``, and the
    score of each point (ties: the first).

    One pass over the rows per RCS exponent: the points that share it are variants of one engine,
    so a metacarpal gain re-weights that pass's slot profiles and a coherence re-uses its signal
    (handradar.gap.engine, ``factories``) instead of simulating again."""
    target = torch.as_tensor(measured[idx])
    scores = [float("nan")] * len(grid)
    by_exponent: dict[float, list[int]] = {}
    for j, point in enumerate(grid):
        by_exponent.setdefault(float(point.get("rcs_exponent", build.rcs_exponent)), []).append(j)
    for exponent, js in by_exponent.items():
        engine = VariantEngine(build.replace(rcs_exponent=exponent), base, rows, batch_size=batch_size, cache=cache)
        factories = [build.replace(**{k: float(v) for k, v in grid[j].items()}) for j in js]
        specs = engine.spectrograms([{}] * len(js), idx, factories=factories,
                                    progress=None if progress is None else lambda n, k=len(js): progress(n * k))
        for j, spec in zip(js, specs):
            scores[j] = _mean_ssim(target, spec)
    return {k: float(v) for k, v in grid[int(np.argmax(scores))].items()}, scores


def fit_baseline_effects(build: SimFactory, base: Mapping[str, Mapping[str, float]], rows: RowSet, idx: np.ndarray,
                         measured: np.ndarray, *, grids: Mapping[str, Mapping[str, Sequence[float]]] | None = None,
                         batch_size: int = 8, progress: Callable[[int], None] | None = None,
                         cache: SpectrogramCache | None = None) -> tuple[dict[str, dict[str, float]], dict[str, GridFit]]:
    """The effects already in the baseline ``base`` fitted on rows ``idx``: each on its grid
    (:func:`effect_grid`), the best point by mean SSIM, and the fitted baseline.

    One coordinate pass in vocabulary order, not iterated to convergence: each effect's grid is
    scored with the others at their current values (fitted for those before it, as given for those
    after). That is enough for the usual baseline of one or two effects acting on different parts
    of the spectrogram (a noise floor, an antenna pattern); effects that trade off against each
    other would need more passes. No gradient refinement: grids only.
    """
    current = {k: dict(v) for k, v in base.items()}
    fits: dict[str, GridFit] = {}
    for name in in_vocabulary_order(current):
        engine = VariantEngine(build, current, rows, batch_size=batch_size, cache=cache)
        fits[name] = grid_fit(engine, [name], idx, measured, progress=progress, grids=grids)[name]
        current[name] = dict(fits[name].best)
    return current, fits


def grid_fit(engine: VariantEngine, candidates: Sequence[str], idx: np.ndarray, measured: np.ndarray,
             progress: Callable[[int], None] | None = None,
             grids: Mapping[str, Mapping[str, Sequence[float]]] | None = None) -> dict[str, GridFit]:
    """Every grid point of every candidate on rows ``idx`` in one pass; the best point per candidate."""
    variants, owners = [], []
    for name in candidates:
        for point in effect_grid(name, grids):
            variants.append({name: point})
            owners.append(name)
    if not variants:  # no candidate (e.g. a calibration-only fit)
        return {}
    specs = engine.spectrograms(variants, idx, progress=progress)
    target = torch.as_tensor(measured[idx])
    fits = {name: GridFit(name, [], []) for name in candidates}
    for v, name, spec in zip(variants, owners, specs):
        f = fits[name]
        f.grid.append(dict(v[name]))
        f.scores.append(_mean_ssim(target, spec))
    for f in fits.values():
        j = int(np.argmax(f.scores))
        f.best, f.best_score = dict(f.grid[j]), f.scores[j]
    return fits


def pool_fits(fits: Sequence[Mapping[str, GridFit]], rows: Sequence[int]) -> dict[str, GridFit]:
    """Each candidate's grid scored over the rows of several fits at once: the mean SSIM of every grid
    point over their rows (each fit's mean weighted by its ``rows``), the best point of that. Cross-fitting's
    folds fit on rows that together cover every row equally often, so this is the all-rows fit wherever the
    folds were fitted under the same calibration, without simulating anything again."""
    out: dict[str, GridFit] = {}
    for name in fits[0]:
        grids = [f[name] for f in fits]
        if any(g.grid != grids[0].grid for g in grids):
            raise ValueError(f"{name}: the fits to pool scored different grids")
        scores = [float(np.average(col, weights=rows)) if np.all(np.isfinite(col)) else float("-inf")
                  for col in zip(*(g.scores for g in grids))]
        j = int(np.argmax(scores))
        out[name] = GridFit(name, [dict(p) for p in grids[0].grid], scores, dict(grids[0].grid[j]), scores[j])
    return out


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
