"""Gesture kinematics: rigid per-subject skeletons, realistic speeds, hands inside the range gate,
the gesture inside the spectrogram window, and the per-subject variation."""

from __future__ import annotations

import numpy as np
import pytest

from handradar.hand.skeleton import BONE_CHILD, BONE_PARENT
from handradar.vocab import GESTURES
from handradar.world.generate import subject
from handradar.world.kinematics import GESTURE_TABLE, Motion, Subject


@pytest.mark.parametrize("gesture", GESTURES)
def test_gesture_kinematics_are_plausible(world, chain, gesture):
    kin = world.kinematics
    capture_s = 2.4
    t = np.arange(0.0, capture_s, 0.002)
    fastest = 0.0
    for k, angle in enumerate((0.0, 30.0, -30.0)):
        subj = subject(world, k)
        motion = Motion(gesture, subj, angle, capture_s, kin, np.random.default_rng(k))
        pose = motion.pose(t)
        hands, _ = GESTURE_TABLE[gesture]
        assert pose.present.sum() == hands
        j = pose.joints[:, pose.present]  # (T, hands, 21, 3)
        # rigid bones of this subject's skeleton
        lengths = np.linalg.norm(j[:, :, BONE_CHILD] - j[:, :, BONE_PARENT], axis=-1)
        assert lengths.std(axis=0).max() < 1e-9
        # inside the chain's range gate, above the radar
        r = np.linalg.norm(j, axis=-1)
        assert chain.gate_m[0] < r.min() and r.max() < chain.gate_m[1]
        assert (j[..., 2] > 0.1).all()
        # realistic speeds: fingertips under ~1.5 m/s, and the gesture does move
        v = np.linalg.norm(np.diff(j, axis=0), axis=-1) / 0.002
        fastest = max(fastest, v.max())
        assert v.max() < 1.6
        # the motion happens inside [start, start + duration] (tremor and drift aside)
        inside = (t[1:] >= motion.start_s) & (t[1:] <= motion.start_s + motion.duration_s)
        energy = (v ** 2).sum(axis=(1, 2))
        assert energy[inside].sum() > 0.9 * energy.sum()
        assert 0.9 < motion.duration_s < 1.75
        # the hand is seen off boresight at the set angle
        palms = pose.palm_centres()[:, pose.present].reshape(-1, 3)
        centre = (palms.max(0) + palms.min(0)) / 2  # middle of the space the gesture sweeps
        assert np.degrees(np.arctan2(centre[0], centre[2])) == pytest.approx(angle, abs=8.0)
    assert fastest > 0.2


def test_subjects_vary_in_size_speed_and_handedness(world):
    subjects = [subject(world, i) for i in range(40)]
    scales = np.array([s.geometry.scale for s in subjects])
    assert 0.85 <= scales.min() and scales.max() <= 1.15 and scales.std() > 0.05
    assert len({s.speed for s in subjects}) == 40 and 0.8 <= min(s.speed for s in subjects)
    assert 0 < sum(s.left_handed for s in subjects) < 20
    # repetitions differ a little, subjects more
    a = Motion("circle", subjects[0], 0.0, 2.4, world.kinematics, np.random.default_rng(1))
    b = Motion("circle", subjects[0], 0.0, 2.4, world.kinematics, np.random.default_rng(2))
    assert a.duration_s != b.duration_s and abs(a.duration_s / b.duration_s - 1) < 0.2
    # a left-handed subject gestures with the left hand (slot 1), mirrored
    lefty = next(s for s in subjects if s.left_handed)
    m = Motion("slide", lefty, 0.0, 2.4, world.kinematics, np.random.default_rng(0))
    pose = m.pose(np.array([1.0]))
    assert pose.present.tolist() == [False, True]
    thumb, pinky = pose.joints[0, 1, 4], pose.joints[0, 1, 20]
    assert thumb[0] > pinky[0]  # left hand palm down: the thumb is on the right (+x)


def test_scaled_skeleton(world):
    rng = np.random.default_rng(0)
    small = Subject.sample(0, rng, world.kinematics, 0.0085)
    pose = Motion("grasp", small, 0.0, 2.0, world.kinematics, rng).pose(np.array([0.0]))
    hand = pose.joints[0, pose.present][0]
    length = np.linalg.norm(hand[12] - hand[0])  # wrist to middle fingertip
    assert length == pytest.approx(0.185 * small.geometry.scale, rel=0.12)
