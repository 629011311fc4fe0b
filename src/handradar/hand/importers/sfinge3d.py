"""SFINGE3D (Caputo et al., Computers & Graphics 2020) Dictionary files -> canonical skeleton.

File: ``<root>/<class 1..13>/<instance>.txt``, one frame per line at 20 fps, 20 joints x 7
``;``-separated floats (position x, y, z in metres, then orientation quaternion x, y, z, w), with a
trailing ``;``. Joints: palm, thumb A/B/end, then index, middle, ring, pinky A/B/C/end.

Choices, measured on all 468 Dictionary instances (20 732 frames):

- Frame. Coordinates are a Unity scene's (y up, palm height ~2.4 m), which is *left-handed*.
  In the raw numbers the hand's (distal, radial, palmar) triad has determinant +1, i.e. a left
  hand in a right-handed frame, while the fingers flex toward that palmar side in 457 of 468
  instances: it is a right hand in a left-handed frame. The importer mirrors z (x right, y up,
  z toward the viewer afterwards), which makes it a right hand (slot 0) in a right-handed frame.
- Wrist. The "palm" joint's orientation has its local +x along the fingers (each finger joint's
  local +x points along its bone to machine precision), and the four finger A joints sit
  7.7-9.0 cm ahead of it along that axis: the anatomical wrist-to-MCP distance (MediaPipe's
  wrist landmark, the canonical joint 0), not the palm centre (about half that). So the wrist is
  the palm joint moved ``wrist_offset_m`` back along the palm's local -x, default 0 m. Wrist-to-MCP
  bones are then 7.3-10.6 cm (the 10.0-10.6 cm ones: 5 frames of a hand tracked 13 % larger).
- Thumb. The thumb's A-B (2.6-3.3 cm) and B-end (2.0-2.6 cm) are the proximal and distal
  phalanges, so A = MCP, B = IP, end = tip; the CMC is not in the file. It is placed on the line
  from the MCP toward the wrist at ``thumb_metacarpal_ratio`` (default 1.45, the adult ratio of
  thumb metacarpal to proximal phalanx length, ~46 / ~32 mm) times this hand's proximal phalanx:
  a rigid bone that scales with the hand, 3.8-4.8 cm here.
- Fingers: A/B/C/end = MCP/PIP/DIP/tip.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from handradar.errors import FormatError
from handradar.hand.importers.common import (
    MIRROR,
    read_float_rows,
    single_hand_sequence,
)
from handradar.hand.skeleton import HandSequence

FPS = 20.0
N_JOINTS = 20
CLASSES = ("one", "two", "three", "four", "ok", "pinch", "grab", "expand", "tap",
           "swipe_left", "swipe_right", "swipe_v", "swipe_o")  # folders 1..13
UP_AXIS = "y"
# source joint (0 palm, 1-3 thumb A/B/end, 4-19 fingers A/B/C/end) of each canonical joint 2..20
_THUMB = (1, 2, 3)  # -> canonical 2 (MCP), 3 (IP), 4 (tip)
_FINGERS = tuple(range(4, 20))  # -> canonical 5..20


def sfinge3d_joints(rows: np.ndarray, *, wrist_offset_m: float = 0.0, thumb_metacarpal_ratio: float = 1.45,
                    mirror: bool = True, path: str | Path = "<sfinge3d>") -> np.ndarray:
    """(T, 140) raw rows -> (T, 21, 3) canonical joints (metres, mirrored to right-handed by default)."""
    raw = rows.reshape(-1, N_JOINTS, 7)
    pos, quat = raw[..., :3], raw[..., 3:]
    qn = np.linalg.norm(quat[:, 0], axis=-1)
    if np.any(np.abs(qn - 1.0) > 1e-3):
        t = int(np.argmax(np.abs(qn - 1.0)))
        raise FormatError(path, f"palm orientation of frame {t + 1} is not a unit quaternion (norm {qn[t]:.4f}); "
                                "expected x y z w with norm 1")
    distal = Rotation.from_quat(quat[:, 0]).apply([1.0, 0.0, 0.0])  # palm's local +x: toward the fingers
    out = np.empty((raw.shape[0], 21, 3))
    out[:, 0] = pos[:, 0] - wrist_offset_m * distal
    out[:, 2:5] = pos[:, _THUMB]
    out[:, 5:21] = pos[:, _FINGERS]
    mcp, ip = out[:, 2], out[:, 3]
    back = out[:, 0] - mcp
    back /= np.maximum(np.linalg.norm(back, axis=-1, keepdims=True), 1e-12)
    out[:, 1] = mcp + thumb_metacarpal_ratio * np.linalg.norm(ip - mcp, axis=-1, keepdims=True) * back
    if mirror:
        out = out @ MIRROR["z"]
    return out


def read_sfinge3d(path: str | Path, *, fps: float = FPS, wrist_offset_m: float = 0.0,
                  thumb_metacarpal_ratio: float = 1.45, mirror: bool = True) -> HandSequence:
    """One Dictionary file -> right-hand HandSequence in the (mirrored) scene frame, t = 0 at frame 0."""
    path = Path(path)
    rows = read_float_rows(path, N_JOINTS * 7, sep=";", what="values (20 joints x position + quaternion)")
    if rows.shape[0] < 2:
        raise FormatError(path, f"expected at least 2 frames, found {rows.shape[0]}")
    joints = sfinge3d_joints(rows, wrist_offset_m=wrist_offset_m, thumb_metacarpal_ratio=thumb_metacarpal_ratio,
                             mirror=mirror, path=path)
    return single_hand_sequence(joints, np.arange(len(joints)) / fps, hand="right", source=str(path),
                                attrs={"up_axis": UP_AXIS, "fps": fps, "frame": "sfinge3d (z mirrored)"})


def _number(name: str) -> int | None:
    m = re.fullmatch(r"(\d+)(?:\.txt)?", name)
    return int(m.group(1)) if m else None


def dictionary_folder(root: str | Path) -> Path:
    """``root`` itself or its ``Dictionary`` subfolder: the one holding class folders 1..13."""
    root = Path(root)
    if not root.is_dir():
        raise FormatError(root, "no such folder (expected SFINGE3D's Dictionary, e.g. from `make fetch-data`)")
    for cand in (root, root / "Dictionary"):
        if cand.is_dir() and any((cand / str(c)).is_dir() for c in range(1, len(CLASSES) + 1)):
            return cand
    raise FormatError(root, "not a SFINGE3D folder: expected class folders 1..13 (or a Dictionary folder "
                            "holding them) with <instance>.txt files")


def sfinge3d_files(root: str | Path) -> list[tuple[Path, int, str]]:
    """(file, class index 0..12, item name 'class/instance') for every instance, in numeric order."""
    folder = dictionary_folder(root)
    out = []
    for cdir in sorted((p for p in folder.iterdir() if p.is_dir() and _number(p.name)), key=lambda p: _number(p.name)):
        c = _number(cdir.name)
        if not 1 <= c <= len(CLASSES):
            raise FormatError(cdir, f"class folder {c} out of range: expected 1..{len(CLASSES)}")
        files = sorted((f for f in cdir.glob("*.txt") if _number(f.name) is not None), key=lambda f: _number(f.name))
        out += [(f, c - 1, f"{c}/{f.stem}") for f in files]
    return out


def iter_sfinge3d(root: str | Path, **options) -> Iterator[tuple[HandSequence, int, str]]:
    """(sequence in the source frame, class index, item name) for every Dictionary instance."""
    for path, label, name in sfinge3d_files(root):
        yield read_sfinge3d(path, **options), label, name
