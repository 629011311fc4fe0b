"""Slot-profile cache: round trip, reuse by key, atomic write."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import handradar.sim.cache as cache_mod
from handradar.errors import FormatError
from handradar.sim.cache import SlotProfileCache, cache_slot_profiles, pack, unpack
from handradar.sim.simulator import Simulator
from tests.sim.demo import window


def _data(radar, chain, n=3):
    t = np.arange(int(round(chain.frames_per_window(radar) * radar.frame_period_s * 100))) / 100
    sk, mk = zip(*[window(t, hands=1 + i % 2, seed=i) for i in range(n)])
    return np.stack(sk), np.stack(mk)


def test_pack_round_trip():
    x = torch.randn(2, 5, 7, dtype=torch.complex64) * torch.tensor([1e-6, 3.0])[:, None, None]
    packed, scale = pack(x)
    assert packed.dtype == torch.float16 and float(packed.abs().max()) <= 1.0
    back = unpack(packed, scale)
    assert ((back - x).abs().amax(dim=(1, 2)) / x.abs().amax(dim=(1, 2))).max() < 1e-3


def test_cache_round_trip_and_reuse(radar, short_chain, tmp_path, monkeypatch):
    sk, mk = _data(radar, short_chain)
    sim = Simulator(radar, short_chain)
    path = cache_slot_profiles(sim, sk, mk, tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # the temporary file is gone
    cache = SlotProfileCache(path)
    assert cache.n == 3
    packed, scale, active = cache.load([1, 0])
    direct = sim.slot_profiles(torch.as_tensor(sk[[1, 0]]), torch.as_tensor(mk[[1, 0]]))
    assert active[0].all() and active[1, :19].all() and not active[1, 19:].any()  # example 0: right hand only
    w = 0.5 + torch.rand(2, sk.shape[1], 38)
    spec_cache = sim.spectrogram(sim.combine(packed, w, scale=scale, active=active.any(0)))
    spec_direct = sim.spectrogram(sim.combine(direct, w))
    assert (spec_cache - spec_direct).abs().max() < 0.01
    # only the non-zero slots are stored: 19 chunks per tracked hand (examples 0 and 2: one hand)
    import h5py

    with h5py.File(path, "r") as h5:
        assert h5["profiles"].id.get_num_chunks() == 19 * int(mk.any(1).sum()) == 19 + 38 + 19
    # same inputs and settings: no recomputation
    monkeypatch.setattr(Simulator, "slot_profiles", lambda *a, **k: (_ for _ in ()).throw(AssertionError("recomputed")))
    assert cache_slot_profiles(sim, sk, mk, tmp_path) == path
    # other effects: another key
    with pytest.raises(AssertionError, match="recomputed"):
        cache_slot_profiles(Simulator(radar, short_chain, effects=["palm"]), sk, mk, tmp_path)


def test_interrupted_cache_leaves_nothing(radar, short_chain, tmp_path, monkeypatch):
    sk, mk = _data(radar, short_chain)
    sim = Simulator(radar, short_chain)
    real = Simulator.slot_profiles
    calls = []

    def flaky(self, *a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(self, *a, **k)

    monkeypatch.setattr(Simulator, "slot_profiles", flaky)
    with pytest.raises(KeyboardInterrupt):
        cache_slot_profiles(sim, sk, mk, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_rejects_a_foreign_file(tmp_path):
    import h5py

    p = tmp_path / "x.h5"
    with h5py.File(p, "w") as h5:
        h5.attrs["format"] = "something/1"
    with pytest.raises(FormatError, match="slot-profile cache"):
        SlotProfileCache(p)
    assert cache_mod.CACHE_FORMAT == "handradar.slot_profiles/2"


def test_cache_dataset_builds_both_caches(radar, short_chain, tmp_path):
    from handradar.data.hdf5 import open_writer
    from handradar.hand.model import HandModelConfig
    from handradar.sim.cache import cache_dataset

    sk, mk = _data(radar, short_chain, n=2)
    ds = tmp_path / "d.h5"
    with open_writer(ds, classes=["a"], radar=radar, chain=short_chain, skeleton_rate_hz=100.0,
                     n_steps=sk.shape[1], config_hash="x") as w:
        for i in range(2):
            w.append(np.zeros((64, 8), np.float32), 0, sk[i], mk[i], 0.0, {"subject": "s"})
    sim = Simulator(radar, short_chain, hand=HandModelConfig(visibility_stride=8), effects=["occlusion"])
    out = cache_dataset(ds, sim, tmp_path / "cache")
    assert out.features.features.shape == (2, sk.shape[1], 2, 19, 5) and out.profiles.n == 2
    np.testing.assert_array_equal(out.masks, mk)
    vis = torch.as_tensor(out.features.visible_fraction()[:1])
    direct = sim.slot_profiles(torch.as_tensor(sk[:1]), torch.as_tensor(mk[:1]), visibility=vis)
    rel = (out.profiles.profiles([0]) - direct).abs().max() / direct.abs().max()
    assert rel < 1e-3
    with pytest.raises(FormatError, match="chain"):
        cache_dataset(ds, Simulator(radar, short_chain.__class__(n_columns=16)), tmp_path / "cache")
