"""Seeded, class-stratified splits of a dataset's rows: the one home of every split.

:func:`stratified_partition` cuts rows into parts (the datamodule's train/val/test, the gap
diagnosis's calibration and evaluation halves); the rest serves the few-shot and OOD experiments.

Every split is a :class:`Split` of row indices into one dataset file:

- ``train``: rows whose *radar* spectrograms train the classifier (the few-shot real data);
- ``pool``: every non-test row. Its *skeletons* may be synthesised (the radar data of rows outside
  ``train`` are not used, but their Leap skeletons are still available); ``train`` is a subset;
- ``test``: rows the classifier is evaluated on; disjoint from ``pool``.

Sampling is stratified by class: each class gets ``max(1, round(fraction * n_class))`` rows, taken
as a prefix of a per-class permutation seeded by ``(seed, class)``. Prefixes make the few-shot sets
of one seed nested (the 5 % rows are among the 20 % rows) and a class's draw independent of which
other classes exist. A measured dataset's rows split by its manifest's splits (:func:`measured_split`):
validation rows of its training split, then K training rows per class.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from handradar.errors import TooFewRows
from handradar.vocab import GESTURES

OOD_KINDS = ("angle", "subject", "hands", "occlusion")


@dataclass(frozen=True)
class Split:
    """Row indices (sorted int64 arrays) into one dataset; see the module docstring."""

    train: np.ndarray
    pool: np.ndarray
    test: np.ndarray

    def __post_init__(self) -> None:
        for name in ("train", "pool", "test"):
            object.__setattr__(self, name, np.sort(np.asarray(getattr(self, name), dtype=np.int64)))
        if not np.isin(self.train, self.pool).all():
            raise ValueError("split: train rows must be part of the pool")
        if np.intersect1d(self.pool, self.test).size:
            raise ValueError("split: test rows overlap the training pool")

    def sizes(self) -> dict[str, int]:
        return {"n_train": len(self.train), "n_pool": len(self.pool), "n_test": len(self.test)}


def _class_permutation(rows: np.ndarray, seed: int, cls: int) -> np.ndarray:
    rng = np.random.default_rng([int(seed), int(cls) + 1])
    return rows[rng.permutation(len(rows))]


def stratified_sample(labels: np.ndarray, fraction: float, seed: int, rows: np.ndarray | None = None) -> np.ndarray:
    """``max(1, round(fraction * n_c))`` rows of each class ``c`` among ``rows`` (default: all)."""
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], found {fraction}")
    labels = np.asarray(labels)
    rows = np.arange(len(labels)) if rows is None else np.asarray(rows, dtype=np.int64)
    picked = []
    for c in np.unique(labels[rows]):
        members = np.sort(rows[labels[rows] == c])
        k = max(1, int(round(fraction * len(members))))
        picked.append(_class_permutation(members, seed, c)[:k])
    return np.sort(np.concatenate(picked)) if picked else np.zeros(0, dtype=np.int64)


def stratified_partition(labels: np.ndarray, fractions: Sequence[float], seed: int, *,
                         every_part: bool = False) -> list[np.ndarray]:
    """Row indices split into ``len(fractions)`` parts, each class divided in those proportions.

    Per class (in label order), rows are shuffled by one generator seeded with ``seed`` and cut at
    round(n_class * cumulative fraction); parts are returned sorted.

    every_part: every part gets each class (the gap diagnosis's calibration / evaluation halves):
    a class of n >= len(fractions) rows gives each part at least one row, and a class of one row
    goes to the first part that is below its target size; a part left empty is an error.
    """
    labels = np.asarray(labels)
    f = np.asarray(fractions, dtype=np.float64)
    if f.ndim != 1 or len(f) == 0 or np.any(f < 0) or not np.isclose(f.sum(), 1.0):
        raise ValueError(f"split fractions must be non-negative and sum to 1, found {list(fractions)}")
    if every_part and np.any(f <= 0):
        raise ValueError(f"every part needs a positive fraction, found {list(fractions)}")
    rng = np.random.default_rng(seed)
    parts: list[list[int]] = [[] for _ in f]
    singles: list[int] = []
    for c in np.unique(labels):
        rows = rng.permutation(np.flatnonzero(labels == c))
        if every_part and rows.size == 1:
            singles.append(int(rows[0]))
            continue
        cuts = np.round(np.cumsum(f) * len(rows)).astype(int)
        if every_part and rows.size >= len(f):  # at least one row per part
            cuts = np.clip(cuts, np.arange(1, len(f) + 1), rows.size - np.arange(len(f) - 1, -1, -1))
        for k, (lo, hi) in enumerate(zip(np.r_[0, cuts[:-1]], cuts)):
            parts[k].extend(rows[lo:hi].tolist())
    for r in rng.permutation(np.asarray(singles, dtype=np.int64)).tolist():
        n = sum(len(p) for p in parts) + 1
        k = next((k for k in range(len(f)) if len(parts[k]) < f[k] * n), len(f) - 1)
        parts[k].append(int(r))
    if every_part and not all(parts):
        raise ValueError(f"{labels.size} rows cannot be split into {len(f)} non-empty parts")
    return [np.sort(np.asarray(p, dtype=np.int64)) for p in parts]


def few_shot_split(labels: np.ndarray, fraction: float, *, seed: int,
                   test: Literal["remainder", "fixed"] = "remainder", test_fraction: float = 0.2,
                   test_seed: int = 0, per_class: int | None = None) -> Split:
    """Few-shot split: ``fraction`` of the real radar data of each class trains the classifier.

    test="remainder": the test set is every row not drawn (the pool is the drawn rows).
    test="fixed": a test set of ``test_fraction`` of each class drawn with ``test_seed`` (the same
    for every seed and fraction: the paper's starred rows); ``fraction`` of each class of the
    *complete* dataset is then drawn from the rest, and the pool is every non-test row.
    per_class: that many training rows of each class instead of a fraction (all there are, if fewer);
    one seed's rows are nested, the first k of a class being those of any smaller k.
    """
    labels = np.asarray(labels)
    every = np.arange(len(labels))
    if per_class is not None and int(per_class) < 1:
        raise ValueError(f"split.per_class must be at least 1, found {per_class}")
    if test == "remainder":
        if per_class is None:
            train = stratified_sample(labels, fraction, seed)
        else:
            train = np.sort(np.concatenate([_class_permutation(np.flatnonzero(labels == c), seed, c)[:int(per_class)]
                                            for c in np.unique(labels)]))
        return Split(train=train, pool=train, test=np.setdiff1d(every, train))
    if test == "fixed":
        test_rows = stratified_sample(labels, test_fraction, test_seed)
        pool = np.setdiff1d(every, test_rows)
        train = []
        for c in np.unique(labels[pool]):
            members = np.sort(pool[labels[pool] == c])
            want = int(per_class) if per_class is not None else max(1, int(round(fraction * np.count_nonzero(labels == c))))
            k = min(len(members), want)
            train.append(_class_permutation(members, seed, c)[:k])
        return Split(train=np.concatenate(train) if train else pool[:0], pool=pool, test=test_rows)
    raise ValueError(f"test protocol must be 'remainder' or 'fixed', found {test!r}")


def class_counts(labels: np.ndarray, classes: Sequence[str] | None = None) -> str:
    """``N rows: grasp 2, circle 1`` (rows per class, in label order) for messages about too few rows."""
    names = list(classes) if classes is not None else list(GESTURES)
    values, counts = np.unique(np.asarray(labels), return_counts=True)
    per = ", ".join(f"{names[v] if 0 <= v < len(names) else v} {n}" for v, n in zip(values.tolist(), counts.tolist()))
    return f"{len(labels)} row{'s' * (len(labels) != 1)}" + (f": {per}" if per else "")


def check_split(split: Split, labels: np.ndarray, spec: dict, classes: Sequence[str] | None = None) -> Split:
    """``split``, or TooFewRows stating the minimum: training rows of at least 2 gestures (a classifier that
    has seen one gesture tells nothing apart) and a test row."""
    trained = len(np.unique(np.asarray(labels)[split.train]))
    if trained >= 2 and len(split.test):
        return split
    what = ("at least 2 gestures with at least 2 rows each (1 to train on, 1 to test on)"
            if spec.get("kind", "few_shot") == "few_shot" else
            "in-distribution rows of at least 2 gestures to train on and out-of-distribution rows to test on")
    raise TooFewRows(f"too few rows for the split {({k: v for k, v in spec.items() if v is not None})}: training needs {what}; the data hold "
                     f"{class_counts(labels, classes)} (the split trains on {len(split.train)} rows of {trained} "
                     f"gesture(s) and tests on {len(split.test)})")


def ood_field(kind: str) -> str:
    """The meta field an OOD split separates on."""
    fields = {"angle": "angle_deg", "subject": "subject", "hands": "hands", "occlusion": "occlusion"}
    if kind not in fields:
        raise ValueError(f"OOD split kind must be one of {OOD_KINDS}, found {kind!r}")
    return fields[kind]


def default_train_values(kind: str, values: np.ndarray, seed: int, test_subjects: float = 0.25) -> list:
    """The in-distribution values of an OOD split.

    angle: 0 deg (test +/-30); hands: 1 (single-hand -> double-hand); occlusion: without -> with;
    subject: all but ``ceil(test_subjects * n_subjects)`` subjects drawn with ``seed``.
    """
    if kind == "angle":
        return [0]
    if kind == "hands":
        return [1]
    if kind == "occlusion":
        return [False]
    if kind == "subject":
        subjects = np.unique(values)
        if len(subjects) < 2:
            raise TooFewRows(f"subject split needs at least 2 subjects, found {list(subjects)}")
        n_test = min(len(subjects) - 1, max(1, int(np.ceil(test_subjects * len(subjects)))))
        held = np.random.default_rng([int(seed), 7919]).permutation(subjects)[:n_test]
        return sorted(set(subjects.tolist()) - set(held.tolist()))
    raise ValueError(f"OOD split kind must be one of {OOD_KINDS}, found {kind!r}")


def ood_split(labels: np.ndarray, values: np.ndarray, train_values: Sequence, *, seed: int,
              fraction: float = 1.0, test_fraction: float = 0.5) -> Split:
    """Out-of-distribution split on one meta field.

    Rows whose ``values`` are in ``train_values`` are in-distribution: ``fraction`` of each class of
    them trains the classifier. The other rows are out-of-distribution: ``test_fraction`` of each of
    their classes is the test set; the remaining OOD rows join the pool (their skeletons may be
    synthesised, their radar data are never used).
    """
    labels = np.asarray(labels)
    values = np.asarray(values)
    inside = np.isin(values, list(train_values))
    in_rows, out_rows = np.flatnonzero(inside), np.flatnonzero(~inside)
    if not len(in_rows) or not len(out_rows):
        raise TooFewRows(f"OOD split on values {sorted(set(values.tolist()))} with in-distribution {list(train_values)}: "
                         f"{len(in_rows)} in-distribution and {len(out_rows)} out-of-distribution rows; both must be > 0")
    train = stratified_sample(labels, fraction, seed, in_rows)
    test = stratified_sample(labels, test_fraction, seed, out_rows)
    pool = np.setdiff1d(np.arange(len(labels)), test)
    return Split(train=train, pool=pool, test=test)


def make_split(spec: dict, labels: np.ndarray, meta: dict[str, np.ndarray], seed: int) -> Split:
    """The split a preset's ``split`` config names (``kind: few_shot`` or ``kind: ood``)."""
    kind = spec.get("kind", "few_shot")
    if kind == "few_shot":
        per_class = spec.get("per_class")
        return check_split(few_shot_split(labels, float(spec["fraction"]), seed=seed, test=spec.get("test", "remainder"),
                                          test_fraction=float(spec.get("test_fraction", 0.2)),
                                          test_seed=int(spec.get("test_seed", 0)),
                                          per_class=None if per_class is None else int(per_class)),
                           labels, spec)
    if kind == "ood":
        ood = spec["ood"]
        field = ood_field(ood)
        if field not in meta:
            raise ValueError(f"OOD split '{ood}' needs the meta field '{field}', which the dataset lacks "
                             f"(fields: {sorted(meta)})")
        values = meta[field]
        train_values = spec.get("train_values")
        if train_values is None:
            train_values = default_train_values(ood, values, seed, float(spec.get("test_subjects", 0.25)))
        return check_split(ood_split(labels, values, list(train_values), seed=seed,
                                     fraction=float(spec.get("fraction", 1.0)),
                                     test_fraction=float(spec.get("test_fraction", 0.5))), labels, spec)
    raise ValueError(f"split kind must be 'few_shot' or 'ood', found {kind!r}")


def measured_split(labels: np.ndarray, splits: np.ndarray, *, train: str, per_class: int | str, val_per_class: int,
                   seed: int, test_seed: int = 0, classes: Sequence[str] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(training rows, validation rows) of the ``train`` split: ``val_per_class`` rows per class drawn with
    ``test_seed`` (the same for every seed and K), then ``per_class`` of the rest drawn with ``seed``, nested
    across K (``all``: every one); a class left with no validation row, or with fewer rows than ``per_class``,
    is an error naming it (``classes``: the names of the labels)."""
    train_rows, val_rows = [], []
    pool = np.flatnonzero(splits == train)
    for c in np.unique(labels[pool]):
        members = np.sort(pool[labels[pool] == c])
        val = _class_permutation(members, test_seed, c)[:val_per_class]
        rest = np.setdiff1d(members, val)
        name = repr(classes[c]) if classes is not None else str(c)
        if len(val) < val_per_class or (per_class != 0 and not len(rest)):
            raise TooFewRows(f"class {name} has {len(members)} rows in split {train!r}: too few for {val_per_class} "
                             "validation rows and at least 1 training row (split.val_per_class)")
        if per_class != "all" and int(per_class) > len(rest):
            raise TooFewRows(f"class {name} has {len(rest)} training rows besides its {val_per_class} validation rows: "
                             f"fewer than split.per_class={per_class} (split.per_class=all takes every one)")
        k = len(rest) if per_class == "all" else int(per_class)
        train_rows.append(_class_permutation(rest, seed, c)[:k])
        val_rows.append(val)
    return np.sort(np.concatenate(train_rows)), np.sort(np.concatenate(val_rows))
