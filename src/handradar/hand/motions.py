"""A library of parametrised hand motions: skeleton sequences for any class vocabulary.

A measured radar dataset without skeletons (docs/datasets.md, "Measured radar datasets") names,
per class, one or more of these motions; synthesis draws skeletons from them. Each motion is a
procedural program on the open standard hand (:func:`handradar.hand.retarget.standard_hand`):

- ``swipe_left`` / ``swipe_right`` / ``swipe_up`` / ``swipe_down``: the hand translates along
  -x / +x / +y / -y of the radar frame (the board's azimuth axis and its forward axis);
- ``push`` / ``pull``: the hand translates toward / away from the radar along the line of sight;
- ``tap`` / ``double_tap``: the index finger flexes toward the radar and back, once or twice;
- ``pinch``: thumb and index tips close and open again;
- ``circle_cw`` / ``circle_ccw``: the hand circles 1.5 turns in the plane holding the line of sight
  and x, clockwise or counter-clockwise with x to the right and the line of sight up;
- ``idle``: the hand holds still with a physiological tremor (about 1 mm, 8-12 Hz); any other motion
  may carry one too (``tremor_mm``);
- ``random``: a smooth random wander of a few centimetres (non-gesture hand movement).

Radar frame (docs/architecture.md, "Coordinates and units"): z is boresight (up from the board),
metres and seconds. The hand is placed palm toward the radar at ``distance_m`` along a direction
``azimuth_deg`` off boresight in the x-z plane. A :class:`MotionDraw` holds the per-sequence
nuisance: the simulated subject's hand size, the speed, the distance, the angle, the amplitude and
when the motion starts. Translations follow a minimum-jerk profile (Flash and Hogan 1985), the
standard model of smooth point-to-point hand movement.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass

import numpy as np

from handradar.hand.retarget import standard_hand
from handradar.hand.skeleton import N_JOINTS, HandSequence

MOTIONS: tuple[str, ...] = ("swipe_left", "swipe_right", "swipe_up", "swipe_down", "push", "pull", "tap",
                            "double_tap", "pinch", "circle_cw", "circle_ccw", "idle", "random")

# Default ranges each MotionDraw field is drawn from (uniform); a manifest or source config may override any.
DEFAULT_RANGES: dict[str, tuple[float, float]] = {
    "hand_scale": (0.85, 1.15),    # hand size against the standard adult hand (simulated subjects)
    "speed": (0.7, 1.4),           # multiplies the motion's rate: 1 = a 0.5 s swipe, a 0.3 s tap
    "distance_m": (0.20, 0.40),    # radar to hand centre
    "azimuth_deg": (-20.0, 20.0),  # hand direction off boresight, in the x-z plane
    "amplitude": (0.7, 1.3),       # multiplies the motion's size: 1 = a 20 cm swipe, a 5 cm circle radius
    "onset": (0.3, 0.7),           # where the motion's middle lies in the sequence (share of its duration)
    "tremor_mm": (0.0, 0.0),       # physiological tremor (8-12 Hz) added to every motion but idle, which has its own
}
SWIPE_M = 0.20          # swipe and push/pull length at amplitude 1
SWIPE_S = 0.5           # swipe duration at speed 1
TAP_S = 0.3             # one tap (down and up) at speed 1
TAP_DEG = 45.0          # index flexion at the bottom of a tap
CIRCLE_RADIUS_M = 0.05
CIRCLE_S = 0.8          # one turn at speed 1
TREMOR_M = 0.001        # physiological tremor amplitude
WANDER_M = 0.03         # random non-gesture movement
INDEX = (5, 6, 7, 8)    # MCP, PIP, DIP, tip
THUMB = (1, 2, 3, 4)


@dataclass(frozen=True)
class MotionDraw:
    """One sequence's nuisance parameters (units in the field names; see DEFAULT_RANGES)."""

    hand_scale: float = 1.0
    speed: float = 1.0
    distance_m: float = 0.30
    azimuth_deg: float = 0.0
    amplitude: float = 1.0
    onset: float = 0.5
    tremor_mm: float = 0.0

    @classmethod
    def draw(cls, rng: np.random.Generator, ranges: Mapping[str, tuple[float, float]] | None = None) -> MotionDraw:
        """Each field uniform in its range (``ranges`` overrides DEFAULT_RANGES by name). A single-value range
        draws nothing, so a field added later (``tremor_mm``) leaves every existing draw as it was."""
        r = {**DEFAULT_RANGES, **(ranges or {})}
        unknown = sorted(set(r) - set(DEFAULT_RANGES))
        if unknown:
            raise ValueError(f"unknown motion parameter {unknown[0]!r}; expected one of {sorted(DEFAULT_RANGES)}")
        lows_highs = {k: tuple(map(float, r[k])) for k in DEFAULT_RANGES}
        return cls(**{k: lo if lo == hi else float(rng.uniform(lo, hi)) for k, (lo, hi) in lows_highs.items()})


def min_jerk(tau: np.ndarray) -> np.ndarray:
    """Minimum-jerk position profile 10 t^3 - 15 t^4 + 6 t^5 on [0, 1], clamped outside."""
    t = np.clip(tau, 0.0, 1.0)
    return t**3 * (10 - 15 * t + 6 * t**2)


def bump(tau: np.ndarray) -> np.ndarray:
    """0 -> 1 -> 0 over tau in [0, 1] with zero velocity at both ends: 1 - cos, halved."""
    t = np.clip(tau, 0.0, 1.0)
    return 0.5 * (1 - np.cos(2 * np.pi * t))


def _rotate(points: np.ndarray, pivot: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues rotation of points (T, k, 3) about ``axis`` through ``pivot`` by ``angle`` (T,) radians."""
    a = axis / np.linalg.norm(axis)
    p = points - pivot
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    return pivot + p * c + np.cross(a, p) * s + a * (p @ a)[..., None] * (1 - c)


def _flex_index(joints: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Index finger flexed toward the palm side by ``angle`` (T,) radians, split 50/30/20 over MCP, PIP, DIP."""
    out = joints.copy()
    lateral = np.array([1.0, 0.0, 0.0])  # fingers along +y, palm facing -z: flexion turns +y toward -z
    for share, k in zip((0.5, 0.3, 0.2), range(3)):
        pivot = out[:, INDEX[k]][:, None, :]
        moving = list(INDEX[k + 1:])
        out[:, moving] = _rotate(out[:, moving], pivot, lateral, -share * angle)
    return out


def _pinch(joints: np.ndarray, closure: np.ndarray) -> np.ndarray:
    """Thumb and index tips drawn together: index flexed 35 deg and the thumb chain moved toward the
    index tip, both by ``closure`` (T,) in [0, 1]."""
    out = _flex_index(joints, np.deg2rad(35.0) * closure)
    target = out[:, INDEX[-1]]
    for k, share in zip(THUMB[1:], (0.3, 0.6, 0.9)):
        out[:, k] = out[:, k] + (share * closure)[:, None] * (target - out[:, k])
    return out


def tremor(t: np.ndarray, amplitude_m: float, rng: np.random.Generator) -> np.ndarray:
    """Physiological tremor (len(t), 3): on each axis a sinusoid of ``amplitude_m`` at 8-12 Hz, random phase."""
    f = rng.uniform(8.0, 12.0, 3)
    return amplitude_m * np.sin(2 * np.pi * f * t[:, None] + rng.uniform(0, 2 * np.pi, 3))


def hand_pose(draw: MotionDraw, hand: str = "right") -> tuple[np.ndarray, np.ndarray]:
    """The open hand of ``draw`` in the radar frame, palm toward the radar: (joints (21, 3), centre (3,))."""
    j = standard_hand(draw.hand_scale, hand)  # wrist at 0, fingers +y, palm facing -z: toward a radar below
    j = j - j[[0, 5, 9, 13, 17]].mean(axis=0)  # hand centre (wrist and MCPs) at the origin
    az = np.deg2rad(draw.azimuth_deg)
    centre = draw.distance_m * np.array([np.sin(az), 0.0, np.cos(az)])
    return j, centre


def motion_sequence(name: str, draw: MotionDraw, *, duration_s: float = 3.2, rate_hz: float = 100.0,
                    rng: np.random.Generator | None = None, hand: str = "right") -> HandSequence:
    """One right hand (slot 0) performing motion ``name`` with ``draw``'s nuisance, ``duration_s`` long at ``rate_hz``.

    ``rng`` drives the idle tremor and the random wander (default: a fixed seed).
    """
    if name not in MOTIONS:
        raise ValueError(f"unknown motion {name!r}; expected one of {list(MOTIONS)}")
    rng = rng if rng is not None else np.random.default_rng(0)
    t = np.arange(int(round(duration_s * rate_hz))) / rate_hz
    pose, centre = hand_pose(draw, hand)
    sight = centre / np.linalg.norm(centre)  # unit vector radar -> hand
    joints = np.broadcast_to(pose, (len(t), N_JOINTS, 3)).copy()
    offset = np.zeros((len(t), 3))
    mid = draw.onset * duration_s

    def tau(length_s: float) -> np.ndarray:  # 0..1 over a motion of that length centred at ``mid``
        return (t - mid) / length_s + 0.5

    if name.startswith("swipe_") or name in ("push", "pull"):
        direction = {"swipe_left": np.array([-1.0, 0, 0]), "swipe_right": np.array([1.0, 0, 0]),
                     "swipe_up": np.array([0, 1.0, 0]), "swipe_down": np.array([0, -1.0, 0]),
                     "push": -sight, "pull": sight}[name]
        length = SWIPE_M * draw.amplitude
        offset = (min_jerk(tau(SWIPE_S / draw.speed)) - 0.5)[:, None] * length * direction
    elif name in ("tap", "double_tap"):
        n = 1 if name == "tap" else 2
        s = tau(n * TAP_S / draw.speed) * n
        flex = bump(s - np.floor(np.clip(s, 0, n - 1e-9))) * ((s >= 0) & (s <= n))
        joints = _flex_index(joints, np.deg2rad(TAP_DEG) * draw.amplitude * flex)
    elif name == "pinch":
        joints = _pinch(joints, bump(tau(2 * TAP_S / draw.speed)))
    elif name in ("circle_cw", "circle_ccw"):
        turns = 1.5
        s = np.clip(tau(turns * CIRCLE_S / draw.speed), 0, 1)
        phase = 2 * np.pi * turns * min_jerk(s) * (1 if name == "circle_ccw" else -1)
        radius = CIRCLE_RADIUS_M * draw.amplitude
        lateral = np.cross([0.0, 1.0, 0.0], sight)  # x turned with the line of sight
        offset = radius * (np.cos(phase)[:, None] - 1) * lateral + radius * np.sin(phase)[:, None] * sight
    elif name == "idle":
        offset = tremor(t, TREMOR_M * draw.amplitude, rng)
    else:  # random: low-pass noise (a few knots, cubic) of WANDER_M
        knots = np.linspace(0, duration_s, 6)
        values = rng.normal(0.0, WANDER_M * draw.amplitude / 2, (len(knots), 3))
        offset = np.stack([np.interp(t, knots, values[:, k]) for k in range(3)], axis=1)
        offset = np.apply_along_axis(lambda v: np.convolve(v, np.ones(25) / 25, mode="same"), 0, offset)
    if draw.tremor_mm > 0 and name != "idle":
        offset = offset + tremor(t, draw.tremor_mm * 1e-3, rng)
    positions = np.zeros((len(t), 2, N_JOINTS, 3), dtype=np.float32)
    positions[:, 0] = joints + centre + offset[:, None, :]
    mask = np.zeros((len(t), 2), dtype=bool)
    mask[:, 0] = True
    return HandSequence(positions, t, mask, source=f"motion:{name}", attrs={"motion": name, "draw": asdict(draw)})
