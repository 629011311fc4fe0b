"""Simulator test fixtures: one torch thread (the 2-core machine is shared; oversubscribed
threads make small tensor ops 10x slower), a short chain for quick windows."""

from __future__ import annotations

import dataclasses

import pytest
import torch


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="session")
def short_chain(chain):
    """Four frames (8 columns, 0.4 s): the chain of the default radar on a shorter window."""
    return dataclasses.replace(chain, n_columns=8)
