"""The synth_fit job's splits: capped, stratified, and shifts the data cannot form are skipped."""

from __future__ import annotations

import numpy as np

from handradar.synthesis.job import synth_splits


def _meta(n: int, subjects: list[str]) -> dict[str, np.ndarray]:
    i = np.arange(n)
    return {"hands": np.where(i % 2, 2, 1), "occlusion": i % 3 == 0, "angle_deg": np.asarray([0, 30, -30])[i % 3],
            "subject": np.asarray(subjects)[i % len(subjects)]}


def test_every_shift_with_enough_subjects():
    labels = np.arange(60) % 5
    splits = synth_splits(labels, _meta(60, ["s1", "s2", "s3", "s4"]), 0, test_fraction=0.2, max_train_rows=20,
                          max_test_rows=10)
    assert set(splits) == {"", "_hands", "_occlusion", "_angle", "_subject"}
    for train, test in splits.values():
        assert len(train) <= 20 and len(test) <= 10 and not np.intersect1d(train, test).size


def test_a_shift_the_data_cannot_form_is_skipped_not_fatal(caplog):
    """Recordings of one subject (a user's first session): no unseen-subject split, the rest go on."""
    labels = np.arange(12) % 3
    splits = synth_splits(labels, _meta(12, ["s01"]), 0, test_fraction=0.25, max_train_rows=8, max_test_rows=4)
    assert "_subject" not in splits and {"", "_hands", "_angle"} <= set(splits)
    assert "skipping the subject generalisation" in caplog.text
