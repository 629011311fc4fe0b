"""Splits: stratified by class, disjoint, reproducible; OOD splits separate the right rows."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from handradar.data.splits import (
    Split,
    default_train_values,
    few_shot_split,
    make_split,
    ood_split,
    stratified_sample,
)

N_CLASSES, PER_CLASS = 10, 24


@pytest.fixture(scope="module")
def labels() -> np.ndarray:
    return np.random.default_rng(3).permutation(np.repeat(np.arange(N_CLASSES), PER_CLASS))


@pytest.fixture(scope="module")
def meta(labels: np.ndarray) -> dict[str, np.ndarray]:
    i = np.arange(len(labels))
    return {"angle_deg": np.array([0, 30, -30])[i % 3].astype(float),
            "subject": np.array([f"s{k:02d}" for k in i % 8]),
            "hands": np.where(labels < 6, 1, 2),
            "occlusion": (i // 3) % 2 == 1}


def _check_partition(split: Split, n: int) -> None:
    assert np.intersect1d(split.pool, split.test).size == 0
    assert np.isin(split.train, split.pool).all()
    assert len(np.unique(split.train)) == len(split.train)
    every = np.concatenate([split.pool, split.test])
    assert every.min() >= 0 and every.max() < n


@pytest.mark.parametrize("fraction,expected", [(0.05, 1), (0.2, 5), (0.5, 12), (0.75, 18)])
def test_few_shot_stratified_counts(labels, fraction, expected):
    split = few_shot_split(labels, fraction, seed=1)
    counts = np.bincount(labels[split.train], minlength=N_CLASSES)
    assert (counts == expected).all()  # max(1, round(f * 24)) per class
    _check_partition(split, len(labels))
    # remainder protocol: everything not drawn is tested on; the pool is the drawn rows
    assert np.array_equal(np.sort(np.concatenate([split.train, split.test])), np.arange(len(labels)))
    assert np.array_equal(split.pool, split.train)


def test_few_shot_reproducible_and_seeded(labels):
    a, b = few_shot_split(labels, 0.2, seed=7), few_shot_split(labels, 0.2, seed=7)
    c = few_shot_split(labels, 0.2, seed=8)
    assert np.array_equal(a.train, b.train) and np.array_equal(a.test, b.test)
    assert not np.array_equal(a.train, c.train)


def test_few_shot_fractions_nested(labels):
    small, mid, big = (few_shot_split(labels, f, seed=2).train for f in (0.05, 0.2, 0.5))
    assert np.isin(small, mid).all() and np.isin(mid, big).all()


def test_fixed_protocol_same_test_for_every_seed_and_fraction(labels):
    splits = [few_shot_split(labels, f, seed=s, test="fixed", test_fraction=0.25) for f in (0.05, 0.5) for s in (1, 2)]
    for s in splits:
        _check_partition(s, len(labels))
        assert np.array_equal(s.test, splits[0].test)
        assert (np.bincount(labels[s.test], minlength=N_CLASSES) == 6).all()
        # the pool is every non-test row: skeletons of unused radar rows are still available
        assert np.array_equal(np.sort(np.concatenate([s.pool, s.test])), np.arange(len(labels)))
    # the fraction is of the complete dataset's class size, drawn from the pool
    assert (np.bincount(labels[splits[2].train], minlength=N_CLASSES) == 12).all()
    assert not np.array_equal(splits[0].train, splits[1].train)  # training rows follow the seed


@pytest.mark.parametrize("kind,field", [("angle", "angle_deg"), ("hands", "hands"), ("occlusion", "occlusion"),
                                        ("subject", "subject")])
def test_ood_splits_separate_the_field(labels, meta, kind, field):
    split = make_split({"kind": "ood", "ood": kind, "fraction": 1.0, "test_fraction": 0.5}, labels, meta, seed=4)
    _check_partition(split, len(labels))
    train_vals, test_vals = set(meta[field][split.train].tolist()), set(meta[field][split.test].tolist())
    assert not train_vals & test_vals
    if kind == "angle":
        assert train_vals == {0.0} and test_vals == {30.0, -30.0}
    if kind == "hands":
        assert train_vals == {1} and test_vals == {2}
        assert set(labels[split.train].tolist()) == set(range(6))  # single-hand gestures only
    if kind == "occlusion":
        assert train_vals == {False} and test_vals == {True}
    if kind == "subject":
        assert len(test_vals) == 2  # ceil(0.25 * 8) unseen subjects
    # every in-distribution row trains (fraction 1); half of each OOD class is tested, the other
    # half stays in the pool for its skeletons
    inside = np.flatnonzero(np.isin(meta[field], list(train_vals)))
    assert np.array_equal(split.train, inside)
    ood_rows = np.setdiff1d(np.arange(len(labels)), inside)
    assert np.array_equal(np.sort(np.concatenate([split.test, np.setdiff1d(split.pool, inside)])), ood_rows)
    for c in np.unique(labels[ood_rows]):
        n_c = np.count_nonzero(labels[ood_rows] == c)
        assert np.count_nonzero(labels[split.test] == c) == max(1, round(0.5 * n_c))


def test_subject_split_follows_seed(labels, meta):
    held = {tuple(sorted(set(meta["subject"].tolist()) - set(default_train_values("subject", meta["subject"], s))))
            for s in range(6)}
    assert len(held) > 1


def test_ood_fraction_subsamples_in_distribution(labels, meta):
    split = make_split({"kind": "ood", "ood": "angle", "fraction": 0.25, "test_fraction": 0.5}, labels, meta, seed=1)
    inside = meta["angle_deg"] == 0
    for c in range(N_CLASSES):
        assert np.count_nonzero(labels[split.train] == c) == max(1, round(0.25 * np.count_nonzero(inside & (labels == c))))


def test_bad_split_specs(labels, meta):
    with pytest.raises(ValueError, match="fraction"):
        few_shot_split(labels, 0.0, seed=1)
    with pytest.raises(ValueError, match="protocol"):
        few_shot_split(labels, 0.1, seed=1, test="sometimes")
    with pytest.raises(ValueError, match="OOD split kind"):
        make_split({"kind": "ood", "ood": "weather"}, labels, meta, seed=1)
    with pytest.raises(ValueError, match="meta field 'angle_deg'"):
        make_split({"kind": "ood", "ood": "angle"}, labels, {"subject": meta["subject"]}, seed=1)
    with pytest.raises(ValueError, match="both must be > 0"):
        ood_split(labels, meta["hands"], [1, 2], seed=1)


@settings(max_examples=40, deadline=None)
@given(counts=st.lists(st.integers(1, 30), min_size=1, max_size=6), fraction=st.floats(0.01, 1.0),
       seed=st.integers(0, 2**31))
def test_stratified_sample_property(counts, fraction, seed):
    labels = np.random.default_rng(seed).permutation(np.repeat(np.arange(len(counts)), counts))
    rows = stratified_sample(labels, fraction, seed)
    got = np.bincount(labels[rows], minlength=len(counts))
    assert np.array_equal(got, [max(1, int(round(fraction * n))) for n in counts])
    assert len(np.unique(rows)) == len(rows)
    assert np.array_equal(rows, stratified_sample(labels, fraction, seed))
