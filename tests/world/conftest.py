"""Fixtures of the reference-world tests: short captures, one subject, effects toggled one at a time."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from handradar.radar.chain import ChainConfig, remove_static_clutter, stft_power
from handradar.world.config import WorldConfig


@pytest.fixture(scope="session")
def world() -> WorldConfig:
    """The default world with short captures (18 frames = 1.8 s) and one worker."""
    return WorldConfig(capture_frames=18, subjects=2, repetitions=1, angles_deg=(0.0,), workers=1)


def with_effects(world: WorldConfig, *names: str, **params: dict) -> WorldConfig:
    """``world`` with only ``names`` enabled; ``params`` maps an effect name to parameter changes."""
    fx = world.effects.only(*names)
    for name, p in params.items():
        fx = fx.with_(name, **p)
    return dataclasses.replace(world, effects=fx)


def range_doppler(profiles: torch.Tensor, chain: ChainConfig, clutter_removal: bool = True) -> np.ndarray:
    """(bins, doppler, columns) STFT power of each range bin of a per-range-bin signal."""
    p = remove_static_clutter(profiles) if clutter_removal else profiles
    return torch.stack([stft_power(p[..., b:b + 1], chain) for b in range(p.shape[-1])]).numpy()
