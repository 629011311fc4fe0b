"""Placement of external skeletons over the radar; the MediaPipe adapter."""

from __future__ import annotations

import numpy as np
import pytest

from handradar.errors import FormatError
from handradar.hand.importers.common import single_hand_sequence
from handradar.hand.importers.mediapipe import mediapipe_sequence
from handradar.hand.placement import (
    axis_vector,
    flexion_score,
    hand_centre,
    hand_direction,
    palm_normal,
    place_in_radar,
)
from handradar.hand.skeleton import HandSequence
from tests.hand.template import TEMPLATE_RIGHT, moving_hand, rotation

DT = 1 / 30


def _seq(joints: np.ndarray, hand: str = "right") -> HandSequence:
    return single_hand_sequence(joints, np.arange(len(joints)) * DT, hand=hand, source="test")


def _mean_normal(seq: HandSequence, slot: int = 0, hand: str = "right") -> np.ndarray:
    n = palm_normal(seq.positions[seq.mask[:, slot], slot].astype(np.float64), hand).mean(axis=0)
    return n / np.linalg.norm(n)


def test_template_geometry():
    """The test hand itself: palm normal +z, fingers +y; a right hand whose fingers flex to its palm."""
    np.testing.assert_allclose(palm_normal(TEMPLATE_RIGHT, "right"), [0, 0, 1], atol=1e-12)
    assert hand_direction(TEMPLATE_RIGHT) @ [0, 1, 0] > 0.99
    assert flexion_score(_seq(moving_hand(3, DT))) > 0
    assert flexion_score(_seq(moving_hand(3, DT) * [-1, 1, 1], hand="left")) > 0  # mirror image = left hand


def test_camera_facing_hand_needs_no_rotation():
    """A camera looking along +z at a palm facing it is the radar looking at the palm: identity."""
    joints = moving_hand(20, DT, rot=rotation("y", 180), start=[0.05, -0.02, 0.40], velocity=[0.3, 0, 0])
    placed = place_in_radar(_seq(joints), up_axis="y")
    np.testing.assert_allclose(placed.attrs["placement"]["rotation"], np.eye(3), atol=1e-9)
    np.testing.assert_allclose(hand_centre(placed.positions[:, 0]).mean(0), [0, 0, 0.30], atol=1e-6)
    np.testing.assert_allclose(np.diff(placed.positions[:, 0, 0], axis=0) / DT, [[0.3, 0, 0]] * 19, atol=1e-4)


@pytest.mark.parametrize("angles", [(30, 40, 0), (-70, 10, 125), (0, 95, -60), (160, -20, 45)])
def test_palm_faces_radar_and_up_becomes_forward(angles):
    rot = rotation("x", angles[0]) @ rotation("y", angles[1]) @ rotation("z", angles[2])
    velocity = np.array([0.2, -0.1, 0.15])
    seq = _seq(moving_hand(30, DT, rot=rot, start=[1.0, 2.0, -0.5], velocity=velocity))
    placed = place_in_radar(seq, up_axis="y", centre_m=(0.02, -0.03, 0.35))
    r = np.array(placed.attrs["placement"]["rotation"])
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)  # a rotation: a right hand stays a right hand
    np.testing.assert_allclose(_mean_normal(placed), [0, 0, -1], atol=1e-5)  # palm toward the radar
    np.testing.assert_allclose(hand_centre(placed.positions[:, 0]).mean(0), [0.02, -0.03, 0.35], atol=1e-6)
    np.testing.assert_allclose(placed.bone_lengths(), seq.bone_lengths(), atol=1e-6)
    if placed.attrs["placement"]["heading"] == "up":
        up = r @ [0, 1, 0]  # the source's up lies in the radar's y-z plane, pointing forward (+y)
        assert abs(up[0]) < 1e-9 and up[1] > 0
    v = np.diff(placed.positions[:, 0, 0], axis=0) / DT
    np.testing.assert_allclose(np.linalg.norm(v, axis=-1), np.linalg.norm(velocity), rtol=1e-3)
    assert flexion_score(placed) == pytest.approx(flexion_score(seq), abs=1e-5)


def test_palm_down_source_takes_heading_from_hand_direction():
    """A hand already palm-down in a y-up frame (like Leap): up is parallel to the palm normal."""
    seq = _seq(moving_hand(10, DT, rot=rotation("x", 90)))  # palm +z -> -y (down), fingers +y -> +z
    placed = place_in_radar(seq, up_axis="y")
    assert placed.attrs["placement"]["heading"] == "hand"
    np.testing.assert_allclose(_mean_normal(placed), [0, 0, -1], atol=1e-6)
    d = hand_direction(placed.positions[:, 0].astype(np.float64)).mean(0)
    assert d[1] > 0.99  # fingers forward
    turned = place_in_radar(seq, up_axis="y", yaw_deg=90)
    d = hand_direction(turned.positions[:, 0].astype(np.float64)).mean(0)
    assert d[0] < -0.99  # +y turned by +90 deg about boresight is -x


def test_two_hands_face_the_radar():
    right = moving_hand(10, DT, start=[0.1, 0, 0])
    left = moving_hand(10, DT, start=[-0.1, 0, 0]) * [-1, 1, 1]
    pos = np.stack([right, left], axis=1).astype(np.float32)
    seq = HandSequence(pos, np.arange(10) * DT, np.ones((10, 2), bool))
    placed = place_in_radar(seq, up_axis="y")
    np.testing.assert_allclose(_mean_normal(placed, 0, "right"), [0, 0, -1], atol=1e-5)
    np.testing.assert_allclose(_mean_normal(placed, 1, "left"), [0, 0, -1], atol=1e-5)


def test_bad_arguments():
    seq = _seq(moving_hand(4, DT))
    with pytest.raises(ValueError, match="axis must be"):
        place_in_radar(seq, up_axis="w")
    with pytest.raises(ValueError, match="centre_m"):
        place_in_radar(seq, centre_m=(0, 0))
    np.testing.assert_allclose(axis_vector("-y"), [0, -1, 0])
    np.testing.assert_allclose(axis_vector([0, 0, 2]), [0, 0, 1])


def test_mediapipe_world_landmarks():
    """MediaPipe axes: x right, y down, z away from the camera; a palm facing the camera, fingers up."""
    # camera frame of the DHG test (looks along +z, y up, so x is the camera's left) -> MediaPipe's:
    # x and y flip (a rotation by 180 deg about z, which keeps a right hand right)
    to_mp = np.diag([-1.0, -1.0, 1.0])
    lm = moving_hand(12, DT, rot=to_mp @ rotation("y", 180))  # palm toward the camera (-z), fingers up (-y)
    seq = mediapipe_sequence(lm, np.arange(12) * DT)
    assert seq.mask[:, 0].all() and not seq.mask[:, 1].any() and seq.attrs["up_axis"] == "-y"
    np.testing.assert_allclose(seq.positions[:, 0], lm, atol=1e-7)
    placed = place_in_radar(seq, up_axis=seq.attrs["up_axis"])
    np.testing.assert_allclose(_mean_normal(placed), [0, 0, -1], atol=1e-5)
    assert hand_direction(placed.positions[:, 0].astype(np.float64)).mean(0)[1] > 0.99  # fingers (up) forward
    both = mediapipe_sequence(np.stack([lm, lm * [-1, 1, 1]], axis=1), np.arange(12) * DT, hands=("right", "left"),
                              mask=np.tile([True, False], (12, 1)))
    assert both.mask[:, 0].all() and not both.mask[:, 1].any() and not both.positions[:, 1].any()
    with pytest.raises(FormatError, match=r"expected landmarks \(T, 21, 3\)"):
        mediapipe_sequence(lm[:, :20], np.arange(12) * DT)
    with pytest.raises(FormatError, match="distinct"):
        mediapipe_sequence(np.stack([lm, lm], axis=1), np.arange(12) * DT, hands=("right", "right"))
