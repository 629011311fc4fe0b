"""The canonical hand skeleton: 21 joints in MediaPipe order, 19 bones, two hand slots.

Joints: 0 wrist; thumb 1 CMC, 2 MCP, 3 IP, 4 tip; index 5 MCP, 6 PIP, 7 DIP, 8 tip; middle 9-12;
ring 13-16; pinky 17-20. Bones: thumb CMC-MCP, MCP-IP, IP-tip; every other finger wrist-MCP
(metacarpal), MCP-PIP (proximal), PIP-DIP (intermediate), DIP-tip (distal). Leap Motion's
zero-length thumb metacarpal is why there are 19 bones and not 20.

A :class:`HandSequence` holds positions (T, 2, 21, 3) float32 in the radar frame (metres),
times (T,) in seconds, and a mask (T, 2) of the tracked hands. Slot 0 is the right hand and
slot 1 the left hand, always, so the weight network sees each hand in a fixed place.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from handradar.errors import FormatError

N_JOINTS = 21
HANDS = ("right", "left")
FINGERS = ("thumb", "index", "middle", "ring", "pinky")
JOINT_NAMES = (
    "wrist",
    "thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip",
    "index_mcp", "index_pip", "index_dip", "index_tip",
    "middle_mcp", "middle_pip", "middle_dip", "middle_tip",
    "ring_mcp", "ring_pip", "ring_dip", "ring_tip",
    "pinky_mcp", "pinky_pip", "pinky_dip", "pinky_tip",
)


def _bones() -> tuple[tuple[int, int], ...]:
    bones = [(1, 2), (2, 3), (3, 4)]
    for f in range(1, 5):
        mcp = 1 + 4 * f
        bones += [(0, mcp), (mcp, mcp + 1), (mcp + 1, mcp + 2), (mcp + 2, mcp + 3)]
    return tuple(bones)


BONES: tuple[tuple[int, int], ...] = _bones()
BONE_NAMES: tuple[str, ...] = (
    "thumb_proximal", "thumb_intermediate", "thumb_distal",
    *(f"{f}_{part}" for f in FINGERS[1:] for part in ("metacarpal", "proximal", "intermediate", "distal")),
)
N_BONES = len(BONES)
assert N_BONES == 19 and len(BONE_NAMES) == N_BONES

BONE_PARENT = np.array([a for a, _ in BONES])
BONE_CHILD = np.array([b for _, b in BONES])


@dataclass
class HandSequence:
    """Two-slot hand skeleton sequence in the radar frame.

    positions: (T, 2, 21, 3) float32 metres; untracked hands hold zeros.
    times: (T,) float64 seconds, strictly increasing.
    mask: (T, 2) bool, True where slot h is tracked at step t.
    source: where it came from (a file name), for error messages.
    arm: (T, 2, 2, 3) float32 metres, each hand's elbow and shoulder, or None where the source has no arm
         (the motion library makes one; trackers of hands do not).
    """

    positions: np.ndarray
    times: np.ndarray
    mask: np.ndarray
    source: str = "<memory>"
    attrs: dict = field(default_factory=dict)
    arm: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.positions = np.asarray(self.positions, dtype=np.float32)
        self.times = np.asarray(self.times, dtype=np.float64)
        self.mask = np.asarray(self.mask, dtype=bool)
        t = self.times.shape[0] if self.times.ndim == 1 else -1
        if self.positions.shape != (t, 2, N_JOINTS, 3) or self.mask.shape != (t, 2):
            raise FormatError(self.source, f"skeleton arrays disagree: positions {self.positions.shape}, times "
                                           f"{self.times.shape}, mask {self.mask.shape}; expected (T, 2, 21, 3), (T,), (T, 2)")
        if t < 2:
            raise FormatError(self.source, f"a sequence needs at least 2 time steps, found {t}")
        if not np.all(np.diff(self.times) > 0):
            bad = int(np.argmin(np.diff(self.times) > 0))
            raise FormatError(self.source, f"times must increase: step {bad + 1} at {self.times[bad + 1]:.6f} s "
                                           f"follows {self.times[bad]:.6f} s")
        tracked = self.positions[self.mask]
        if not np.all(np.isfinite(tracked)):
            raise FormatError(self.source, "tracked joints contain NaN or infinite coordinates")
        self.positions[~self.mask] = 0.0
        if self.arm is not None:
            self.arm = np.asarray(self.arm, dtype=np.float32)
            if self.arm.shape != (t, 2, 2, 3) or not np.all(np.isfinite(self.arm[self.mask])):
                raise FormatError(self.source, f"arm joints of shape {self.arm.shape}, or not finite where tracked; "
                                               f"expected (T, 2, 2, 3) = ({t}, 2, 2, 3)")
            self.arm[~self.mask] = 0.0

    @property
    def n_steps(self) -> int:
        return self.times.shape[0]

    def bone_lengths(self) -> np.ndarray:
        """(T, 2, 19) bone lengths in metres (zero for untracked hands)."""
        return np.linalg.norm(self.positions[:, :, BONE_CHILD] - self.positions[:, :, BONE_PARENT], axis=-1)

    def resample(self, times: np.ndarray) -> HandSequence:
        """Linear interpolation in time to ``times`` (seconds); a hand counts as tracked at t only
        if it is tracked at both neighbouring samples. Times outside the sequence are clamped."""
        joints = self.positions if self.arm is None else np.concatenate([self.positions, self.arm], axis=2)
        pos, new_times, mask = interpolate(joints, self.times, self.mask, np.asarray(times, dtype=np.float64))
        return HandSequence(pos[:, :, :N_JOINTS], new_times, mask, source=self.source, attrs=dict(self.attrs),
                            arm=None if self.arm is None else pos[:, :, N_JOINTS:])

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> HandSequence:
        """Rigid transform x -> R x + t of every tracked joint."""
        r, tr = np.asarray(rotation, dtype=np.float32), np.asarray(translation, dtype=np.float32)
        arm = None if self.arm is None else self.arm @ r.T + tr
        return HandSequence(self.positions @ r.T + tr, self.times.copy(), self.mask.copy(), source=self.source,
                            attrs=dict(self.attrs), arm=arm)


def interpolate(positions: np.ndarray, times: np.ndarray, mask: np.ndarray,
                new_times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linear interpolation of (T, 2, J, 3) positions (the 21 joints, or an arm's 2) and (T, 2) mask from ``times`` to
    ``new_times``."""
    t = np.clip(new_times, times[0], times[-1])
    hi = np.clip(np.searchsorted(times, t, side="right"), 1, len(times) - 1)
    lo = hi - 1
    frac = ((t - times[lo]) / (times[hi] - times[lo])).astype(np.float32)[:, None, None, None]
    pos = positions[lo] * (1 - frac) + positions[hi] * frac
    new_mask = mask[lo] & mask[hi]
    # exactly on a sample: its own mask decides
    exact_lo = frac[:, 0, 0, 0] == 0
    new_mask[exact_lo] = mask[lo][exact_lo]
    pos[~new_mask] = 0.0
    return pos.astype(np.float32), new_times, new_mask
