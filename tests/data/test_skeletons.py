"""The skeleton-source registry used by handradar-synth: sfinge3d, dhg, leap."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from handradar.data.skeletons import SOURCES, iter_source, source_classes
from handradar.errors import FormatError
from handradar.hand.importers.dhg import GESTURES_28
from handradar.hand.importers.sfinge3d import CLASSES as SFINGE_CLASSES
from handradar.hand.placement import hand_centre, palm_normal
from handradar.vocab import GESTURES
from tests.data.writer import Scene, write_recording
from tests.hand.template import moving_hand, rotation
from tests.hand.test_dhg import write_sequence


def _check_radar_frame(item, centre=(0.0, 0.0, 0.30)):
    seq = item.sequence
    j = seq.positions[:, 0].astype(np.float64)
    np.testing.assert_allclose(hand_centre(j).mean(0), centre, atol=1e-5)
    n = palm_normal(j, "right").mean(0)
    assert n[2] / np.linalg.norm(n) == pytest.approx(-1.0, abs=1e-5)  # palm toward the radar
    assert seq.attrs["frame"] == "radar"


def test_registry_names():
    assert set(SOURCES) == {"sfinge3d", "dhg", "leap", "motions"}
    assert source_classes("motions", classes={"b": ["tap"], "a": ["push"]}) == ("b", "a")  # the mapping's order
    assert source_classes("sfinge3d") == SFINGE_CLASSES and len(SFINGE_CLASSES) == 13
    assert source_classes("dhg", n_classes=28) == GESTURES_28
    assert source_classes("leap") == GESTURES
    with pytest.raises(ValueError, match="unknown skeleton source"):
        iter_source("kinect", ".")


@pytest.mark.parametrize("name, hint", [("sfinge3d", "`make fetch-data`"),
                                        ("dhg", "`handradar-fetch dataset=dhg fetch.url=URL out=")])
def test_missing_dataset_folder_says_how_to_get_it(tmp_path, name, hint):
    root = tmp_path / "data" / name
    with pytest.raises(FormatError) as info:
        next(iter_source(name, root))
    msg = str(info.value)
    assert msg.startswith(f"{root}: no such folder: the {name} skeletons are read from here") and "\n" not in msg
    assert hint in msg and "source.root=DIR" in msg and f"data.{name}.root=DIR" in msg


def test_sfinge3d_items(sfinge3d_dir):
    root = sfinge3d_dir
    items = list(iter_source("sfinge3d", root))
    assert len(items) == 468 and len({it.name for it in items}) == 468
    assert [it.label for it in items[::36]] == list(range(13))
    for it in items:
        _check_radar_frame(it)
        assert it.classes == SFINGE_CLASSES and it.meta["gesture"] == SFINGE_CLASSES[it.label]
        assert it.meta["recording"] == it.name and it.meta["hands"] == 1
    # swipes travel up to ~47 cm, yet centred 0.30 m up every joint stays above the board (min 3.8 cm)
    assert min(float(it.sequence.positions[:, 0, :, 2].min()) for it in items) > 0.03
    for it in itertools.islice(iter_source("sfinge3d", root, centre_m=(0.0, 0.05, 0.25), yaw_deg=30), 5):
        _check_radar_frame(it, (0.0, 0.05, 0.25))


def test_dhg_items(tmp_path):
    root = tmp_path / "dhg"
    write_sequence(root, 2, 1, 7, 3, moving_hand(40, 1 / 30, rot=rotation("y", 180), velocity=[0.3, 0, 0]))
    write_sequence(root, 9, 2, 7, 1, moving_hand(40, 1 / 30, rot=rotation("y", 150)))
    (root / "informations_troncage_sequences.txt").write_text("2 1 7 3 3 35\n9 2 7 1 1 40\n")
    items = list(iter_source("dhg", root, n_classes=28))
    assert [it.label for it in items] == [2, 17]
    assert items[0].meta == {"gesture": "tap_one_finger", "subject": "s07", "hands": 1, "repetition": 3,
                             "fingers": 1, "recording": "gesture_2/finger_1/subject_7/essai_3"}
    assert items[0].sequence.n_steps == 33
    for it in items:
        _check_radar_frame(it)
    # the +x motion in front of the camera keeps its speed over the radar
    v = np.diff(items[0].sequence.positions[:, 0, 0], axis=0) * 30
    np.testing.assert_allclose(np.linalg.norm(v, axis=-1), 0.3, rtol=1e-3)


def test_leap_items_read_only_leap_and_meta(tmp_path):
    write_recording(tmp_path / "a" / "rec1", Scene(gesture="circle", subject="s02", repetition=4))
    write_recording(tmp_path / "b" / "rec1", Scene(gesture="slide"))
    (tmp_path / "a" / "rec1" / "adc_data.bin").write_bytes(b"not read")  # only leap.jsonl + meta.json
    (tmp_path / "a" / "rec1" / "radar.cfg").write_text("garbage")
    items = list(iter_source("leap", tmp_path))
    assert [it.name for it in items] == ["a/rec1", "b/rec1"]
    assert [it.label for it in items] == [GESTURES.index("circle"), GESTURES.index("slide")]
    assert items[0].meta["subject"] == "s02" and items[0].meta["repetition"] == 4
    assert items[0].meta["recording"] == "a/rec1" and items[0].classes == GESTURES
    scene = Scene()
    t = items[0].sequence.times
    np.testing.assert_allclose(items[0].sequence.positions[:, 0], scene.joints(t), atol=2e-6)


def test_bad_items_raise_or_are_collected(tmp_path):
    write_recording(tmp_path / "good", Scene())
    bad = write_recording(tmp_path / "bad", Scene())
    meta = json.loads((bad / "meta.json").read_text())
    del meta["subject"]
    (bad / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(FormatError, match="missing required field 'subject'"):
        list(iter_source("leap", tmp_path))
    errors: list = []
    items = list(iter_source("leap", tmp_path, errors=errors))
    assert [it.name for it in items] == ["good"]
    assert errors[0][0] == "bad" and "missing required field 'subject'" in errors[0][1]
