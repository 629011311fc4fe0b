"""Gap-diagnosis fixtures: synthetic "measured" rows made by the
simulator itself (with an effect switched on, or with a distortion outside the effect vocabulary)."""

from __future__ import annotations

import numpy as np
import torch

from handradar.gap.data import GapData
from handradar.gap.engine import RowSet
from handradar.sim.factory import SimFactory
from tests.sim.demo import window


def builder(radar, chain) -> SimFactory:
    """The simulator factory of the tests: the paper's simulator, build(effects) adds the given effects."""
    return SimFactory(radar, chain)


def rows(radar, chain, n: int, seed: int = 0) -> tuple[RowSet, np.ndarray, dict]:
    """n windows of flexing hands spread over +-35 deg of azimuth, four 'gestures' (by hand count and side)."""
    steps = int(round(chain.frames_per_window(radar) * radar.frame_period_s * 100.0))
    times = np.arange(steps) / 100.0
    rng = np.random.default_rng(seed)
    sk, masks, labels = [], [], []
    for i in range(n):
        x = rng.uniform(-0.2, 0.2)
        z = rng.uniform(0.25, 0.4)
        p, m = window(times, hands=1 + i % 2, seed=seed * 1000 + i, centre=(x, -0.06, z))
        sk.append(p)
        masks.append(m)
        labels.append(i % 4)
    labels = np.asarray(labels)
    meta = {"gesture": np.asarray([f"g{k}" for k in labels]), "hands": np.asarray([1 + i % 2 for i in range(n)]),
            "subject": np.asarray([f"s{i % 3}" for i in range(n)])}
    return RowSet(np.stack(sk), np.stack(masks), times), labels, meta


def simulate(radar, chain, rowset: RowSet, effects: dict, distort=None) -> np.ndarray:
    """Spectrograms of the rows by the simulator with ``effects``; ``distort(signal)`` acts on the summed
    signal before the chain (a distortion the effect vocabulary lacks)."""
    sim = builder(radar, chain)(effects)
    with torch.no_grad():
        sig = sim.combine(sim.slot_profiles(torch.as_tensor(rowset.skeletons), torch.as_tensor(rowset.masks),
                                            times=torch.as_tensor(rowset.times)))
        if distort is not None:
            sig = distort(sig)
        return sim.spectrogram(sig).float().numpy()


def gap_data(radar, chain, n: int, effects: dict, seed: int = 0, distort=None) -> GapData:
    rs, labels, meta = rows(radar, chain, n, seed)
    return GapData(simulate(radar, chain, rs, effects, distort), rs, labels, meta, radar, chain, 100.0)
