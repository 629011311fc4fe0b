"""Gesture kinematics: joint angles -> forward kinematics on a per-subject skeleton.

A hand is a rigid palm frame (wrist position + orientation) carrying five finger chains. Each
chain starts at a fixed base in the palm (thumb CMC, finger MCPs) and bends by an abduction
angle at its base and three flexion angles (thumb: CMC abduction/flexion, MCP and IP flexion).
Bone lengths come from an adult template scaled by the subject's hand size (0.85-1.15) with a
few per-cent per-bone variation. Hand-local frame: +y along the fingers, +z out of the back of the
hand (dorsal), +x = y cross z; a left hand is the mirror image (x -> -x) of a right hand.

Radar frame (docs/architecture.md, "Coordinates and units"): z is boresight (up), the user sits at -y facing +y, so their right
is +x. At rest a hand is held palm down (dorsal +z, fingers +y) 0.22-0.36 m above the radar; for
angle theta the gesture centre moves to x = h tan(theta) (the hand seen theta off boresight).

Gestures (paper indices 1-10; hands; occlusion, i.e. a part hides another from the radar below):

| gesture | hands | occlusion | motion |
|---|---|---|---|
| grasp | 1 | yes | fingers and thumb curl into a fist and reopen; curled fingers cover the palm |
| finger_friction | 1 | no | thumb tip rubs index/middle tips (4 small strokes) |
| finger_wave | 1 | no | fingers flex in sequence, pinky first, two waves |
| circle | 1 | no | pointing hand draws 1.25 circles in a plane tilted 50 deg towards the radar |
| slide | 1 | no | hand swipes 0.22 m sideways and back |
| finger_cross | 1 | yes | middle finger crosses over the index and back, twice (one finger hides the other) |
| double_hand_clap | 2 | yes | palms face each other and clap twice (each hand hides the other's palm) |
| double_hand_drumming | 2 | no | both hands tap their fingers, alternating, three taps each |
| hand_merge | 2 | yes | hands approach and stack, the right one above the left (the lower hides the upper) |
| double_hand_circle | 2 | no | both hands draw one mirrored circle each |

Speeds: the envelopes below keep fingertips under about 1.5 m/s for the fastest subject
(speed 1.25); tests check the bound on every gesture.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from handradar.vocab import GESTURES
from handradar.world.config import Kinematics

GESTURE_TABLE: dict[str, tuple[int, bool]] = {
    "grasp": (1, True), "finger_friction": (1, False), "finger_wave": (1, False), "circle": (1, False),
    "slide": (1, False), "finger_cross": (1, True), "double_hand_clap": (2, True),
    "double_hand_drumming": (2, False), "hand_merge": (2, True), "double_hand_circle": (2, False),
}
assert tuple(GESTURE_TABLE) == GESTURES

# Adult right-hand template (hand scale 1), metres, hand-local frame. Bases: thumb CMC, index..pinky MCP.
_BASES = np.array([[-0.022, 0.028, -0.012], [-0.026, 0.090, 0.0], [-0.005, 0.093, 0.0],
                   [0.015, 0.087, 0.0], [0.032, 0.077, 0.0]])
# Bone lengths of each chain: thumb CMC-MCP, MCP-IP, IP-tip; fingers proximal, middle, distal.
_LENGTHS = np.array([[0.044, 0.032, 0.027], [0.040, 0.024, 0.020], [0.045, 0.028, 0.021],
                     [0.042, 0.027, 0.021], [0.033, 0.019, 0.018]])
_RADIUS_REL = np.array([1.12, 1.0, 1.02, 0.97, 0.86])  # finger thickness relative to finger_radius_m
# Rest angles per chain: [abduction, flex1, flex2, flex3] (radians; thumb: CMC abd, CMC flex, MCP, IP).
REST = np.array([[0.0, 0.15, 0.15, 0.10], [-0.10, 0.12, 0.18, 0.12], [0.0, 0.12, 0.18, 0.12],
                 [0.08, 0.14, 0.20, 0.13], [0.18, 0.16, 0.22, 0.15]])
PALM_CENTRE = np.array([0.0, 0.055, 0.0])  # hand-local, scale 1


def _rot_x(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def _rot_z(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _finger_base_frames() -> np.ndarray:
    """(5, 3, 3) rotation of each chain's frame (columns: flexion axis, bone direction, normal) in the hand frame."""
    frames = []
    for f in range(5):
        if f == 0:  # thumb: points forward-outward, tilted towards the palm; flexes across the palm
            d = np.array([-0.65, 0.75, -0.10])
            up = np.array([-0.90, 0.0, 0.45])
        else:  # fingers splay slightly outward from the hand axis
            d = np.array([_BASES[f, 0] * 1.6, 1.0, 0.0])
            up = np.array([0.0, 0.0, 1.0])
        d /= np.linalg.norm(d)
        n = up - (up @ d) * d
        n /= np.linalg.norm(n)
        x = np.cross(d, n)
        frames.append(np.stack([x, d, n], axis=1))
    return np.stack(frames)


_BASE_FRAMES = _finger_base_frames()


@dataclass(frozen=True)
class HandGeometry:
    """One subject's hand (right-hand form, hand-local metres)."""

    scale: float
    bases: np.ndarray  # (5, 3)
    lengths: np.ndarray  # (5, 3)
    finger_radius_m: np.ndarray  # (5,) at the chain base; tapers to 75 % at the tip

    @classmethod
    def sample(cls, rng: np.random.Generator, scale: float, finger_radius_m: float) -> HandGeometry:
        var = rng.normal(1.0, 0.04, size=_LENGTHS.shape).clip(0.9, 1.1)
        return cls(scale=scale, bases=_BASES * scale * rng.normal(1.0, 0.02, size=_BASES.shape).clip(0.95, 1.05),
                   lengths=_LENGTHS * scale * var, finger_radius_m=finger_radius_m * scale * _RADIUS_REL)


def forward_kinematics(geom: HandGeometry, angles: np.ndarray, left: bool) -> np.ndarray:
    """Joint angles (T, 5, 4) -> canonical 21 joints (T, 21, 3) in the hand-local frame (metres)."""
    t = angles.shape[0]
    out = np.zeros((t, 21, 3))
    for f in range(5):
        rot = _BASE_FRAMES[f] @ _rot_z(angles[:, f, 0])  # abduction about the chain's normal
        p = np.broadcast_to(geom.bases[f], (t, 3)).copy()
        out[:, 1 + 4 * f] = p
        for k in range(3):
            rot = rot @ _rot_x(-angles[:, f, 1 + k])  # flexion bends the bone towards the palm (-normal)
            p = p + rot[:, :, 1] * geom.lengths[f, k]
            out[:, 2 + 4 * f + k] = p
    if left:
        out[..., 0] *= -1.0
    return out


# ---- gesture programs ------------------------------------------------------------------------------
def _clip(u: np.ndarray) -> np.ndarray:
    return np.clip(u, 0.0, 1.0)


def smooth(u: np.ndarray) -> np.ndarray:
    """Smoothstep 0 -> 1 with zero slope at both ends."""
    u = _clip(u)
    return u * u * (3.0 - 2.0 * u)


def envelope(u: np.ndarray, edge: float = 0.15) -> np.ndarray:
    """1 inside (0, 1), ramping smoothly to 0 over ``edge`` at both ends."""
    return smooth(u / edge) * smooth((1.0 - u) / edge)


def cycles(u: np.ndarray, n: float) -> np.ndarray:
    """0 -> 1 -> 0, n times over u in [0, 1] (raised cosine)."""
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * n * _clip(u))


@dataclass
class HandProgram:
    """What one hand does: offsets from its rest pose, all (T, ...) arrays."""

    offset: np.ndarray  # (T, 3) wrist displacement, radar-aligned gesture frame, metres
    rotvec: np.ndarray  # (T, 3) extra rotation of the hand (radar-aligned axes), radians
    angles: np.ndarray  # (T, 5, 4) joint angles
    rest_x: float = 0.0  # lateral rest position of this hand relative to the gesture centre, metres
    roll: float = 0.0  # base roll about the finger axis (palms facing each other for a clap), radians


def _program(t_shape: int) -> HandProgram:
    return HandProgram(np.zeros((t_shape, 3)), np.zeros((t_shape, 3)), np.broadcast_to(REST, (t_shape, 5, 4)).copy())


def _grasp(u, a, style):
    p = _program(len(u))
    c = smooth(u / 0.38) * smooth((1.0 - u) / 0.38)
    p.angles[:, 1:, 1:] += c[:, None, None] * a * np.array([1.35, 1.5, 1.0])
    p.angles[:, 0] += c[:, None] * a * np.array([0.0, 0.4, 0.45, 0.35])
    p.offset[:, 2] += 0.012 * a * c
    p.rotvec[:, 0] += 0.12 * a * c
    return [p]


def _finger_friction(u, a, style):
    p = _program(len(u))
    pose = smooth(u / 0.18) * smooth((1.0 - u) / 0.18)
    p.angles[:, 1:3] += pose[:, None, None] * np.array([0.0, 0.55, 0.75, 0.5])
    p.angles[:, 0] += pose[:, None] * np.array([0.0, 0.45, 0.3, 0.2])
    rub = np.sin(2 * np.pi * 4.0 * _clip(u) + style) * envelope(u, 0.22) * a
    p.angles[:, 0, 2] += 0.32 * rub
    p.angles[:, 0, 3] += 0.30 * rub
    p.angles[:, 1, 1] -= 0.12 * rub
    return [p]


def _finger_wave(u, a, style):
    p = _program(len(u))
    env = envelope(u, 0.12)
    for f in range(1, 5):
        w = cycles(2.0 * u - 0.16 * (4 - f), 1.0) * ((2.0 * u - 0.16 * (4 - f) > 0) & (2.0 * u - 0.16 * (4 - f) < 2))
        p.angles[:, f, 1] += a * 0.95 * w * env
        p.angles[:, f, 2] += a * 0.7 * w * env
        p.angles[:, f, 3] += a * 0.45 * w * env
    return [p]


def _circle_offset(u, radius, turns, tilt_deg, sign=1.0, phase=0.0):
    phi = 2 * np.pi * turns * smooth(u) * sign + phase
    e1 = np.array([1.0, 0.0, 0.0])
    tilt = np.deg2rad(tilt_deg)
    e2 = np.array([0.0, np.cos(tilt), np.sin(tilt)])
    # centred on the rest position: the hand waits on the circle before and after drawing it
    return radius * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)


def _pointing(p: HandProgram, amount: np.ndarray) -> None:
    p.angles[:, 1, 1:] -= amount[:, None] * REST[1, 1:]  # index straight
    p.angles[:, 2:, 1:] += amount[:, None, None] * np.array([1.3, 1.4, 0.9])
    p.angles[:, 0] += amount[:, None] * np.array([0.0, 0.35, 0.4, 0.3])


def _circle(u, a, style):
    p = _program(len(u))
    _pointing(p, smooth(u / 0.22) * smooth((1.0 - u) / 0.22))
    p.offset += _circle_offset(u, 0.055 * a, 1.25, 50.0, phase=style)
    return [p]


def _slide(u, a, style):
    p = _program(len(u))
    go = smooth((u - 0.05) / 0.42) - smooth((u - 0.55) / 0.42)
    p.offset[:, 0] += 0.22 * a * (go - 0.5)
    p.offset[:, 2] -= 0.02 * a * np.sin(np.pi * go)
    p.rotvec[:, 1] += 0.15 * a * (go - 0.5)
    return [p]


def _finger_cross(u, a, style):
    p = _program(len(u))
    c = cycles(u, 2.0) * envelope(u, 0.1) * a
    p.angles[:, 2] += c[:, None] * np.array([-0.5, 0.3, 0.15, 0.1])
    p.angles[:, 1] += c[:, None] * np.array([0.18, 0.12, 0.05, 0.0])
    p.angles[:, 3:] += c[:, None, None] * np.array([0.0, 0.35, 0.4, 0.3])
    p.rotvec[:, 1] += 0.08 * c
    return [p]


def _double_hand_clap(u, a, style):
    right, left = _program(len(u)), _program(len(u))
    # contact when the palms (half a palm thickness from each wrist axis, rolled by 75 deg) touch
    gap0, contact = 0.26 * a, 0.05
    c = cycles(u, 2.0) ** 1.3
    gap = gap0 - (gap0 - contact) * c
    for p, s in ((right, 1.0), (left, -1.0)):
        p.rest_x = s * gap0 / 2
        p.offset[:, 0] += s * (gap - gap0) / 2
        p.roll = s * np.deg2rad(75.0)
        p.angles[:, :, 1:] -= 0.5 * REST[:, 1:]  # flat hands
    return [right, left]


def _double_hand_drumming(u, a, style):
    right, left = _program(len(u)), _program(len(u))
    env = envelope(u, 0.08)
    for p, s, ph in ((right, 1.0, 0.0), (left, -1.0, np.pi)):
        p.rest_x = s * 0.09
        tap = np.maximum(0.0, np.sin(2 * np.pi * 3.0 * _clip(u) + ph + style)) ** 2 * env * a
        p.angles[:, 1:, 1] += 0.55 * tap[:, None]
        p.angles[:, 1:, 2] += 0.25 * tap[:, None]
        p.offset[:, 2] -= 0.012 * tap
        p.rotvec[:, 0] += 0.15 * tap
    return [right, left]


def _hand_merge(u, a, style):
    right, left = _program(len(u)), _program(len(u))
    s = smooth(u / 0.62)
    for p, side in ((right, 1.0), (left, -1.0)):
        p.rest_x = side * 0.12 * a
        p.offset[:, 0] -= side * 0.12 * a * s
    right.offset[:, 2] += 0.04 * s  # the right hand ends on top of the left one
    right.offset[:, 1] += 0.01 * s
    left.offset[:, 2] -= 0.005 * s
    return [right, left]


def _double_hand_circle(u, a, style):
    right, left = _program(len(u)), _program(len(u))
    for p, side in ((right, 1.0), (left, -1.0)):
        p.rest_x = side * 0.11
        off = _circle_offset(u, 0.05 * a, 1.0, 45.0, sign=side, phase=style if side > 0 else np.pi - style)
        p.offset += off
    return [right, left]


PROGRAMS: dict[str, Callable[[np.ndarray, float, float], list[HandProgram]]] = {
    "grasp": _grasp, "finger_friction": _finger_friction, "finger_wave": _finger_wave, "circle": _circle,
    "slide": _slide, "finger_cross": _finger_cross, "double_hand_clap": _double_hand_clap,
    "double_hand_drumming": _double_hand_drumming, "hand_merge": _hand_merge,
    "double_hand_circle": _double_hand_circle,
}


# ---- subjects and recordings -------------------------------------------------------------------
@dataclass(frozen=True)
class Subject:
    """Per-subject anatomy and style (drawn once per subject from the world seed)."""

    index: int
    geometry: HandGeometry
    speed: float
    amplitude: float
    height_m: float
    left_handed: bool
    yaw_deg: float  # hand heading relative to +y
    pitch_deg: float
    style: float  # phase of oscillatory gestures, radians

    @classmethod
    def sample(cls, index: int, rng: np.random.Generator, kin: Kinematics, finger_radius_m: float) -> Subject:
        scale = float(rng.uniform(*kin.hand_scale))
        return cls(index=index, geometry=HandGeometry.sample(rng, scale, finger_radius_m),
                   speed=float(rng.uniform(*kin.speed)), amplitude=float(rng.uniform(*kin.amplitude)),
                   height_m=float(rng.uniform(*kin.height_m)), left_handed=bool(rng.random() < kin.left_handed_fraction),
                   yaw_deg=float(rng.normal(0, 8)), pitch_deg=float(rng.normal(0, 5)),
                   style=float(rng.uniform(0, 2 * np.pi)))

    def summary(self) -> dict[str, float | bool]:
        return {"hand_scale": round(self.geometry.scale, 4), "speed": round(self.speed, 4),
                "amplitude": round(self.amplitude, 4), "height_m": round(self.height_m, 4),
                "left_handed": self.left_handed}


@dataclass
class Pose:
    """The true hands at some times: joints (T, 2, 21, 3) radar frame, hand rotations (T, 2, 3, 3)
    (columns: hand-local x, y, z in the radar frame), elbows (2, 3), tracked hands (2,)."""

    times: np.ndarray
    joints: np.ndarray
    rotations: np.ndarray
    elbows: np.ndarray
    present: np.ndarray
    geometry: HandGeometry

    def palm_centres(self) -> np.ndarray:
        """(T, 2, 3) centre of each palm, radar frame (metres)."""
        local = PALM_CENTRE * self.geometry.scale
        return self.joints[:, :, 0] + np.einsum("thij,j->thi", self.rotations, local)


def _tremor(rng: np.random.Generator, kin: Kinematics) -> Callable[[np.ndarray], np.ndarray]:
    """Physiological tremor (8-12 Hz) and slow postural drift of one hand: t (T,) -> (T, 3) metres."""
    f_t = rng.uniform(8.0, 12.0, size=(3, 3))
    ph_t = rng.uniform(0, 2 * np.pi, size=(3, 3))
    f_d = rng.uniform(0.15, 0.6, size=(2, 3))
    ph_d = rng.uniform(0, 2 * np.pi, size=(2, 3))

    def fn(t: np.ndarray) -> np.ndarray:
        tt = t[:, None, None]
        trem = (np.sin(2 * np.pi * f_t * tt + ph_t)).sum(1) * kin.tremor_m / np.sqrt(1.5 * 3)
        drift = (np.sin(2 * np.pi * f_d * tt + ph_d)).sum(1) * kin.drift_m / np.sqrt(2.0)
        return trem + drift

    return fn


class Motion:
    """One recording's true hand motion, evaluated at any times (seconds on the radar clock)."""

    def __init__(self, gesture: str, subject: Subject, angle_deg: float, capture_s: float, kin: Kinematics,
                 rng: np.random.Generator, forearm_m: float = 0.26) -> None:
        if gesture not in PROGRAMS:
            raise ValueError(f"unknown gesture {gesture!r}; expected one of {GESTURES}")
        self.gesture = gesture
        self.subject = subject
        self.n_hands, self.occlusion = GESTURE_TABLE[gesture]
        j = kin.repetition_jitter
        self.duration_s = float(kin.duration_s / subject.speed * rng.uniform(1 - j, 1 + j))
        self.duration_s = min(self.duration_s, max(0.5, capture_s - 0.5))
        slack = capture_s - self.duration_s
        lo, hi = min(0.3, slack / 2), max(min(0.3, slack / 2), slack - 0.3)
        self.start_s = float(rng.uniform(lo, hi))
        self.amplitude = float(subject.amplitude * rng.uniform(1 - j, 1 + j))
        height = subject.height_m + rng.normal(0, kin.position_jitter_m)
        theta = np.deg2rad(angle_deg)
        self.centre = np.array([height * np.tan(theta), rng.normal(0, kin.position_jitter_m), height])
        rj = kin.rotation_jitter_deg
        yaw = np.deg2rad(subject.yaw_deg + rng.normal(0, rj))
        pitch = np.deg2rad(subject.pitch_deg + rng.normal(0, rj))
        roll = np.deg2rad(rng.normal(0, rj))
        self.base = Rotation.from_euler("zxy", [yaw, pitch, roll]).as_matrix()
        if self.n_hands == 1:
            self.slots = [1 if subject.left_handed else 0]
        else:
            self.slots = [0, 1]  # programs list the right hand first
        self.style = subject.style + rng.normal(0, 0.3)
        self.tremor = [_tremor(rng, kin) for _ in self.slots]
        # elbows: behind and below the rest wrist, fixed for the recording (the forearm pivots about them)
        rest = self._programs(np.array([0.0]))
        self.elbows = np.zeros((2, 3))
        for slot, prog in zip(self.slots, rest):
            side = 1.0 if slot == 0 else -1.0
            wrist0 = self._wrist(prog, 0, side)
            back = self.base @ np.array([0.06 * side, -0.93, -0.36])
            self.elbows[slot] = wrist0 + forearm_m * subject.geometry.scale * back / np.linalg.norm(back)

    def _programs(self, t: np.ndarray) -> list[HandProgram]:
        u = (t - self.start_s) / self.duration_s
        return PROGRAMS[self.gesture](u, self.amplitude, self.style)

    def _wrist(self, prog: HandProgram, i: int | slice, side: float) -> np.ndarray:
        palm = self.base @ (PALM_CENTRE * self.subject.geometry.scale)
        rest = self.centre + self.base @ np.array([prog.rest_x, 0.0, 0.0]) - palm
        # a left-handed subject mirrors single-hand programs (written for the right hand)
        mirror = np.array([side if self.n_hands == 1 else 1.0, 1.0, 1.0])
        return rest + (prog.offset[i] * mirror) @ self.base.T

    def pose(self, times: np.ndarray) -> Pose:
        t = np.asarray(times, dtype=np.float64)
        geom = self.subject.geometry
        joints = np.zeros((len(t), 2, 21, 3))
        rots = np.tile(np.eye(3), (len(t), 2, 1, 1))
        present = np.zeros(2, dtype=bool)
        for k, (slot, prog) in enumerate(zip(self.slots, self._programs(t))):
            side = 1.0 if slot == 0 else -1.0
            left = slot == 1
            # the mirror image of a rotation vector (an axial vector) across x = 0 is (wx, -wy, -wz)
            extra = Rotation.from_rotvec(prog.rotvec * np.array([1.0, side, side])).as_matrix()
            roll = Rotation.from_rotvec([0.0, prog.roll, 0.0]).as_matrix()
            rot = self.base @ extra @ roll  # (T, 3, 3) hand-local -> radar
            wrist = self._wrist(prog, slice(None), side) + self.tremor[k](t)
            local = forward_kinematics(geom, prog.angles, left)
            joints[:, slot] = wrist[:, None, :] + np.einsum("tij,tkj->tki", rot, local)
            rots[:, slot] = rot
            present[slot] = True
        return Pose(t, joints, rots, self.elbows.copy(), present, geom)
