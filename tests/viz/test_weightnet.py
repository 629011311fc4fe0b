"""The hybrid synthesis figures (handradar.viz.weightnet), their content read back from the figure
before it is saved: which panels, in which order, showing which values."""

from __future__ import annotations

import re

import h5py
import numpy as np
import pytest

import handradar.viz.weightnet as weightnet
from handradar.sim.simulator import Simulator
from handradar.synthesis.fit import load_pairs
from handradar.synthesis.providers import cache_rows
from tests.tasks.test_closed_loop import RATE, _measured


@pytest.fixture
def figures(monkeypatch) -> list:
    """Every figure a weightnet plot saves (still open), in order; the PNG is written as usual."""
    saved = []
    real = weightnet.save_figure

    def spy(fig, path, *a, **k):
        saved.append({"axes": fig.axes, "path": path})
        fig.canvas.draw()  # lay out now: the axes are read after the real save closes the figure
        return real(fig, path, *a, **k)

    monkeypatch.setattr(weightnet, "save_figure", spy)
    return saved


@pytest.fixture(scope="module")
def pairs_and_sim(tmp_path_factory, radar, short_chain):
    tmp = tmp_path_factory.mktemp("wn")
    path = _measured(tmp / "m.h5", radar, short_chain, per_class=1)  # rows: one hand, one hand, two hands
    sim = Simulator(radar, short_chain, skeleton_rate_hz=RATE)
    caches = cache_rows(path, np.arange(3), sim, tmp / "cache", features=True, n_jobs=1)
    with h5py.File(path) as h5:
        targets = h5["spectrograms"][()]
    return load_pairs(caches, targets, np.arange(3)), sim


def _percent(title: str) -> float:
    return float(re.search(r"\n(\d+)%$", title).group(1))


def test_decomposition_shows_only_weighted_slots_by_energy(pairs_and_sim, figures, tmp_path):
    """Weights zero except on three slots: exactly those three panels, strongest first, their shares
    of the energy summing to 100 %; with every slot weighted, the top 11 of a one-hand row, all R."""
    pairs, sim = pairs_and_sim
    one = pairs.subset([0])
    t = one.features.shape[1]
    w = np.zeros((t, 38), np.float32)
    w[:, [2, 7, 12]] = [1.0, 0.5, 0.1]
    out = weightnet.plot_decomposition(sim, one, w, tmp_path / "d.png", title="x")
    assert out.is_file() and out.stat().st_size > 1000
    axes = figures[-1]["axes"]
    titles = [a.get_title() for a in axes]
    assert titles[0] == "all points" and len(axes) == 4
    names = [s.split("\n")[0] for s in titles[1:]]
    assert set(names) == {weightnet.SLOT_NAMES[k] for k in (2, 7, 12)}
    shares = [_percent(s) for s in titles[1:]]
    assert shares == sorted(shares, reverse=True) and abs(sum(shares) - 100) <= 2
    for ax in axes:
        img = ax.get_images()[0].get_array()
        assert img.shape == one.targets.shape[1:] and 0.0 <= img.min() and img.max() <= 1.0
    weightnet.plot_decomposition(sim, one, np.ones((t, 38), np.float32), tmp_path / "all.png")
    titles = [a.get_title() for a in figures[-1]["axes"][1:]]
    assert len(titles) == 11 and all(s.startswith("R ") for s in titles)  # the left hand is not tracked
    assert sum(_percent(s) for s in titles) <= 100 + 6  # 11 rounded shares of at most all the energy


def test_weights_figure_shows_tracked_slots_only(figures, tmp_path):
    t = 10
    w = np.random.default_rng(0).uniform(0.5, 2.0, (t, 38))
    mask = np.zeros((t, 2), bool)
    mask[:, 0] = True
    mask[3:5, 0] = False  # a short tracking gap: blank steps, not dropped slots
    weightnet.plot_weights(w, mask, tmp_path / "w.png", title="row")
    ax = figures[-1]["axes"][0]
    img = np.ma.filled(ax.get_images()[0].get_array(), np.nan)
    assert img.shape == (19, t)  # the right hand's 19 slots by the steps
    np.testing.assert_allclose(img[:, :3], w[:3, :19].T)
    assert np.isnan(img[:, 3:5]).all() and not np.isnan(img[:, 5:]).any()
    assert [lab.get_text() for lab in ax.get_yticklabels()] == list(weightnet.SLOT_NAMES[:19])
    assert ax.get_title() == "RadarWeightNet weights row"


def test_comparison_has_three_rows_of_the_given_examples(figures, tmp_path):
    rng = np.random.default_rng(1)
    stacks = [rng.random((2, 64, 32)) for _ in range(3)]
    weightnet.plot_comparison(*stacks, ["a", "b"], tmp_path / "c.png")
    axes = figures[-1]["axes"]
    assert len(axes) == 6 and [a.get_title() for a in axes[:2]] == ["a", "b"]
    assert [axes[i].get_ylabel() for i in (0, 2, 4)] == ["measured", "model", "enhanced"]
    for i, ax in enumerate(axes):  # row-major: row i // 2 is the stack, column i % 2 the example
        np.testing.assert_array_equal(ax.get_images()[0].get_array(), stacks[i // 2][i % 2])
