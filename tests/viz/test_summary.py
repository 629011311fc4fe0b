"""The job summary figure: bars at the accuracies, real and synthetic spectrograms of the same rows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")

from handradar.viz.summary import plot_summary  # noqa: E402


def test_summary_bars_and_spectrogram_pairs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    import matplotlib.figure

    saved = []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig",
                        lambda fig, *a, **k: saved.append(fig) or Path(a[0]).write_bytes(b"png"))
    rng = np.random.default_rng(0)
    pairs = [(g, rng.random((64, 32)), rng.random((64, 32))) for g in ("grasp", "circle")]
    acc = {"radar_only": 0.2, "model_synth": 0.6}
    out = plot_summary(acc, tmp_path / "f" / "summary.png", chance=0.1, pairs=pairs)
    assert out.read_bytes() == b"png"
    (fig,) = saved
    bars_ax, *images = fig.axes
    assert [round(b.get_width(), 6) for b in bars_ax.patches] == [0.2, 0.6]
    assert [t.get_text() for t in bars_ax.get_yticklabels()] == ["radar_only", "model_synth"]
    assert bars_ax.lines[0].get_xdata()[0] == pytest.approx(0.1)  # chance
    assert len(images) == 4
    np.testing.assert_array_equal(images[0].images[0].get_array(), pairs[0][1])  # real above ...
    np.testing.assert_array_equal(images[1].images[0].get_array(), pairs[0][2])  # ... synthetic below


def test_summary_writes_a_png_without_pairs(tmp_path: Path):
    out = plot_summary({"radar_only": 0.5}, tmp_path / "summary.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
