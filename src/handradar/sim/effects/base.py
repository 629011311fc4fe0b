"""Effect base class, parameter specs, the registry and the simulation context (see __init__)."""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import torch
from torch import nn

if TYPE_CHECKING:
    from handradar.radar.chain import ChainConfig
    from handradar.radar.config import RadarConfig
    from handradar.sim.scatterers import Scatterers

STAGES = ("skeleton", "scatterers", "signal")


@dataclass(frozen=True)
class Param:
    """A physical parameter: default, closed bounds, and the values of the fitting grid."""

    default: float
    low: float
    high: float
    grid: tuple[float, ...]
    doc: str = ""

    def __post_init__(self) -> None:
        if not self.low <= self.default <= self.high or not all(self.low <= g <= self.high for g in self.grid):
            raise ValueError(f"default {self.default} or grid {self.grid} outside [{self.low}, {self.high}]")


@dataclass
class SimContext:
    """What an effect may read while it enters the signal (one batch).

    joints: (B, T, 2, 21, 3) metres, the skeleton the scatterers were built from (retargeted).
    mask: (B, T, 2) bool tracked hands; times: (T,) or (B, T) seconds of the skeleton steps.
    visibility: (B, T, 2, 19) visible / facing vertex fraction, or None (occlusion computes it).
    radar, chain, the hand model and the cylinder RCS aspect exponent (for effects that add reflectors).
    arm: (B, T, 2, 2, 3) metres, each hand's elbow and shoulder where the source has an arm, else None.
    """

    joints: torch.Tensor
    mask: torch.Tensor
    times: torch.Tensor
    visibility: torch.Tensor | None
    radar: RadarConfig
    chain: ChainConfig
    hand: object  # handradar.hand.model.HandModelConfig
    rcs_exponent: float = 1.0  # aspect exponent of cylinder RCS (handradar.sim.rcs), for effects that add cylinders
    arm: torch.Tensor | None = None


class Effect(nn.Module):
    """One physical effect the paper's simulator lacks (subclass contract in the package doc)."""

    name: ClassVar[str]
    stage: ClassVar[str]  # one of STAGES: where it enters the signal
    order: ClassVar[int]  # position in the pipeline (lower first)
    params: ClassVar[dict[str, Param]]
    fit: ClassVar[str] = "grad"  # "grad": differentiable in its parameters; "grid": grid search only

    def __init__(self, **values: float) -> None:
        super().__init__()
        unknown = set(values) - set(self.params)
        if unknown:
            raise ValueError(f"effect {self.name!r} has no parameter(s) {sorted(unknown)}; "
                             f"expected {sorted(self.params)}")
        for key, spec in self.params.items():
            # frozen by default: a training run that holds a simulator must not tune effects silently;
            # the gap diagnosis calls .requires_grad_(True) to fit them by gradient
            self.register_parameter(key, nn.Parameter(torch.tensor(float(spec.default)), requires_grad=False))
        self.set_values(**values)

    # ---- parameters -----------------------------------------------------------------------
    def value(self, key: str) -> torch.Tensor:
        """Parameter ``key`` clamped to its bounds (what the physics uses).

        The clamp passes gradients straight through, so that a parameter sitting on a bound (e.g.
        transmission = 0) still gets the gradient that would move it inside (projected gradient)."""
        spec = self.params[key]
        p = getattr(self, key)
        return p + (p.clamp(spec.low, spec.high) - p).detach()

    def values(self) -> dict[str, float]:
        return {k: float(self.value(k)) for k in self.params}

    def settings(self) -> dict[str, int]:
        """Constructor settings that are not fitted parameters (segments, paths, seed, draws)."""
        return {}

    def set_values(self, **values: float) -> Effect:
        for key, v in values.items():
            if key not in self.params:
                raise ValueError(f"effect {self.name!r} has no parameter {key!r}; expected {sorted(self.params)}")
            spec = self.params[key]
            if not spec.low <= float(v) <= spec.high:
                raise ValueError(f"{self.name}.{key} = {v} outside its bounds [{spec.low}, {spec.high}]")
            with torch.no_grad():
                getattr(self, key).fill_(float(v))
        return self

    @torch.no_grad()
    def clamp_(self) -> None:
        """Project the parameters into their bounds (call after an optimiser step)."""
        for key, spec in self.params.items():
            getattr(self, key).clamp_(spec.low, spec.high)

    @classmethod
    def grid(cls, overrides: Mapping[str, Sequence[float]] | None = None) -> list[dict[str, float]]:
        """The fitting grid: the Cartesian product of every parameter's grid values, the documented
        ones unless ``overrides[param]`` replaces them (bounds checked)."""
        own = dict(overrides or {})
        unknown = set(own) - set(cls.params)
        if unknown:
            raise ValueError(f"{cls.name}: unknown parameter(s) {sorted(unknown)}; expected some of {sorted(cls.params)}")
        axes = {}
        for key, spec in cls.params.items():
            values = [float(v) for v in own.get(key, spec.grid)]
            if not values or not all(spec.low <= v <= spec.high for v in values):
                raise ValueError(f"{cls.name}.{key}: {values or 'no values'}; each must lie in [{spec.low}, {spec.high}]")
            axes[key] = values
        return [dict(zip(axes, combo)) for combo in itertools.product(*axes.values())]

    @classmethod
    def defaults(cls) -> dict[str, float]:
        return {k: p.default for k, p in cls.params.items()}

    def extra_repr(self) -> str:
        return ", ".join(f"{k}={v:.4g}" for k, v in self.values().items())

    # ---- the three ways into the signal (an effect overrides the one of its stage) -------------
    def apply_skeleton(self, positions: torch.Tensor, mask: torch.Tensor, times: torch.Tensor
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """positions (B, T, 2, 21, 3) m, mask (B, T, 2), times (T,) | (B, T) s -> the same, changed."""
        return positions, mask, times

    def apply_scatterers(self, scat: Scatterers, ctx: SimContext) -> Scatterers:
        """Reflection points at the skeleton steps -> reflection points (added or re-scaled)."""
        return scat

    def apply_signal(self, signal: torch.Tensor, radar: RadarConfig, chain: ChainConfig,
                     power_scale: torch.Tensor | None = None) -> torch.Tensor:
        """Summed per-range-bin slow-time signal (B, frames, loops, channels, bins) -> the same.
        ``power_scale`` (B,): the power the chain will show over the summed signal's own (the
        simulator's coherence below 1), for effects whose level is set relative to the signal's."""
        return signal


REGISTRY: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    if cls.stage not in STAGES:
        raise ValueError(f"effect {cls.name!r}: stage {cls.stage!r} not one of {STAGES}")
    if cls.name in REGISTRY and REGISTRY[cls.name] is not cls:
        raise ValueError(f"effect name {cls.name!r} registered twice")
    REGISTRY[cls.name] = cls
    return cls


def build_effects(effects: list | tuple = (), params: dict | None = None) -> list[Effect]:
    """Effects by name (or ready instances), parameters from ``params[name]``, in pipeline order."""
    params = dict(params or {})
    out: list[Effect] = []
    for item in effects:
        if isinstance(item, Effect):
            out.append(item)
            continue
        name = str(item)
        if name not in REGISTRY:
            raise ValueError(f"unknown effect {name!r}; expected one of {sorted(REGISTRY)}")
        out.append(REGISTRY[name](**dict(params.get(name) or {})))
    names = [e.name for e in out]
    if len(set(names)) != len(names):
        raise ValueError(f"an effect is listed twice: {names}")
    unknown = set(params) - set(REGISTRY)
    if unknown:  # parameters of known but unselected effects are allowed (a config may list them all)
        raise ValueError(f"parameters given for unknown effect(s) {sorted(unknown)}; expected {sorted(REGISTRY)}")
    return sorted(out, key=lambda e: e.order)
