"""The one vocabulary: the simulator's effect registry, the world's effect switches and the gesture
classes of every reader are the tuples of handradar.vocab."""

from __future__ import annotations

import dataclasses

from handradar import vocab
from handradar.sim.effects import REGISTRY
from handradar.world.config import EFFECTS as WORLD_SWITCHES
from handradar.world.config import Effects
from handradar.world.kinematics import GESTURE_TABLE


def test_simulator_registry_is_the_effect_vocabulary():
    assert set(REGISTRY) == set(vocab.EFFECTS)


def test_world_switches_every_effect_of_the_vocabulary_and_its_own():
    assert WORLD_SWITCHES == vocab.EFFECTS + vocab.WORLD_ONLY_EFFECTS
    assert {f.name for f in dataclasses.fields(Effects)} == set(WORLD_SWITCHES)
    assert not set(vocab.EFFECTS) & set(vocab.WORLD_ONLY_EFFECTS)


def test_world_kinematics_drive_every_gesture_class():
    assert tuple(GESTURE_TABLE) == vocab.GESTURES
