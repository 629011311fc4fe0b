"""SFINGE3D: every real Dictionary instance imports; anatomy and frame convention hold; bad files."""

from __future__ import annotations

import numpy as np
import pytest

from handradar.errors import FormatError
from handradar.hand.importers.sfinge3d import (
    CLASSES,
    iter_sfinge3d,
    read_sfinge3d,
    sfinge3d_files,
)
from handradar.hand.placement import flexion_score
from handradar.hand.skeleton import BONE_NAMES


@pytest.fixture(scope="module")
def dictionary(sfinge3d_dir):
    return sfinge3d_dir


@pytest.fixture(scope="module")
def imported(dictionary):
    return list(iter_sfinge3d(dictionary))


def test_all_468_instances_import(imported, dictionary):
    assert len(imported) == 468 == len(sfinge3d_files(dictionary / "Dictionary"))
    labels = np.array([label for _, label, _ in imported])
    assert np.bincount(labels).tolist() == [36] * len(CLASSES)
    for seq, label, name in imported:
        assert name.split("/")[0] == str(label + 1)
        assert seq.mask[:, 0].all() and not seq.mask[:, 1].any()  # a right hand, always tracked
        assert seq.n_steps >= 24
        np.testing.assert_allclose(np.diff(seq.times), 1 / 20)
        assert np.isfinite(seq.positions).all()


def test_bone_lengths_are_anatomical(imported):
    """Phalanges 1-5 cm and the thumb metacarpal 3.5-5 cm; wrist-to-MCP 7-11 cm.

    Wrist-to-MCP spans the carpus and the metacarpal, so it exceeds the 10 cm a phalanx check would
    use: 5 of 20 732 frames reach 10.0-10.6 cm (instances 1/23, 1/32, 3/10, hand tracked ~13 % larger).
    """
    lengths = np.concatenate([s.bone_lengths()[:, 0] for s, _, _ in imported])  # (frames, 19)
    assert lengths.shape == (20732, 19)
    wrist_mcp = np.array(["metacarpal" in n and not n.startswith("thumb") for n in BONE_NAMES])
    assert lengths.min() >= 0.01
    assert lengths[:, ~wrist_mcp].max() <= 0.05
    assert 0.035 <= lengths[:, 0].min() and lengths[:, 0].max() <= 0.05  # derived thumb metacarpal
    assert 0.07 <= lengths[:, wrist_mcp].min() and lengths[:, wrist_mcp].max() <= 0.11
    assert (lengths[:, wrist_mcp] > 0.10).sum() == 5
    # finger bones are rigid within an instance: a tracked skeleton, not noise
    for seq, _, _ in imported[:50]:
        bl = seq.bone_lengths()[:, 0]
        assert (bl.std(axis=0) / bl.mean(axis=0)).max() < 0.1


def test_frame_convention_gives_a_right_hand(imported, dictionary):
    """Mirroring z makes the hand a right hand in a right-handed frame: fingers flex toward its palm."""
    scores = np.array([flexion_score(s) for s, _, _ in imported])
    assert (scores > 0).mean() > 0.95 and np.median(scores) > 0.3
    raw = read_sfinge3d(dictionary / "Dictionary" / "1" / "1.txt", mirror=False)
    assert flexion_score(raw) < 0  # unmirrored, the right hand looks left


def test_thumb_and_wrist_derivation(dictionary):
    path = dictionary / "Dictionary" / "7" / "3.txt"
    rows = np.array([[float(v) for v in line.rstrip(";\n").split(";")] for line in path.open()])
    raw = rows.reshape(-1, 20, 7)
    seq = read_sfinge3d(path)
    j = seq.positions[:, 0].astype(np.float64) * [1, 1, -1]  # undo the z mirror
    np.testing.assert_allclose(j[:, 0], raw[:, 0, :3], atol=1e-6)  # wrist = palm joint (offset 0)
    np.testing.assert_allclose(j[:, 2:5], raw[:, 1:4, :3], atol=1e-6)  # thumb A/B/end = MCP/IP/tip
    np.testing.assert_allclose(j[:, 5:21], raw[:, 4:20, :3], atol=1e-6)
    # CMC on the MCP -> wrist line, 1.45 proximal phalanges from the MCP
    meta = np.linalg.norm(j[:, 1] - j[:, 2], axis=-1)
    np.testing.assert_allclose(meta, 1.45 * np.linalg.norm(j[:, 3] - j[:, 2], axis=-1), rtol=1e-5)
    cross = np.cross(j[:, 1] - j[:, 2], j[:, 0] - j[:, 2])
    assert np.abs(cross).max() < 1e-6
    shifted = read_sfinge3d(path, wrist_offset_m=0.02)
    moved = np.linalg.norm(shifted.positions[:, 0, 0] - seq.positions[:, 0, 0], axis=-1)
    np.testing.assert_allclose(moved, 0.02, atol=1e-6)
    # moved backwards: away from the fingers
    assert (np.linalg.norm(shifted.positions[:, 0, 9] - shifted.positions[:, 0, 0], axis=-1)
            > np.linalg.norm(seq.positions[:, 0, 9] - seq.positions[:, 0, 0], axis=-1)).all()


GOOD_ROW = ";".join(["0.1;2.3;0.3;0;0;0;1"] * 20) + ";"


@pytest.mark.parametrize(("text", "fragment"), [
    (GOOD_ROW + "\n" + GOOD_ROW.replace("2.3", "abc", 1) + "\n", "expected a number, found 'abc'"),
    (GOOD_ROW + "\n" + ";".join(["0.1;2.3;0.3;0;0;0;1"] * 19) + ";\n", "expected 140 values"),
    (GOOD_ROW + "\n" + GOOD_ROW.replace("2.3", "nan", 1) + "\n", "NaN or infinite"),
    (GOOD_ROW + "\n" + GOOD_ROW.replace(";0;0;0;1;", ";0;0;0;2;", 1) + "\n", "not a unit quaternion"),
    (GOOD_ROW + "\n", "at least 2 frames"),
    ("\n\n", "no data"),
])
def test_bad_files(tmp_path, text, fragment):
    path = tmp_path / "5.txt"
    path.write_text(text)
    with pytest.raises(FormatError) as info:
        read_sfinge3d(path)
    assert str(info.value).startswith(str(path)) and fragment in str(info.value)


def test_not_a_sfinge3d_folder(tmp_path):
    with pytest.raises(FormatError, match="not a SFINGE3D folder"):
        list(iter_sfinge3d(tmp_path))
