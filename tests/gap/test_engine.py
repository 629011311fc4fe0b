"""The variant engine's shortcuts give the simulator's own spectrograms."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from handradar.gap.engine import VariantEngine, constant_ratio, merge, slot_weights
from handradar.gap.fit import calibrate_settings, generic_grid
from handradar.metrics import per_example_ssim
from handradar.sim.scatterers import Scatterers
from tests.gap.conftest import builder, rows, simulate

VARIANTS = [{}, {"noise": {"snr_db": 10.0}}, {"palm": {"radius_m": 0.03}},
            {"forearm": {"length_m": 0.1, "radius_m": 0.02}}, {"forearm": {"length_m": 0.1, "radius_m": 0.04}},
            {"multipath": {"height_m": 0.03, "scale": 0.3}},
            {"multipath": {"height_m": 0.03, "scale": 1.0}},  # reuses the previous per-point profiles
            {"antenna_pattern": {"q": 6.0}}, {"sync_offset": {"offset_s": 0.05}}]


@pytest.mark.parametrize("coherence", [1.0, 0.4])
@pytest.mark.parametrize("base", [{}, {"palm": {}}, {"multipath": {}}])
def test_variants_match_full_simulation(radar, short_chain, base, coherence):
    """Every path of the engine, also with the slots' own power (coherence < 1: added points join
    slot 38, re-weighted slots and full simulations give their own)."""
    rs, _, _ = rows(radar, short_chain, 2, seed=1)  # one- and two-hand rows (kept in this order)
    build = builder(radar, short_chain).replace(coherence=coherence)
    engine = VariantEngine(build, base, rs, batch_size=2)
    out = engine.spectrograms(VARIANTS)
    paths = {k: p for (k, p) in engine.paths}
    assert paths["noise"] == "signal" and paths["sync_offset"] == "full"
    assert paths["forearm"] == "added"  # forearm points do not bounce: added also on a multipath base
    assert paths["palm"] == ("full" if "palm" in base else "added")  # a changed palm radius moves no point but its RCS
    assert paths["antenna_pattern"] == ("reweighted" if not base else "full")  # one batch: the same noise draws
    for v, spec in zip(VARIANTS, out):
        sim = build(merge(base, v))
        with torch.no_grad():
            ref = sim(torch.as_tensor(rs.skeletons), torch.as_tensor(rs.masks), times=torch.as_tensor(rs.times)).numpy()
        # exact paths agree to float32 rounding; the re-weighting path (antenna_pattern) interpolates
        # the amplitude and the ratio separately between skeleton steps: a second-order difference
        tol = 5e-3 if "antenna_pattern" in v and not base else 1e-4
        np.testing.assert_allclose(spec, ref, atol=tol, err_msg=str(v))


def test_constant_ratio_and_slot_weights():
    ref = torch.tensor([[[1.0, 2.0], [2.0, 0.0]]])  # (B=1, T=2, K=2)
    assert torch.allclose(constant_ratio(3 * ref, ref), torch.tensor([[3.0, 3.0]]))
    assert constant_ratio(ref * torch.tensor([[[1.0], [2.0]]]), ref) is None  # factor changes in time
    assert constant_ratio(ref + torch.tensor([[[0.0, 0.0], [0.0, 1.0]]]), ref) is None  # non-zero where ref is 0
    pos = torch.zeros(1, 2, 3, 3)
    s0 = Scatterers(pos, pos, torch.ones(1, 2, 3), torch.ones(1, 2, 3), torch.tensor([0, 0, -1]))
    same_slot = Scatterers(pos, pos, torch.ones(1, 2, 3), torch.tensor([[[2.0, 2.0, 1.0], [0.5, 0.5, 1.0]]]), s0.owner)
    w = slot_weights(s0, same_slot)
    assert w is not None and torch.allclose(w[0, :, 0], torch.tensor([2.0, 0.5])) and torch.all(w[..., 1:] == 1)
    split_slot = Scatterers(pos, pos, torch.ones(1, 2, 3), torch.tensor([[[2.0, 1.0, 1.0], [1.0, 1.0, 1.0]]]), s0.owner)
    assert slot_weights(s0, split_slot) is None  # two points of slot 0 change differently
    free = Scatterers(pos, pos, torch.ones(1, 2, 3), torch.tensor([[[1.0, 1.0, 2.0], [1.0, 1.0, 2.0]]]), s0.owner)
    assert slot_weights(s0, free) is None  # an unweighted point changes: no weight reaches it


def test_variant_factories_share_the_base_where_their_settings_allow(radar, short_chain):
    """A variant with its own generic settings: a coherence re-uses the base's signal, a metacarpal
    gain re-weights its slot profiles, an RCS exponent (read by the effects from the context) is
    simulated in full; each gives the simulator's own spectrogram, also across a tracking dropout
    inside the window (the points reflect nothing there; the weights are interpolated in between)."""
    rs, _, _ = rows(radar, short_chain, 2, seed=1)
    rs.masks[:, 20:23] = False
    build = builder(radar, short_chain)
    base = {"forearm": {"length_m": 0.1}}
    settings = [{"coherence": 0.5}, {"metacarpal_gain": 0.5}, {"metacarpal_gain": 0.0}, {"rcs_exponent": 0.5}]
    engine = VariantEngine(build, base, rs, batch_size=2)
    factories = [build.replace(**s) for s in settings]
    out = engine.spectrograms([{}] * len(settings), factories=factories)
    assert engine.paths == {("settings", "signal"): 1, ("settings", "reweighted"): 2, ("settings", "full"): 1}
    for s, f, spec in zip(settings, factories, out):
        with torch.no_grad():
            ref = f(base)(torch.as_tensor(rs.skeletons), torch.as_tensor(rs.masks),
                          times=torch.as_tensor(rs.times)).numpy()
        np.testing.assert_allclose(spec, ref, atol=1e-4, err_msg=str(s))
    with pytest.raises(ValueError, match="2 factories for 1 variants"):
        engine.spectrograms([{}], factories=factories[:2])


def test_step_0_scores_every_grid_point_as_its_own_simulator_would(radar, short_chain):
    """calibrate_settings shares one pass per RCS exponent between the points of its grid: each point's
    score is still the mean SSIM of that point's own simulator against the rows."""
    rs, _, _ = rows(radar, short_chain, 4, seed=2)
    build = builder(radar, short_chain)
    measured = simulate(radar, short_chain, rs, {})
    grid = generic_grid({"rcs_exponents": [1.0, 0.25], "metacarpal_gains": [1.0, 0.5], "coherences": [1.0, 0.0]})
    best, scores = calibrate_settings(build, {}, rs, np.arange(4), measured, grid, batch_size=4)
    assert best == {"rcs_exponent": 1.0, "metacarpal_gain": 1.0, "coherence": 1.0}
    assert len(scores) == 8
    for point, score in zip(grid, scores):
        with torch.no_grad():
            spec = build.replace(**point)()(torch.as_tensor(rs.skeletons), torch.as_tensor(rs.masks),
                                           times=torch.as_tensor(rs.times))
        assert score == pytest.approx(float(per_example_ssim(torch.as_tensor(measured), spec).mean()), abs=1e-5)


def test_the_cache_simulates_each_row_of_each_simulator_once(radar, short_chain):
    """Variants that are the same simulator share their rows across calls and engines; only rows not
    simulated yet are simulated, and what comes back equals the uncached engine's."""
    from handradar.gap.engine import SpectrogramCache

    rs, _, _ = rows(radar, short_chain, 6, seed=2)
    build, cache = builder(radar, short_chain), SpectrogramCache()
    variants = [{}, {"palm": {"radius_m": 0.03}}, {"antenna_pattern": {"q": 6.0}}]
    plain = VariantEngine(build, {}, rs, batch_size=2).spectrograms(variants)
    engine = VariantEngine(build, {}, rs, batch_size=2, cache=cache)
    first = engine.spectrograms(variants, np.arange(4))
    assert (cache.misses, cache.hits) == (3 * 4, 0)
    again = engine.spectrograms(variants, np.arange(6))  # rows 0-3 cached, 4-5 simulated
    assert (cache.misses, cache.hits) == (3 * 6, 0) and np.array_equal(again[:, :4], first)
    np.testing.assert_allclose(again, plain, atol=1e-6)
    # another engine whose base already holds the palm: {palm} + {} is the palm variant above
    other = VariantEngine(build, {"palm": {"radius_m": 0.03}}, rs, batch_size=2, cache=cache)
    out = other.spectrograms([{}], np.arange(6))
    assert cache.misses == 3 * 6 and cache.hits == 6 and np.array_equal(out[0], again[1])
    # another factory setting is another simulator
    VariantEngine(build.replace(rcs_exponent=0.5), {}, rs, batch_size=2, cache=cache).spectrograms([{}], np.arange(2))
    assert cache.misses == 3 * 6 + 2
