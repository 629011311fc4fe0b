"""DHG-14/28 (De Smedt et al., CVPRW 2016) and SHREC'17 track skeletons -> canonical skeleton.

Layout: ``<root>/gesture_g/finger_f/subject_s/essai_e/skeleton_world.txt`` (SHREC'17:
``skeletons_world.txt``), one frame per line at 30 fps, 66 whitespace-separated floats = 22 joints
x (x, y, z) in metres in the depth camera's frame. Joints: 1 wrist, 2 palm, 3-6 thumb base, first
joint, second joint, tip, then the same four for index, middle, ring and pinky.
``<root>/informations_troncage_sequences.txt`` lists ``g f s e start end`` per sequence: the
effective gesture's first and last frame, 1-based (the dataset numbers its depth images
``depth_1.png`` .. ``depth_N.png``), inclusive.

Mapping: wrist -> 0, palm dropped, thumb base/first/second/tip -> CMC/MCP/IP/tip, each other
finger's base/first/second/tip -> MCP/PIP/DIP/tip. All participants are right-handed and the
gestures are one-handed: the hand goes to slot 0 (right) unless ``hand`` says otherwise.

Frame convention: the camera frame is taken as right-handed with ``up_axis`` 'y'. Neither could
be checked without the data (it is not available offline); ``mirror`` flips x if the RealSense
frame turns out left-handed, and :func:`handradar.hand.placement.flexion_score` on a few
sequences tells which holds (positive: the right hand's fingers flex toward its palm).

Classes: 14 gestures, or 28 = gesture x (one finger, whole hand), label 2 (g - 1) + (f - 1).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from handradar.errors import FormatError
from handradar.hand.importers.common import (
    MIRROR,
    read_float_rows,
    single_hand_sequence,
    trim_rows,
)
from handradar.hand.skeleton import HandSequence

FPS = 30.0
N_SOURCE_JOINTS = 22
TO_CANONICAL = (0, *range(2, 22))  # drop the palm (index 1)
GESTURES_14 = ("grab", "tap", "expand", "pinch", "rotation_cw", "rotation_ccw", "swipe_right", "swipe_left",
               "swipe_up", "swipe_down", "swipe_x", "swipe_plus", "swipe_v", "shake")
FINGERS = ("one_finger", "whole_hand")  # finger_1, finger_2
GESTURES_28 = tuple(f"{g}_{f}" for g in GESTURES_14 for f in FINGERS)
INFO_FILE = "informations_troncage_sequences.txt"
SKELETON_FILES = ("skeleton_world.txt", "skeletons_world.txt")
UP_AXIS = "y"
_SEQ_DIR = re.compile(r"gesture_(\d+)/finger_(\d+)/subject_(\d+)/essai_(\d+)")


@dataclass(frozen=True)
class DhgKey:
    gesture: int  # 1..14
    finger: int  # 1 one finger, 2 whole hand
    subject: int
    essai: int

    @property
    def name(self) -> str:
        return f"gesture_{self.gesture}/finger_{self.finger}/subject_{self.subject}/essai_{self.essai}"

    def label(self, n_classes: int) -> int:
        return self.gesture - 1 if n_classes == 14 else 2 * (self.gesture - 1) + self.finger - 1


def classes(n_classes: int = 14) -> tuple[str, ...]:
    if n_classes not in (14, 28):
        raise ValueError(f"DHG has 14 or 28 classes, found {n_classes}")
    return GESTURES_14 if n_classes == 14 else GESTURES_28


def read_info(path: str | Path) -> dict[DhgKey, tuple[int, int]]:
    """``informations_troncage_sequences.txt`` -> {key: (start, end)} (1-based, inclusive)."""
    path = Path(path)
    rows = read_float_rows(path, 6, what="integers (gesture finger subject essai start end)")
    if not np.all(rows == np.round(rows)):
        line = int(np.flatnonzero(np.any(rows != np.round(rows), axis=1))[0]) + 1
        raise FormatError(path, f"expected integers, found {rows[line - 1].tolist()} (data row {line})")
    out: dict[DhgKey, tuple[int, int]] = {}
    for i, (g, f, s, e, start, end) in enumerate(rows.astype(np.int64).tolist(), start=1):
        if not (1 <= g <= 14 and f in (1, 2) and start >= 1 and end > start):
            raise FormatError(path, f"data row {i}: expected gesture 1-14, finger 1-2 and 1 <= start < end, "
                                    f"found {g} {f} {s} {e} {start} {end}")
        out[DhgKey(g, f, s, e)] = (start, end)
    return out


def read_dhg(path: str | Path, *, start: int | None = None, end: int | None = None, fps: float = FPS,
             hand: str = "right", mirror: bool = False) -> HandSequence:
    """One ``skeleton_world.txt`` -> HandSequence in the camera frame, frames start..end (1-based,
    inclusive; default all), t = 0 at the first kept frame."""
    path = Path(path)
    rows = read_float_rows(path, N_SOURCE_JOINTS * 3, what="values (22 joints x 3)")
    rows = trim_rows(path, rows, start, end)
    joints = rows.reshape(-1, N_SOURCE_JOINTS, 3)[:, TO_CANONICAL]
    if mirror:
        joints = joints @ MIRROR["x"]
    return single_hand_sequence(joints, np.arange(len(joints)) / fps, hand=hand, source=str(path),
                                attrs={"up_axis": UP_AXIS, "fps": fps, "frame": "dhg camera" + (" (x mirrored)" if mirror else ""),
                                       "first_frame": 1 if start is None else int(start)})


def dhg_files(root: str | Path) -> list[tuple[Path, DhgKey]]:
    """Every sequence file under ``root`` with its key, in numeric (g, f, s, e) order."""
    root = Path(root)
    if not root.is_dir():
        raise FormatError(root, "no such directory (expected DHG-14/28's gesture_<g> folders, e.g. from "
                                "`handradar-fetch dataset=dhg fetch.url=URL`)")
    found = []
    for name in SKELETON_FILES:
        for p in root.glob(f"gesture_*/finger_*/subject_*/essai_*/{name}"):
            m = _SEQ_DIR.fullmatch(p.parent.relative_to(root).as_posix())
            if m:
                found.append((p, DhgKey(*map(int, m.groups()))))
    if not found:
        raise FormatError(root, "no DHG sequences: expected gesture_g/finger_f/subject_s/essai_e/"
                                f"{' or '.join(SKELETON_FILES)}")
    found.sort(key=lambda pk: (pk[1].gesture, pk[1].finger, pk[1].subject, pk[1].essai))
    return found


def load_info(root: str | Path, trim: bool) -> dict[DhgKey, tuple[int, int]] | None:
    """The start/end table of ``root`` when trimming (an explanatory FormatError if absent), else None."""
    if not trim:
        return None
    path = Path(root) / INFO_FILE
    if not path.is_file():
        raise FormatError(path, "missing: it gives each gesture's start and end frames "
                                "(pass trim=false to keep whole sequences, e.g. for SHREC'17)")
    return read_info(path)


def read_listed(path: str | Path, key: DhgKey, info: dict[DhgKey, tuple[int, int]] | None, **options) -> HandSequence:
    """:func:`read_dhg` trimmed to the frames ``info`` lists for ``key`` (whole file if info is None)."""
    if info is None:
        return read_dhg(path, **options)
    if key not in info:
        raise FormatError(path, f"{INFO_FILE} lists no start/end frames for {key.name}")
    start, end = info[key]
    return read_dhg(path, start=start, end=end, **options)


def iter_dhg(root: str | Path, *, n_classes: int = 14, trim: bool = True, fps: float = FPS,
             hand: str = "right", mirror: bool = False) -> Iterator[tuple[HandSequence, int, DhgKey]]:
    """(sequence in the camera frame, class index, key) for every sequence under ``root``.

    trim: keep only the effective gesture listed in ``informations_troncage_sequences.txt``
    (required then; a sequence missing from it is an error).
    """
    classes(n_classes)
    files = dhg_files(root)
    info = load_info(root, trim)
    for path, key in files:
        yield read_listed(path, key, info, fps=fps, hand=hand, mirror=mirror), key.label(n_classes), key
