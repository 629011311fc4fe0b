"""The README's hero figure: draw_hero writes a PNG from a skeleton window and two spectrograms."""

from __future__ import annotations

import numpy as np

from handradar.hand.skeleton import BONES
from handradar.viz.hero import draw_hero

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _panels() -> dict:
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 1.6, 40)
    hand = rng.normal(0.0, 0.03, (21, 3)) + np.array([0.0, 0.0, 0.3])  # 21 joints ~30 cm above the radar
    skeleton = np.zeros((len(t), 2, 21, 3))
    skeleton[:, 0] = hand + 0.02 * np.stack([np.cos(t), np.sin(t), 0 * t], axis=-1)[:, None]
    mask = np.zeros((len(t), 2), bool)
    mask[:, 0] = True  # one hand tracked, the second slot empty
    mask[:3, 0] = False  # ... and untracked at the start (a gap in the fingertip paths)
    spec = rng.uniform(0.0, 1.0, (64, 32)).astype(np.float32)
    return {"skeleton": skeleton, "hand_mask": mask, "simulated": spec, "world": spec[::-1],
            "ssim": 0.5, "title": "test"}


def test_draw_hero_writes_a_png(tmp_path):
    assert max(max(b) for b in BONES) == 20  # the canonical 21-joint skeleton the panel draws
    out = draw_hero(_panels(), tmp_path / "sub" / "hero.png")
    assert out == tmp_path / "sub" / "hero.png"
    data = out.read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > 10_000  # a real image, not an empty canvas
    assert [p.name for p in out.parent.iterdir()] == ["hero.png"]  # atomic: no temporary file left
