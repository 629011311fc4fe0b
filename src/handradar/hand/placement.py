"""Placing an external (non-radar) skeleton sequence over the radar.

Skeletons from DHG, SFINGE3D or MediaPipe live in their own frame (a camera's, a VR scene's). To
synthesise radar data they are moved, rigidly, to where a hand over the radar would be:

- the palm faces the radar: the sequence's mean palm normal (pointing out of the palm) is turned
  to radar -z, i.e. down toward the board (radar z is boresight, pointing up);
- the heading about boresight is fixed by the source's up axis: its part perpendicular to the mean
  palm normal becomes radar +y, so "up" in a camera frame becomes "forward" over the board, the
  way a raised hand is lowered flat with its fingers pointing away from the user. A source whose
  up axis is within ``min_heading_deg`` of the palm normal (a hand already palm-down) takes its
  heading from the mean hand direction (wrist -> middle MCP) instead;
- an optional extra yaw turns the result about boresight;
- the mean hand centre (wrist and four MCPs, over time) goes to ``centre_m``, by default 0.30 m
  above the radar on boresight.

One rotation and one translation are applied to the whole sequence, so the gesture's own motion
(translation, rotation, finger movement) and every bone length are kept exactly.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from handradar.hand.skeleton import HANDS, HandSequence

DEFAULT_CENTRE_M = (0.0, 0.0, 0.30)
_AXES = {"x": 0, "y": 1, "z": 2}
MCPS = (5, 9, 13, 17)
FINGER_TIPS = (8, 12, 16, 20)


def axis_vector(axis: str | Sequence[float]) -> np.ndarray:
    """'x', '-y', ... or a 3-vector -> unit vector."""
    if isinstance(axis, str):
        name = axis.strip().lower()
        sign = -1.0 if name.startswith("-") else 1.0
        name = name.lstrip("+-")
        if name not in _AXES:
            raise ValueError(f"axis must be one of x, y, z, -x, -y, -z or a 3-vector, found {axis!r}")
        v = np.zeros(3)
        v[_AXES[name]] = sign
        return v
    v = np.asarray(axis, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
        raise ValueError(f"axis must be a non-zero finite 3-vector, found {axis!r}")
    return v / np.linalg.norm(v)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def palm_normal(joints: np.ndarray, hand: str) -> np.ndarray:
    """Unit normal pointing out of the palm, from (..., 21, 3) canonical joints.

    With distal = wrist -> middle MCP and radial = pinky MCP -> index MCP, the palm of a right
    hand faces radial x distal (in a right-handed frame), a left hand's faces distal x radial.
    """
    radial = joints[..., 5, :] - joints[..., 17, :]
    distal = joints[..., 9, :] - joints[..., 0, :]
    n = np.cross(radial, distal) if hand == "right" else np.cross(distal, radial)
    return _unit(n)


def hand_direction(joints: np.ndarray) -> np.ndarray:
    """Unit vector wrist -> middle MCP."""
    return _unit(joints[..., 9, :] - joints[..., 0, :])


def hand_centre(joints: np.ndarray) -> np.ndarray:
    """Mean of the wrist and the four finger MCPs: the middle of the palm, metres."""
    return joints[..., (0, *MCPS), :].mean(axis=-2)


def flexion_score(seq: HandSequence) -> float:
    """Mean cosine between each finger's MCP -> tip vector and the palm normal, over tracked hands.

    Fingers flex toward the palm, so a correctly labelled hand in a right-handed frame scores
    > 0 unless every finger is held straight; a mirrored frame (or a wrong hand label) makes it
    negative. Used to check a source's frame convention on real data.
    """
    scores = []
    for slot, hand in enumerate(HANDS):
        j = seq.positions[seq.mask[:, slot], slot].astype(np.float64)
        if len(j) == 0:
            continue
        n = palm_normal(j, hand)
        flex = _unit(j[:, FINGER_TIPS] - j[:, MCPS])
        scores.append(np.einsum("tfi,ti->tf", flex, n).reshape(-1))
    if not scores:
        raise ValueError(f"{seq.source}: no tracked hand")
    return float(np.mean(np.concatenate(scores)))


def mean_palm_normal(seq: HandSequence) -> np.ndarray:
    """Sum of the tracked hands' palm normals over the sequence (not normalised)."""
    total = np.zeros(3)
    for slot, hand in enumerate(HANDS):
        j = seq.positions[seq.mask[:, slot], slot].astype(np.float64)
        if len(j):
            total += palm_normal(j, hand).sum(axis=0)
    return total


def placement_rotation(seq: HandSequence, up_axis: str | Sequence[float] = "y", *,
                       min_heading_deg: float = 20.0) -> tuple[np.ndarray, str]:
    """Rotation (3, 3) that turns the mean palm normal to -z and the source's up axis to +y.

    Returns the rotation and which heading reference was used ("up" or "hand").
    """
    up = axis_vector(up_axis)
    total = mean_palm_normal(seq)
    if np.linalg.norm(total) < 1e-6 * max(1, int(seq.mask.sum())):
        normal = -up  # the palm turns all the way round: no mean facing, keep the source's vertical
    else:
        normal = total / np.linalg.norm(total)
    heading = up - np.dot(up, normal) * normal
    used = "up"
    if np.linalg.norm(heading) < np.sin(np.radians(min_heading_deg)):
        used = "hand"
        d = np.zeros(3)
        for slot in range(2):
            j = seq.positions[seq.mask[:, slot], slot].astype(np.float64)
            if len(j):
                d += hand_direction(j).sum(axis=0)
        heading = d - np.dot(d, normal) * normal
        if np.linalg.norm(heading) < 1e-9:  # degenerate: any direction perpendicular to the normal
            heading = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    a_y = _unit(heading)
    a_z = -normal
    a_x = np.cross(a_y, a_z)
    return np.stack([a_x, a_y, a_z]), used  # rows: the source vectors that become radar x, y, z


def yaw_matrix(yaw_deg: float) -> np.ndarray:
    """Rotation by ``yaw_deg`` about radar z (boresight)."""
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def place_in_radar(seq: HandSequence, *, up_axis: str | Sequence[float] = "y",
                   centre_m: Sequence[float] = DEFAULT_CENTRE_M, yaw_deg: float = 0.0,
                   min_heading_deg: float = 20.0) -> HandSequence:
    """Move a source-frame sequence rigidly over the radar (see the module docstring).

    up_axis: the source frame's up direction ('y' for DHG and SFINGE3D, '-y' for MediaPipe).
    centre_m: where the mean hand centre goes, radar frame metres (default 0.30 m on boresight).
    yaw_deg: extra rotation about boresight after the palm-facing rotation.
    The returned sequence's ``attrs["placement"]`` records the rotation, translation and heading.
    """
    centre = np.asarray(centre_m, dtype=np.float64).reshape(-1)
    if centre.shape != (3,) or not np.all(np.isfinite(centre)):
        raise ValueError(f"centre_m must be a finite 3-vector in metres, found {centre_m!r}")
    if not seq.mask.any():
        raise ValueError(f"{seq.source}: no tracked hand to place")
    rot, used = placement_rotation(seq, up_axis, min_heading_deg=min_heading_deg)
    rot = yaw_matrix(yaw_deg) @ rot
    tracked = seq.positions[seq.mask].astype(np.float64)  # (n, 21, 3)
    translation = centre - rot @ hand_centre(tracked).mean(axis=0)
    out = seq.transformed(rot, translation)
    out.attrs["placement"] = {"rotation": rot.tolist(), "translation_m": translation.tolist(), "heading": used,
                              "up_axis": up_axis if isinstance(up_axis, str) else list(map(float, up_axis))}
    out.attrs["frame"] = "radar"
    return out
