"""Which rows each step of the gap diagnosis sees: the folds, the calibration subsets, the readout's fold, and
the minimum rows a diagnosis needs (docs/gap_diagnosis.md; handradar.gap.diagnosis uses them)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from handradar.data.splits import class_counts, stratified_partition
from handradar.errors import TooFewRows


def stratified_subset(labels: np.ndarray, idx: np.ndarray, n: int | None, seed: int) -> np.ndarray:
    """A stratified subset of ``n`` of the rows ``idx`` (all when n is None or >= len(idx))."""
    if n is None or n >= len(idx):
        return idx
    f = max(min(n / len(idx), 0.999), 1e-3)
    keep, _ = stratified_partition(labels[idx], (f, 1.0 - f), seed, every_part=True)
    return idx[keep]


READOUT_MIN_ROWS = 2  # the readout's paired bootstrap of gap_closed resamples at least 2 held-out rows


def readout_fold(held_out: Sequence[int]) -> int | None:
    """The fold that scores the RadarWeightNet readout, from each scored fold's count of held-out rows: the
    first with at least READOUT_MIN_ROWS (fold 0 wherever it has them); None where no fold has."""
    return next((i for i, n in enumerate(held_out) if n >= READOUT_MIN_ROWS), None)


def fold_positions(held_out: Sequence[int], k: int) -> np.ndarray:
    """Positions of scored fold ``k``'s rows in the evaluation arrays, which hold the scored folds' rows
    fold after fold (``held_out``: each fold's count)."""
    start = int(sum(held_out[:k]))
    return np.arange(start, start + held_out[k])


def readout_skip_reason(held_out: Sequence[int]) -> str:
    """Why the readout is skipped where :func:`readout_fold` finds no fold (the report's ``skipped``)."""
    return (f"no fold holds the {READOUT_MIN_ROWS} held-out rows its paired-bootstrap CI needs (the {len(held_out)} "
            f"folds hold {', '.join(map(str, held_out))}); record a second gesture, or more than {len(held_out)} "
            "recordings of one")


AUTO = "auto"
# folds = "auto" (the default): cross-fitting at every size, in AUTO_FOLDS_SMALL folds below
# AUTO_SMALL_BELOW_ROWS rows and AUTO_FOLDS from there. A false cause is the worst answer the diagnosis
# gives, and cross-fitting is the one setting measured to remove them (docs/gap_validation.md); below 60
# rows 3 folds let each fit see two thirds of the rows instead of half.
AUTO_FOLDS = 2
AUTO_FOLDS_SMALL = 3
AUTO_SMALL_BELOW_ROWS = 60


def resolve_folds(folds: int | str, labels: np.ndarray) -> int:
    """The folds a diagnosis of rows with class ``labels`` uses: ``folds`` itself, or for "auto"
    AUTO_FOLDS_SMALL below AUTO_SMALL_BELOW_ROWS rows and AUTO_FOLDS from there, at most the smallest
    class's rows (1, one split, where that is under 2)."""
    if folds != AUTO:
        if isinstance(folds, bool) or not isinstance(folds, int) or folds < 1:
            raise ValueError(f"diagnose.folds must be an integer >= 1 (1: one calibration/evaluation split) or "
                             f"'auto', found {folds!r}")
        return folds
    smallest = int(np.unique(labels, return_counts=True)[1].min()) if len(labels) else 0
    k = min(AUTO_FOLDS_SMALL if len(labels) < AUTO_SMALL_BELOW_ROWS else AUTO_FOLDS, smallest)
    return k if k >= 2 else 1


def cross_folds(labels: np.ndarray, k: int, seed: int) -> list[np.ndarray]:
    """``k`` disjoint parts of the rows (sorted indices), seeded and stratified by class, each holding
    every class: a k above the rows of the smallest class is refused."""
    classes, counts = np.unique(labels, return_counts=True)
    if k < 2:
        raise ValueError(f"cross-fitting needs at least 2 folds, found {k}")
    if k > counts.min():
        smallest = classes[counts.argmin()].item()
        raise ValueError(f"diagnose.folds = {k} exceeds the {counts.min()} rows of class {smallest!r}: every fold"
                         f" must hold every class (use at most {counts.min()} folds)")
    return stratified_partition(labels, [1.0 / k] * k, seed, every_part=True)


def check_rows(labels: np.ndarray, folds: int | str, calibration_fraction: float, seed: int) -> None:
    """TooFewRows, stating the minimum, when ``labels``' rows cannot be diagnosed: the paired bootstrap
    needs 2 evaluation rows and the fits 1 calibration row. With folds = "auto" that is 2 rows of
    each gesture (cross-fitting then scores every row); one split (folds = 1) needs more."""
    labels = np.asarray(labels)
    k = resolve_folds(folds, labels)
    minimum = ("too few rows to diagnose: the diagnosis needs at least 2 rows of each gesture (with diagnose.folds="
               "auto; one calibration/evaluation split needs 1 calibration and 2 evaluation rows)")
    try:
        parts = (stratified_partition(labels, (calibration_fraction, 1.0 - calibration_fraction), seed,
                                      every_part=True) if k == 1 else cross_folds(labels, k, seed))
    except ValueError as exc:  # fewer rows than parts, or a class smaller than the folds asked for
        raise TooFewRows(f"{minimum}; the data hold {class_counts(labels)}: {exc}") from None
    n_eval = len(parts[-1]) if k == 1 else len(labels)
    n_cal = len(parts[0]) if k == 1 else len(labels) - max(len(p) for p in parts)
    if n_eval >= 2 and n_cal >= 1:
        return
    raise TooFewRows(f"{minimum}; the data hold {class_counts(labels)}, which leave {n_cal} calibration and "
                     f"{n_eval} evaluation rows with folds={folds}")
