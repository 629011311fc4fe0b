"""The reference-world gallery (handradar.viz.world_gallery): what it asks the world for, how it lays
the panels out, and the red velocity line from the Leap skeleton."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

import handradar.viz.world_gallery as wg
from handradar.radar.chain import velocity_axis_m_s
from handradar.vocab import GESTURES


def _row(times: np.ndarray, r_m: np.ndarray, tracked: np.ndarray | None = None) -> dict:
    """A row whose every joint of both hands sits on boresight at range r_m(t)."""
    sk = np.zeros((len(times), 2, 21, 3), np.float32)
    sk[..., 2] = r_m[:, None, None]
    mask = np.ones((len(times), 2), bool) if tracked is None else tracked
    return {"spectrogram": np.zeros((64, 32), np.float32), "skeleton": sk, "hand_mask": mask}


def test_velocity_line_is_the_radial_speed_on_the_doppler_axis(radar, chain):
    """An approaching hand (range falling at v) is drawn above the middle (zero Doppler) row, a
    receding one below, by v over the axis' row spacing: linear and antisymmetric in v."""
    rate = 100.0
    times = np.arange(20) / rate
    vel = velocity_axis_m_s(radar, chain)
    step = vel[1] - vel[0]
    zero = int(np.argmin(np.abs(vel)))
    assert vel[zero] == 0.0 and zero == chain.stft_len // 2
    for v in (0.0, 0.2, -0.2, 0.5):
        rows = wg._velocity_rows(_row(times, 0.4 - v * times), radar, chain, rate)
        np.testing.assert_allclose(rows, zero + v / step, atol=1e-3)  # float32 joints: 1e-4 rows
    tracked = np.ones((20, 2), bool)
    tracked[5:8] = False  # no hand tracked: no line there
    rows = wg._velocity_rows(_row(times, 0.4 - 0.2 * times, tracked), radar, chain, rate)
    assert np.isnan(rows[5:8]).all() and np.isfinite(rows[:4]).all() and np.isfinite(rows[9:]).all()


def test_gallery_draws_every_gesture_and_toggles_every_effect(tmp_path, monkeypatch):
    """With the world's renderer replaced by a recorder: 10 gestures at 0 and +30 deg in the default
    world, then each showcased effect as in the default world and toggled; a 15 x 6.6 in PNG at 72 dpi."""
    calls = []

    def fake_example(world, radar, chain, spec):
        calls.append((world, spec))
        times = np.arange(30) / world.skeleton_rate_hz
        row = _row(times, 0.4 - 0.1 * times)
        row["spectrogram"] = np.full((64, 32), len(calls) / 40.0, np.float32)
        return row

    monkeypatch.setattr(wg, "fast_example", fake_example)
    out = wg.gallery(tmp_path / "figs" / "gallery.png", ["world.seed=5"])
    with Image.open(out) as im:
        assert im.size == (1080, 475)
    assert len(calls) == 40
    default = calls[0][0]
    assert default.seed == 5
    assert [(s.gesture, s.angle_deg) for _, s in calls[:20]] == [(g, a) for g in GESTURES for a in (0.0, 30.0)]
    assert all(w is default for w, _ in calls[:20])
    effect_calls = calls[20:]
    assert len(effect_calls) == 2 * len(wg.SHOWCASE)
    for k, (effect, (gesture, angle)) in enumerate(wg.SHOWCASE.items()):
        (w_on, s_on), (w_toggled, s_toggled) = effect_calls[2 * k], effect_calls[2 * k + 1]
        assert (s_on.gesture, s_on.angle_deg) == (s_toggled.gesture, s_toggled.angle_deg) == (gesture, angle)
        assert w_on is default
        assert getattr(w_toggled.effects, effect).enabled is not getattr(default.effects, effect).enabled
        others = [n for n in wg.SHOWCASE if n != effect]
        assert all(getattr(w_toggled.effects, n) == getattr(default.effects, n) for n in others)


def test_command_line_prints_the_written_file(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(wg, "gallery", lambda out, overrides, subject: out)
    wg.main(["--out", str(tmp_path / "g.png"), "--subject", "2", "world.seed=3"])
    assert capsys.readouterr().out.strip() == str(tmp_path / "g.png")
    with pytest.raises(SystemExit):
        wg.main(["--subject", "two"])
