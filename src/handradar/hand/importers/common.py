"""Helpers shared by the skeleton importers: strict float tables and single-hand sequences."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from handradar.errors import FormatError
from handradar.hand.skeleton import HANDS, N_JOINTS, HandSequence

MIRROR = {"x": np.diag([-1.0, 1.0, 1.0]), "y": np.diag([1.0, -1.0, 1.0]), "z": np.diag([1.0, 1.0, -1.0])}


def read_float_rows(path: str | Path, n_values: int, *, sep: str | None = None, what: str = "values") -> np.ndarray:
    """A text table of ``n_values`` finite floats per non-empty line -> (rows, n_values) float64.

    sep: None for whitespace, else a one-character separator (a trailing separator is allowed).
    Raises FormatError naming the file, the line and expected vs found for a short or long line,
    a token that is not a number, or a NaN/infinite value; never a numpy error.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise FormatError(path, f"cannot read: {exc.strerror}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
    rows: list[np.ndarray] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line:
            continue
        tokens = line.split(sep)
        if sep is not None and tokens[-1].strip() == "":
            tokens = tokens[:-1]  # "1;2;3;" ends with the separator
        if len(tokens) != n_values:
            raise FormatError(path, f"expected {n_values} {what} per line, found {len(tokens)}", line=lineno)
        try:
            row = np.array([float(t) for t in tokens], dtype=np.float64)
        except ValueError:
            k = next(i for i, t in enumerate(tokens) if not _is_float(t))
            raise FormatError(path, f"expected a number, found {tokens[k].strip()!r:.40} "
                                    f"(value {k + 1} of {n_values})", line=lineno) from None
        if not np.all(np.isfinite(row)):
            k = int(np.flatnonzero(~np.isfinite(row))[0])
            raise FormatError(path, f"value {k + 1} of {n_values} is {tokens[k].strip()!r}: NaN or infinite "
                                    "coordinates (missing joints?)", line=lineno)
        rows.append(row)
    if not rows:
        raise FormatError(path, f"no data: expected lines of {n_values} {what}")
    return np.stack(rows)


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def single_hand_sequence(joints: np.ndarray, times: np.ndarray, *, hand: str = "right", source: str,
                         attrs: dict | None = None) -> HandSequence:
    """(T, 21, 3) joints of one hand -> a two-slot HandSequence with the hand in its slot."""
    if hand not in HANDS:
        raise ValueError(f"hand must be one of {HANDS}, found {hand!r}")
    t = joints.shape[0]
    positions = np.zeros((t, 2, N_JOINTS, 3), dtype=np.float32)
    mask = np.zeros((t, 2), dtype=bool)
    slot = HANDS.index(hand)
    positions[:, slot] = joints
    mask[:, slot] = True
    return HandSequence(positions, times, mask, source=source, attrs=dict(attrs or {}))


def trim_rows(path: Path, rows: np.ndarray, start: int | None, end: int | None) -> np.ndarray:
    """Keep frames ``start..end`` (1-based, inclusive, as in DHG's informations_troncage_sequences.txt)."""
    n = rows.shape[0]
    lo = 1 if start is None else int(start)
    hi = n if end is None else int(end)
    if not 1 <= lo < hi <= n:
        raise FormatError(path, f"frames {lo}..{hi} requested (1-based, inclusive) but the file has {n} frames")
    return rows[lo - 1:hi]
