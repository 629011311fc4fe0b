"""Shared fixtures: the default radar and chain (and a short one), SFINGE3D, one torch thread per
test (the suite runs one xdist worker per core; oversubscribed threads make small tensor ops up to
10x slower).

SFINGE3D (not in the repository: no licence file comes with it) is looked for in ``data/sfinge3d``
(``make fetch-data``), then in ``../shared/data/sfinge3d``; the tests that need it skip with a hint
where neither holds it, except under CI, which always has ``../shared`` and must run every test.
``HANDRADAR_DATA`` and ``HANDRADAR_SHARED`` move the two folders."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import pytest
import torch

from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig

REPO = Path(__file__).resolve().parents[1]
LOCAL_DATA = Path(os.environ.get("HANDRADAR_DATA", REPO / "data"))
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
def sfinge3d_dir() -> Path:
    """The SFINGE3D Dictionary's parent folder (module doc)."""
    for folder in (LOCAL_DATA / "sfinge3d", SHARED / "data" / "sfinge3d"):
        if (folder / "Dictionary").is_dir():
            return folder
    message = f"SFINGE3D not found in {LOCAL_DATA / 'sfinge3d'} or {SHARED / 'data' / 'sfinge3d'}: run `make fetch-data`"
    if os.environ.get("CI"):
        pytest.fail(message)
    pytest.skip(message)
