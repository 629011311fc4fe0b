"""DHG-14/28 and SHREC'17 importer on fixture files written in the dataset's format."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from handradar.errors import FormatError
from handradar.hand.importers.dhg import (
    GESTURES_14,
    GESTURES_28,
    iter_dhg,
    read_dhg,
    read_info,
)
from handradar.hand.placement import flexion_score
from tests.hand.template import moving_hand, rotation

FPS = 30.0


def dhg_rows(joints: np.ndarray) -> np.ndarray:
    """(T, 21, 3) canonical -> (T, 66) DHG rows: wrist, palm, then thumb base..pinky tip."""
    palm = joints[:, [0, 5, 9, 13, 17]].mean(axis=1, keepdims=True)
    return np.concatenate([joints[:, :1], palm, joints[:, 1:]], axis=1).reshape(len(joints), 66)


def write_sequence(root: Path, g: int, f: int, s: int, e: int, joints: np.ndarray,
                   name: str = "skeleton_world.txt") -> Path:
    folder = root / f"gesture_{g}" / f"finger_{f}" / f"subject_{s}" / f"essai_{e}"
    folder.mkdir(parents=True)
    path = folder / name
    path.write_text("".join(" ".join(f"{v:.6f}" for v in row) + "\n" for row in dhg_rows(joints)))
    return path


# camera frame: the camera looks along +z; the hand, 0.4 m away, faces it (palm normal -z) with its
# fingers up (+y), moving along +x at 0.3 m/s
CAMERA_POSE = dict(start=[0.05, -0.02, 0.40], velocity=[0.3, 0.0, 0.0])


@pytest.fixture()
def dhg_root(tmp_path) -> Path:
    root = tmp_path / "DHG2016"
    write_sequence(root, 1, 1, 1, 1, moving_hand(40, 1 / FPS, rot=rotation("y", 180), **CAMERA_POSE))
    write_sequence(root, 3, 2, 2, 4, moving_hand(40, 1 / FPS, rot=rotation("z", 20)))
    write_sequence(root, 14, 2, 3, 1, moving_hand(12, 1 / FPS), name="skeletons_world.txt")  # SHREC'17 name
    (root / "informations_troncage_sequences.txt").write_text("1 1 1 1 5 30\n3 2 2 4 1 40\n14 2 3 1 2 10\n")
    return root


def test_mapping_drops_palm_and_keeps_joint_order(dhg_root):
    joints = moving_hand(40, 1 / FPS, rot=rotation("y", 180), **CAMERA_POSE)
    seq = read_dhg(dhg_root / "gesture_1/finger_1/subject_1/essai_1/skeleton_world.txt")
    assert seq.n_steps == 40 and seq.mask[:, 0].all() and not seq.mask[:, 1].any()
    np.testing.assert_allclose(seq.positions[:, 0], joints, atol=1e-6)  # thumb base -> CMC, ..., pinky tip
    np.testing.assert_allclose(seq.times, np.arange(40) / 30)
    assert seq.attrs["up_axis"] == "y"
    assert flexion_score(seq) > 0  # a right hand in a right-handed frame
    mirrored = read_dhg(dhg_root / "gesture_1/finger_1/subject_1/essai_1/skeleton_world.txt", mirror=True)
    np.testing.assert_allclose(mirrored.positions[:, 0, :, 0], -joints[..., 0], atol=1e-6)
    assert flexion_score(mirrored) < 0


def test_trim_is_one_based_inclusive(dhg_root):
    joints = moving_hand(40, 1 / FPS, rot=rotation("y", 180), **CAMERA_POSE)
    items = list(iter_dhg(dhg_root))
    seq, label, key = items[0]
    assert key.name == "gesture_1/finger_1/subject_1/essai_1" and label == 0
    assert seq.n_steps == 26  # frames 5..30
    np.testing.assert_allclose(seq.positions[0, 0], joints[4], atol=1e-6)
    np.testing.assert_allclose(seq.positions[-1, 0], joints[29], atol=1e-6)
    assert seq.times[0] == 0.0 and seq.attrs["first_frame"] == 5


def test_labels_14_and_28(dhg_root):
    l14 = [(label, key.name) for _, label, key in iter_dhg(dhg_root, n_classes=14)]
    l28 = [label for _, label, _ in iter_dhg(dhg_root, n_classes=28)]
    assert [x for x, _ in l14] == [0, 2, 13]
    assert l28 == [0, 5, 27]  # 2 (g - 1) + (f - 1)
    assert GESTURES_14[2] == "expand" and GESTURES_28[5] == "expand_whole_hand"
    assert GESTURES_28[27] == "shake_whole_hand" and len(GESTURES_28) == 28
    assert l14[2][1] == "gesture_14/finger_2/subject_3/essai_1"  # SHREC'17's skeletons_world.txt found
    with pytest.raises(ValueError, match="14 or 28"):
        next(iter_dhg(dhg_root, n_classes=10))


def test_untrimmed_without_info_file(dhg_root):
    (dhg_root / "informations_troncage_sequences.txt").unlink()
    with pytest.raises(FormatError, match="pass trim=false"):
        next(iter_dhg(dhg_root))
    assert [s.n_steps for s, _, _ in iter_dhg(dhg_root, trim=False)] == [40, 40, 12]


def _bad_file(dhg_root: Path, text: str, *fragments: str):
    path = dhg_root / "gesture_3/finger_2/subject_2/essai_4/skeleton_world.txt"
    path.write_text(text)
    with pytest.raises(FormatError) as info:
        list(iter_dhg(dhg_root))
    msg = str(info.value)
    assert msg.startswith(str(path)), msg
    for frag in fragments:
        assert frag in msg, msg


def test_missing_and_nan_joints(dhg_root):
    rows = dhg_rows(moving_hand(40, 1 / FPS))
    lines = [" ".join(f"{v:.5f}" for v in r) for r in rows]
    short = lines.copy()
    short[7] = " ".join(short[7].split()[:63])  # joint 22 missing
    _bad_file(dhg_root, "\n".join(short), ":8: expected 66 values (22 joints x 3) per line, found 63")
    nan = lines.copy()
    nan[3] = nan[3].replace(nan[3].split()[10], "nan", 1)
    _bad_file(dhg_root, "\n".join(nan), ":4:", "NaN or infinite")
    word = lines.copy()
    word[0] = "x " + " ".join(word[0].split()[1:])
    _bad_file(dhg_root, "\n".join(word), "expected a number, found 'x' (value 1 of 66)")
    _bad_file(dhg_root, "\n".join(lines[:30]), "frames 1..40 requested", "the file has 30 frames")


def test_bad_info_file(dhg_root, tmp_path):
    info = dhg_root / "informations_troncage_sequences.txt"
    info.write_text("1 1 1 1 5 30\n3 2 2 4 1 40\n")  # no entry for gesture 14
    with pytest.raises(FormatError, match="lists no start/end frames for gesture_14/finger_2/subject_3/essai_1"):
        list(iter_dhg(dhg_root))
    info.write_text("1 1 1 1 5\n")
    with pytest.raises(FormatError, match="expected 6 integers"):
        read_info(info)
    info.write_text("1 1 1 1 30 5\n")
    with pytest.raises(FormatError, match="1 <= start < end"):
        read_info(info)
    info.write_text("1 1 1 1 5.5 30\n")
    with pytest.raises(FormatError, match="expected integers"):
        read_info(info)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FormatError, match="no DHG sequences"):
        list(iter_dhg(empty))
