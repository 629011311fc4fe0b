"""Synthetic skeleton windows for demos, tests and benchmarks: a standard hand whose fingers flex.

    flexing_hand(times (T,), seed=0, centre=(0, -0.06, 0.30), hand="right", amplitude_rad=0.5,
                 drift_m_s=(0, 0, 0)) -> (T, 21, 3) metres, radar frame, palm facing the radar
    window(times, hands=1 | 2, seed=0, **kw) -> positions (T, 2, 21, 3) float32, mask (T, 2) bool
"""

from __future__ import annotations

import numpy as np

from handradar.hand.retarget import standard_hand


def _rot_x(a: np.ndarray) -> np.ndarray:
    """Rotation matrices about +x by angles a (...,) -> (..., 3, 3)."""
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def flexing_hand(times: np.ndarray, *, seed: int = 0, centre=(0.0, -0.06, 0.30), hand: str = "right",
                 amplitude_rad: float = 0.5, drift_m_s=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(T, 21, 3) joints: palm down (facing the radar at the origin), each finger curling toward
    the radar with its own frequency and phase (so the bones have different radial velocities)."""
    rng = np.random.default_rng(seed)
    base = standard_hand(hand=hand)
    t = np.asarray(times, dtype=np.float64)
    out = np.repeat(base[None], len(t), axis=0)
    chains = [[1, 2, 3, 4]] + [[5 + 4 * f, 6 + 4 * f, 7 + 4 * f, 8 + 4 * f] for f in range(4)]
    for chain in chains:
        freq = rng.uniform(0.8, 2.5)
        phase = rng.uniform(0, 2 * np.pi)
        # curl toward -z (the radar): negative rotation about x for fingers along +y
        ang = -amplitude_rad * 0.5 * (1 - np.cos(2 * np.pi * freq * t + phase))
        pts = base[chain]
        new = np.repeat(pts[None], len(t), axis=0)
        for j in range(1, len(chain)):  # rotate the rest of the chain about joint j-1 by ang (cumulative curl)
            r = _rot_x(ang * (1.0 if j < 3 else 0.7))
            pivot = new[:, j - 1:j]
            new[:, j:] = pivot + np.einsum("tij,tkj->tki", r, new[:, j:] - pivot)
        out[:, chain] = new
    out = out + np.asarray(centre) + (np.asarray(drift_m_s)[None, :] * t[:, None])[:, None, :]
    return out


def window(times: np.ndarray, *, hands: int = 1, seed: int = 0, **kw) -> tuple[np.ndarray, np.ndarray]:
    """positions (T, 2, 21, 3) float32 and mask (T, 2): right hand in slot 0, optional left in slot 1."""
    pos = np.zeros((len(times), 2, 21, 3), np.float32)
    mask = np.zeros((len(times), 2), bool)
    pos[:, 0] = flexing_hand(times, seed=seed, **kw)
    mask[:, 0] = True
    if hands == 2:
        kw2 = dict(kw)
        c = np.asarray(kw2.pop("centre", (0.0, -0.06, 0.30)), dtype=float)
        pos[:, 1] = flexing_hand(times, seed=seed + 1000, hand="left", centre=tuple(c + [0.12, 0.0, 0.05]), **kw2)
        mask[:, 1] = True
    return pos, mask
