"""MediaPipe Hands world landmarks -> HandSequence (already the canonical 21-joint order).

MediaPipe's ``multi_hand_world_landmarks`` are metres with the origin at the hand's approximate
centre and the image's axes: x right, y down, z away from the camera (right-handed), so the up
axis is '-y'. Its handedness label assumes a mirrored (selfie) image: pass the true hand.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from handradar.errors import FormatError
from handradar.hand.skeleton import HANDS, N_JOINTS, HandSequence

UP_AXIS = "-y"


def mediapipe_sequence(landmarks: np.ndarray, times_s: np.ndarray, *, hands: Sequence[str] = ("right",),
                       mask: np.ndarray | None = None, source: str = "<mediapipe>") -> HandSequence:
    """landmarks (T, 21, 3) for one hand or (T, H, 21, 3) for ``hands`` (H names, 'right'/'left');
    times_s (T,) seconds; mask (T, H) of the frames where each hand was detected (default all)."""
    lm = np.asarray(landmarks, dtype=np.float64)
    if lm.ndim == 3:
        lm = lm[:, None]
    hands = tuple(hands)
    if lm.ndim != 4 or lm.shape[1:] != (len(hands), N_JOINTS, 3):
        raise FormatError(source, f"expected landmarks (T, 21, 3) or (T, {len(hands)}, 21, 3) for hands {hands}, "
                                  f"found {np.shape(landmarks)}")
    if len(set(hands)) != len(hands) or not set(hands) <= set(HANDS):
        raise FormatError(source, f"hands must be distinct names among {HANDS}, found {hands}")
    m = np.ones(lm.shape[:2], dtype=bool) if mask is None else np.asarray(mask, dtype=bool).reshape(lm.shape[:2])
    positions = np.zeros((lm.shape[0], 2, N_JOINTS, 3), dtype=np.float32)
    full_mask = np.zeros((lm.shape[0], 2), dtype=bool)
    for i, h in enumerate(hands):
        positions[:, HANDS.index(h)] = np.where(m[:, i, None, None], lm[:, i], 0.0)
        full_mask[:, HANDS.index(h)] = m[:, i]
    return HandSequence(positions, np.asarray(times_s, dtype=np.float64), full_mask, source=source,
                        attrs={"up_axis": UP_AXIS, "frame": "mediapipe world"})
