"""Standard-hand retargeting (Tang et al.): keep each bone's measured direction, replace its length.

The wrist is the origin of the hand: every joint is rebuilt outward from it along the kinematic
tree, ``child = parent + L_standard * unit(child_measured - parent_measured)``, then the rebuilt hand
is placed back at the measured wrist (the radar needs absolute positions). The result has the
pose and the motion of the measured hand but the bone lengths of one standard adult hand, so
that the simulator and RadarWeightNet do not depend on a tracker's per-user length estimates.

Standard lengths (metres), rounded adult means (not one subject):

- phalanges (MCP-PIP, PIP-DIP, DIP-tip; thumb MCP-IP, IP-tip): Buryanov A., Kotiuk V. (2010)
  "Proportions of hand segments", Int. J. Morphol. 28(3):755-758 (bone lengths), the distal
  segments lengthened by ~4 mm of finger pulp because our distal joint is the fingertip;
- wrist-MCP links ("metacarpal" bones of the canonical skeleton: wrist crease to knuckle, i.e.
  metacarpal plus carpal row) and the thumb metacarpal: palm length of Greiner T.M. (1991)
  "Hand anthropometry of U.S. Army personnel", US Army Natick TR-92/011 (palm length ~0.10-0.11 m
  to the middle MCP crease), split over the four rays by the usual radiographic metacarpal
  proportions (index ~ middle > ring > little);
- wrist to thumb CMC (not one of the 19 bones, but a link of the tree): 0.035 m.

``scale`` multiplies all lengths (e.g. 0.93 for a smaller hand). A bone whose measured length is
(near) zero keeps zero length (its direction is undefined); untracked hands stay all-zero.

Public API (torch, differentiable in the positions; numpy arrays are accepted and returned as
torch tensors):

    standard_lengths(scale=1.0) -> np.ndarray (19,) metres, in BONES order
    retarget(positions (..., 21, 3), lengths=None | (19,), *, wrist_to_thumb_cmc_m=0.035)
        -> (..., 21, 3) same dtype
"""

from __future__ import annotations

import numpy as np
import torch

from handradar.hand.skeleton import BONE_NAMES, BONES, N_BONES, N_JOINTS

# Standard bone lengths in metres, keyed by BONE_NAMES (sources in the module docstring).
STANDARD_BONE_LENGTH_M: dict[str, float] = {
    "thumb_proximal": 0.046,      # CMC-MCP: thumb metacarpal
    "thumb_intermediate": 0.031,  # MCP-IP: proximal phalanx
    "thumb_distal": 0.025,        # IP-tip: distal phalanx + pulp
    "index_metacarpal": 0.090, "index_proximal": 0.040, "index_intermediate": 0.023, "index_distal": 0.020,
    "middle_metacarpal": 0.088, "middle_proximal": 0.045, "middle_intermediate": 0.027, "middle_distal": 0.021,
    "ring_metacarpal": 0.083, "ring_proximal": 0.042, "ring_intermediate": 0.026, "ring_distal": 0.021,
    "pinky_metacarpal": 0.078, "pinky_proximal": 0.033, "pinky_intermediate": 0.019, "pinky_distal": 0.019,
}
WRIST_TO_THUMB_CMC_M = 0.035
assert set(STANDARD_BONE_LENGTH_M) == set(BONE_NAMES)

# The kinematic tree as (parent, child, length index) links, parents before children. Index -1 is
# the wrist-thumb CMC link, which is not a bone.
_LINKS: tuple[tuple[int, int, int], ...] = ((0, 1, -1),) + tuple((a, b, i) for i, (a, b) in enumerate(BONES))
_EPS_M = 1e-6  # shorter measured bones have no direction


def standard_lengths(scale: float = 1.0) -> np.ndarray:
    """(19,) standard bone lengths in metres, BONES order, times ``scale``."""
    return scale * np.array([STANDARD_BONE_LENGTH_M[n] for n in BONE_NAMES], dtype=np.float64)


def retarget(positions: torch.Tensor | np.ndarray, lengths: torch.Tensor | np.ndarray | None = None, *,
             wrist_to_thumb_cmc_m: float = WRIST_TO_THUMB_CMC_M) -> torch.Tensor:
    """Joints (..., 21, 3) metres -> joints with standard bone lengths, same directions and wrist.

    lengths: (19,) metres in BONES order (default :func:`standard_lengths`).
    """
    pos = torch.as_tensor(positions)
    if pos.shape[-2:] != (N_JOINTS, 3):
        raise ValueError(f"positions must end in (21, 3), found {tuple(pos.shape)}")
    lens = torch.as_tensor(standard_lengths() if lengths is None else lengths, dtype=pos.dtype, device=pos.device)
    if lens.shape != (N_BONES,):
        raise ValueError(f"lengths must have shape (19,), found {tuple(lens.shape)}")
    link_len = torch.cat([lens.new_tensor([wrist_to_thumb_cmc_m]), lens])
    parent = torch.tensor([a for a, _, _ in _LINKS], device=pos.device)
    child = torch.tensor([b for _, b, _ in _LINKS], device=pos.device)
    vec = pos[..., child, :] - pos[..., parent, :]  # (..., 20, 3) measured link vectors
    norm = vec.norm(dim=-1, keepdim=True)
    unit = torch.where(norm > _EPS_M, vec / norm.clamp_min(_EPS_M), torch.zeros_like(vec))
    step = unit * link_len[:, None]  # (..., 20, 3)
    # Accumulate along the tree; a list keeps autograd simple (20 links, parents first).
    joints: list[torch.Tensor | None] = [None] * N_JOINTS
    joints[0] = pos[..., 0, :]
    for j, (a, b, _) in enumerate(_LINKS):
        joints[b] = joints[a] + step[..., j, :]
    return torch.stack(joints, dim=-2)  # type: ignore[arg-type]


# Open, flat standard hand: wrist at the origin, fingers along +y, palm facing -z, thumb toward -x
# (a right hand seen from above with its palm down). Angles from +y in the palm plane, degrees,
# positive toward the thumb.
_RAY_ANGLE_DEG = {"index": 12.0, "middle": 0.0, "ring": -11.0, "pinky": -23.0}
_THUMB_ANGLE_DEG = (55.0, 40.0, 30.0, 25.0)  # wrist-CMC link, then the three thumb bones


def standard_hand(scale: float = 1.0, hand: str = "right") -> np.ndarray:
    """(21, 3) joints of the open standard hand (metres; see the comment above); ``hand="left"``
    mirrors x. A reference pose for tests, examples and synthetic sequences."""
    lens = dict(zip(BONE_NAMES, standard_lengths(scale)))
    j = np.zeros((N_JOINTS, 3))

    def direction(deg: float) -> np.ndarray:
        a = np.deg2rad(deg)
        return np.array([-np.sin(a), np.cos(a), 0.0])

    j[1] = direction(_THUMB_ANGLE_DEG[0]) * WRIST_TO_THUMB_CMC_M * scale
    for i, part in enumerate(("proximal", "intermediate", "distal")):
        j[2 + i] = j[1 + i] + direction(_THUMB_ANGLE_DEG[1 + i]) * lens[f"thumb_{part}"]
    for f, finger in enumerate(("index", "middle", "ring", "pinky")):
        base = 5 + 4 * f
        d = direction(_RAY_ANGLE_DEG[finger])
        j[base] = d * lens[f"{finger}_metacarpal"]
        for i, part in enumerate(("proximal", "intermediate", "distal")):
            j[base + 1 + i] = j[base + i] + d * lens[f"{finger}_{part}"]
    if hand == "left":
        j[:, 0] *= -1
    elif hand != "right":
        raise ValueError(f"hand must be 'right' or 'left', found {hand!r}")
    return j
