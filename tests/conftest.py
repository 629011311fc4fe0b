"""Shared fixtures: the default radar and chain (and a short one), the shared data folder, one torch
thread per test (the suite runs one xdist worker per core; oversubscribed threads make small
tensor ops up to 10x slower)."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import pytest
import torch

from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("HANDRADAR_SHARED", REPO.parent / "shared"))
DEFAULT_CFG = """\
% the default radar of docs/architecture.md, "Processing chain and simulator"
channelCfg 1 1 0
adcCfg 2 1
profileCfg 0 77 338.8 6 51.2 0 0 76.22 1 256 10000 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
frameCfg 0 0 128 0 100 1 0
"""


@pytest.fixture(scope="session")
def radar() -> RadarConfig:
    return RadarConfig.from_cfg_text(DEFAULT_CFG, "default.cfg")


@pytest.fixture(scope="session")
def chain() -> ChainConfig:
    return ChainConfig()


@pytest.fixture(scope="session")
def short_chain(chain: ChainConfig) -> ChainConfig:
    """Four frames (8 columns, 0.4 s): the default radar's chain on a shorter window."""
    return dataclasses.replace(chain, n_columns=8)


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.fail(f"../shared not found at {SHARED}: the tests need the shared data folder beside the repo")
    return SHARED
