"""A hand-made right hand for tests: canonical joints (metres) in a frame where the palm faces +z,
the fingers point +y and the thumb side is +x. Fingers bend a little toward the palm (+z)."""

from __future__ import annotations

import numpy as np

TEMPLATE_RIGHT = np.array([
    [0.000, 0.000, 0.000],                                                           # wrist
    [0.025, 0.030, 0.010], [0.045, 0.055, 0.015], [0.060, 0.080, 0.020], [0.070, 0.100, 0.025],  # thumb
    [0.030, 0.090, 0.000], [0.030, 0.130, 0.006], [0.030, 0.155, 0.012], [0.030, 0.175, 0.018],  # index
    [0.010, 0.095, 0.000], [0.010, 0.140, 0.006], [0.010, 0.168, 0.012], [0.010, 0.190, 0.018],  # middle
    [-0.010, 0.090, 0.000], [-0.010, 0.132, 0.006], [-0.010, 0.158, 0.012], [-0.010, 0.178, 0.018],  # ring
    [-0.030, 0.080, 0.000], [-0.030, 0.113, 0.006], [-0.030, 0.133, 0.012], [-0.030, 0.150, 0.018],  # pinky
])


def rotation(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def moving_hand(n: int, dt: float, *, rot: np.ndarray | None = None, start: np.ndarray | None = None,
                velocity: np.ndarray | None = None) -> np.ndarray:
    """(n, 21, 3) template joints, rotated by ``rot``, translated from ``start`` at ``velocity`` (m/s)."""
    rot = np.eye(3) if rot is None else rot
    start = np.zeros(3) if start is None else np.asarray(start, dtype=float)
    velocity = np.zeros(3) if velocity is None else np.asarray(velocity, dtype=float)
    t = np.arange(n)[:, None, None] * dt
    return TEMPLATE_RIGHT @ rot.T + start + velocity * t
