"""A library of parametrised hand motions: skeleton sequences for any class vocabulary.

A measured radar dataset without skeletons (docs/datasets.md, "Measured radar datasets") names,
per class, one or more of these motions; synthesis draws skeletons from them. Each motion is a
procedural program on the open standard hand (:func:`handradar.hand.retarget.standard_hand`):

- ``swipe_left`` / ``swipe_right`` / ``swipe_up`` / ``swipe_down``: the forearm swings about the elbow
  (and the hand about the wrist, ``wrist_share`` of the angle), so the hand sweeps an arc whose chord
  runs along -x / +x / +y / -y of the radar frame (the board's azimuth axis and its forward axis);
- ``push`` / ``pull``: the hand translates toward / away from the radar along the line of sight;
- ``tap`` / ``double_tap``: the index finger flexes toward the radar and back, once or twice;
- ``pinch``: thumb and index tips close, hold ``hold_s`` closed and open again;
- a tap or pinch may flex the wrist with it (``wrist_flex_deg`` at the finger's peak): the whole hand turns palm-ward
  about the wrist's lateral axis, its fingers toward the radar, with the finger's own profile;
- ``circle_cw`` / ``circle_ccw``: the hand circles ``turns`` turns (1.5 unless drawn otherwise) in the plane
  holding the line of sight and x, clockwise or counter-clockwise with x to the right and the line of sight up;
- ``idle``: the hand holds still with a physiological tremor (about 1 mm, 8-12 Hz); any other motion
  may carry one too (``tremor_mm``);
- ``random``: a smooth random wander of a few centimetres (non-gesture hand movement).

Every motion carries its arm (``HandSequence.arm``: elbow and shoulder at every step): the forearm
leaves the wrist away from the fingers, tilted ``forearm_deg`` out of the palm plane away from the
radar and turned ``elbow_out_deg`` toward the hand's own side; the upper arm runs on to a shoulder
fixed for the sequence. A swipe turns the forearm about the fixed elbow, so its points move from zero
at the elbow to the hand's speed at the wrist, and an arc across the beam is lopsided: the part of the
hand's path along the forearm's tilt and turn is radial. Any
other motion moves the hand and the elbow follows it by two-link inverse kinematics
(:func:`elbow_ik`), the shoulder held.

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

# Raised whenever a motion's kinematics change (2: the arm, swipes swung about the elbow, circles' turns drawn; 3: wrist
# flexion in taps and pinches, a pinch's hold).
MOTIONS_VERSION = 3
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
    "forearm_deg": (60.0, 90.0),   # forearm out of the palm plane, away from the radar (0: in it; 90: along the sight)
    "elbow_out_deg": (30.0, 60.0), # the arm turned about the vertical toward the hand's side (chosen on validation)
    "wrist_share": (0.0, 0.4),     # share of a swipe's angle turned at the wrist (the rest at the elbow)
    "turns": (1.5, 1.5),           # a circle's turns
    "wrist_flex_deg": (0.0, 0.0),  # a tap's or pinch's wrist flexion at the finger's peak (the hand palm-ward)
    "hold_s": (0.0, 0.0),          # a pinch held closed between closing and opening
}
SWIPE_M = 0.20          # swipe and push/pull length at amplitude 1
SWIPE_S = 0.5           # swipe duration at speed 1
TAP_S = 0.3             # one tap (down and up) at speed 1
TAP_DEG = 45.0          # index flexion at the bottom of a tap
CIRCLE_RADIUS_M = 0.05
CIRCLE_S = 0.8          # one turn at speed 1
TREMOR_M = 0.001        # physiological tremor amplitude
WANDER_M = 0.03         # random non-gesture movement
FOREARM_M = 0.26        # wrist to elbow at hand_scale 1 (adult forearm)
UPPER_ARM_M = 0.30      # elbow to shoulder at hand_scale 1
UPPER_ARM_DEG = 60.0    # the upper arm runs from the elbow away from the radar, raised this much toward the fingers
INDEX = (5, 6, 7, 8)    # MCP, PIP, DIP, tip
CENTRE = (0, 5, 9, 13, 17)  # the hand centre: wrist and finger MCPs
THUMB = (1, 2, 3, 4)
LATERAL = np.array([1.0, 0.0, 0.0])  # fingers along +y, palm facing -z: flexion about it turns +y toward -z


def library_key() -> dict:
    """What makes the library's sequences besides a source's own settings: its version and default draws. Cache keys of
    rows synthesised from motions hold it, so that a changed default or motion never reuses stale rows."""
    return {"version": MOTIONS_VERSION, "defaults": {k: list(v) for k, v in DEFAULT_RANGES.items()}}


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
    forearm_deg: float = 75.0
    elbow_out_deg: float = 0.0
    wrist_share: float = 0.0
    turns: float = 1.5
    wrist_flex_deg: float = 0.0
    hold_s: float = 0.0

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
    skew = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])  # skew @ v = a x v
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    rot = c * np.eye(3) + s * skew + (1 - c) * np.outer(a, a)  # (T, 3, 3): Rodrigues' matrix at each step
    return pivot + (points - pivot) @ rot.transpose(0, 2, 1)


def _flex_index(joints: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Index finger flexed toward the palm side by ``angle`` (T,) radians, split 50/30/20 over MCP, PIP, DIP."""
    out = joints.copy()
    for share, k in zip((0.5, 0.3, 0.2), range(3)):
        pivot = out[:, INDEX[k]][:, None, :]
        moving = list(INDEX[k + 1:])
        out[:, moving] = _rotate(out[:, moving], pivot, LATERAL, -share * angle)
    return out


def _flex_wrist(joints: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """The whole hand turned palm-ward about the wrist's lateral axis by ``angle`` (T,) radians: the fingers (+y)
    toward the palm's side (-z), as the index flexes in :func:`_flex_index`."""
    return _rotate(joints, joints[:, :1], LATERAL, -angle)


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
    j = j - j[list(CENTRE)].mean(axis=0)  # hand centre (wrist and MCPs) at the origin
    az = np.deg2rad(draw.azimuth_deg)
    centre = draw.distance_m * np.array([np.sin(az), 0.0, np.cos(az)])
    return j, centre


def arm_pose(draw: MotionDraw, wrist: np.ndarray, sight: np.ndarray, hand: str = "right") -> tuple[np.ndarray, np.ndarray]:
    """Rest elbow and shoulder (3,) each of a hand whose wrist is at ``wrist``, ``sight`` the unit vector radar -> hand:
    the forearm points away from the fingers (-y) tilted ``forearm_deg`` toward +sight, the upper arm on from the
    elbow along +sight raised ``UPPER_ARM_DEG`` toward +y; both turned ``elbow_out_deg`` about y toward the hand's
    side (+x for a right hand, -x for a left one)."""
    side = 1.0 if hand == "right" else -1.0
    phi, psi, beta = np.deg2rad(draw.forearm_deg), np.deg2rad(UPPER_ARM_DEG), side * np.deg2rad(draw.elbow_out_deg)
    up = np.array([0.0, 1.0, 0.0])
    back = np.cos(beta) * sight + np.sin(beta) * np.cross(up, sight)  # away from the radar, turned toward the side
    elbow = wrist + FOREARM_M * draw.hand_scale * (-np.cos(phi) * up + np.sin(phi) * back)
    return elbow, elbow + UPPER_ARM_M * draw.hand_scale * (np.cos(psi) * back + np.sin(psi) * up)


def elbow_ik(wrist: np.ndarray, shoulder: np.ndarray, upper_m: float, fore_m: float, pole: np.ndarray) -> np.ndarray:
    """Elbows (T, 3) of a two-link arm from a fixed ``shoulder`` to each ``wrist`` (T, 3): on the circle of points
    ``upper_m`` from the shoulder and ``fore_m`` from the wrist, the one nearest ``pole`` (3,); a wrist beyond reach
    straightens the arm toward it."""
    axis = wrist - shoulder
    d = np.linalg.norm(axis, axis=-1, keepdims=True)
    n = axis / np.maximum(d, 1e-9)
    d = np.clip(d, abs(upper_m - fore_m) + 1e-9, upper_m + fore_m)
    a = (upper_m**2 - fore_m**2 + d**2) / (2 * d)         # along the axis from the shoulder
    h = np.sqrt(np.maximum(upper_m**2 - a**2, 0.0))        # the circle's radius
    centre = shoulder + a * n
    off = pole - centre
    off = off - (off * n).sum(-1, keepdims=True) * n
    return centre + h * off / np.maximum(np.linalg.norm(off, axis=-1, keepdims=True), 1e-12)


def _swing(joints: np.ndarray, elbow: np.ndarray, axis: np.ndarray, angle: np.ndarray, wrist_share: float) -> np.ndarray:
    """Joints (T, 21, 3) turned ``wrist_share`` of ``angle`` (T,) about the wrist, then the rest about the elbow."""
    out = _rotate(joints, joints[:, :1], axis, wrist_share * angle)
    return _rotate(out, elbow, axis, (1 - wrist_share) * angle)


def _swipe_angle(pose: np.ndarray, elbow: np.ndarray, axis: np.ndarray, wrist_share: float, chord_m: float) -> float:
    """The swing angle (radians, at most half a turn) that carries the hand centre (wrist and MCPs) ``chord_m`` from
    start to end: the chord on 65 angles at once, then on 65 within the step that brackets ``chord_m``, interpolated
    (it grows with the angle up to half a turn; the fine step of 0.8 mrad puts the chord within a micrometre)."""
    centre = pose[list(CENTRE)]  # the wrist first: _swing turns the hand about it

    def chords(angles: np.ndarray) -> np.ndarray:
        ends = _swing(np.broadcast_to(centre, (2 * len(angles), *centre.shape)), elbow, axis,
                      np.concatenate([-angles / 2, angles / 2]), wrist_share).mean(axis=1)
        return np.linalg.norm(ends[len(angles):] - ends[:len(angles)], axis=-1)

    coarse = np.linspace(0.0, np.pi, 65)
    c = chords(coarse)
    if chord_m >= c[-1]:
        return float(np.pi)
    i = max(int(np.searchsorted(c, chord_m)), 1)
    fine = np.linspace(coarse[i - 1], coarse[i], 65)
    return float(np.interp(chord_m, chords(fine), fine))


def motion_sequence(name: str, draw: MotionDraw, *, duration_s: float = 3.2, rate_hz: float = 100.0,
                    rng: np.random.Generator | None = None, hand: str = "right") -> HandSequence:
    """One right hand (slot 0) with its arm performing motion ``name`` with ``draw``'s nuisance, ``duration_s`` long
    at ``rate_hz``.

    ``rng`` drives the idle tremor and the random wander (default: a fixed seed).
    """
    if name not in MOTIONS:
        raise ValueError(f"unknown motion {name!r}; expected one of {list(MOTIONS)}")
    rng = rng if rng is not None else np.random.default_rng(0)
    t = np.arange(int(round(duration_s * rate_hz))) / rate_hz
    pose, centre = hand_pose(draw, hand)
    pose = pose + centre
    sight = centre / np.linalg.norm(centre)  # unit vector radar -> hand
    elbow0, shoulder = arm_pose(draw, pose[0], sight, hand)
    joints = np.broadcast_to(pose, (len(t), N_JOINTS, 3)).copy()
    offset = np.zeros((len(t), 3))
    elbow = None  # None: the elbow follows the wrist (elbow_ik)
    mid = draw.onset * duration_s

    def tau(length_s: float) -> np.ndarray:  # 0..1 over a motion of that length centred at ``mid``
        return (t - mid) / length_s + 0.5

    if name.startswith("swipe_"):
        direction = {"swipe_left": [-1.0, 0, 0], "swipe_right": [1.0, 0, 0], "swipe_up": [0, 1.0, 0],
                     "swipe_down": [0, -1.0, 0]}[name]
        reach = pose[list(CENTRE)].mean(axis=0) - elbow0
        axis = np.cross(reach, direction)  # turning about it moves the hand centre along ``direction`` (its part
        axis = axis / np.linalg.norm(axis)  # across the forearm) at the middle of the arc
        angle = _swipe_angle(pose, elbow0, axis, draw.wrist_share, SWIPE_M * draw.amplitude)
        swing = (min_jerk(tau(SWIPE_S / draw.speed)) - 0.5) * angle
        joints = _swing(joints, elbow0, axis, swing, draw.wrist_share)
        elbow = np.broadcast_to(elbow0, (len(t), 3))
    elif name in ("push", "pull"):
        direction = -sight if name == "push" else sight
        offset = (min_jerk(tau(SWIPE_S / draw.speed)) - 0.5)[:, None] * SWIPE_M * draw.amplitude * direction
    elif name in ("tap", "double_tap"):
        n = 1 if name == "tap" else 2
        s = tau(n * TAP_S / draw.speed) * n
        flex = bump(s - np.floor(np.clip(s, 0, n - 1e-9))) * ((s >= 0) & (s <= n))
        joints = _flex_index(joints, np.deg2rad(TAP_DEG) * draw.amplitude * flex)
        joints = _flex_wrist(joints, np.deg2rad(draw.wrist_flex_deg) * flex)
    elif name == "pinch":
        # closing and opening each half a tap's bump (TAP_S / speed), held closed for hold_s between them
        half = TAP_S / draw.speed
        s = t - mid + half + draw.hold_s / 2  # seconds since the pinch began
        closure = np.where(s < half, bump(s / (2 * half)),
                           np.where(s < half + draw.hold_s, 1.0, bump((s - draw.hold_s) / (2 * half))))
        joints = _flex_wrist(_pinch(joints, closure), np.deg2rad(draw.wrist_flex_deg) * closure)
    elif name in ("circle_cw", "circle_ccw"):
        turns = draw.turns
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
    joints = joints + offset[:, None, :]
    if elbow is None:
        elbow = elbow_ik(joints[:, 0], shoulder, UPPER_ARM_M * draw.hand_scale, FOREARM_M * draw.hand_scale, elbow0)
    positions = np.zeros((len(t), 2, N_JOINTS, 3), dtype=np.float32)
    positions[:, 0] = joints
    arm = np.zeros((len(t), 2, 2, 3), dtype=np.float32)
    arm[:, 0, 0], arm[:, 0, 1] = elbow, shoulder
    mask = np.zeros((len(t), 2), dtype=bool)
    mask[:, 0] = True
    return HandSequence(positions, t, mask, source=f"motion:{name}", attrs={"motion": name, "draw": asdict(draw)},
                        arm=arm)
