"""Leap Motion ``leap.jsonl`` (a subset of the WebSocket frame, protocol v6): reader and writer.

Leap frame: millimetres, origin at the device, +y up, +x right, +z toward the user; timestamps in
microseconds. Each hand has a ``wrist``; each pointable (``type`` 0..4 = thumb..pinky) has
carp/mcp/pip/dip/btip positions. Mapping to the canonical skeleton: thumb carp == mcp (Leap's
zero-length thumb metacarpal), so thumb mcp/pip/dip/btip are CMC/MCP/IP/tip; other fingers'
mcp/pip/dip/btip are MCP/PIP/DIP/tip; the wrist comes from the hand's ``wrist`` field.

Frames without hands are kept as untracked steps (mask False); nothing is invented.
"""

from __future__ import annotations

import contextlib
import gc
import itertools
import json
import math
import operator
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np
import pydantic_core

from handradar.atomic import atomic_write_text
from handradar.errors import FormatError
from handradar.hand.skeleton import HANDS, N_JOINTS, HandSequence

LEAP_JOINT_FIELDS = ("mcpPosition", "pipPosition", "dipPosition", "btipPosition")


def finite_number(value: object) -> float | None:
    """``value`` as a finite float, or None if it is not a JSON number (bools excluded) or not finite.

    JSON integers can be arbitrarily large; converting one beyond float range raises OverflowError,
    which is caught here so that no reader lets it escape.
    """
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return None
    try:
        out = float(value)
    except OverflowError:
        return None
    return out if math.isfinite(out) else None


def _vec3(path: Path, lineno: int, what: str, value: object) -> list[float]:
    if not isinstance(value, list) or len(value) != 3:
        raise FormatError(path, f"{what}: expected [x, y, z] numbers, found {value!r:.80}", line=lineno)
    out = [finite_number(v) for v in value]
    if any(v is None for v in out):
        raise FormatError(path, f"{what}: expected three finite numbers, found {value!r:.80}", line=lineno)
    return out  # type: ignore[return-value]


def _hand_id(path: Path, lineno: int, what: str, value: object) -> int | str:
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        raise FormatError(path, f"{what} must be an integer id, found {value!r:.40}", line=lineno)
    return value


_NUMBER = (int, float)  # exact types: json gives bool for true/false, which must not pass as a number
_PLAIN_NUMBERS = frozenset(_NUMBER)
_NO_FINGERS = (None,) * (N_JOINTS - 1)
_ALL_FINGERS = 0b11111
_JOINT_VALUES = operator.itemgetter(*LEAP_JOINT_FIELDS)  # one C call per pointable; KeyError if one is missing
_FINGER_SLICES = tuple(slice(1 + 4 * f, 5 + 4 * f) for f in range(5))  # finger f's joints in canonical order
_BATCH_HANDS = 2048  # hands whose raw JSON values are kept before converting them: bounds the memory of long files


def _joint_block(path: Path, lineno: int, slot: int, raw: list[object]) -> np.ndarray:
    """21 raw JSON values (wrist, then mcp/pip/dip/btip of fingers 0..4) -> (21, 3) float64.

    Fast path: one type sweep and one numpy conversion; anything unusual falls back to checking
    vector by vector, which names the offending field.
    """
    if all(type(v) is list and len(v) == 3 for v in raw) and all(type(x) in _NUMBER for v in raw for x in v):
        try:
            block = np.array(raw, dtype=np.float64)
        except OverflowError:  # an integer beyond float range
            block = None
        if block is not None and np.isfinite(block).all():
            return block
    for k, value in enumerate(raw):
        what = (f"{HANDS[slot]} hand wrist" if k == 0
                else f"{HANDS[slot]} finger {(k - 1) // 4} {LEAP_JOINT_FIELDS[(k - 1) % 4]}")
        _vec3(path, lineno, what, value)
    raise AssertionError("unreachable: a vector failed the fast check but passed the slow one")


def _frame_vectors(obj: object, path: Path, lineno: int) -> tuple[float, list[list[object] | None]]:
    """Every check of one frame but the joint numbers: (timestamp_us, per slot its 21 raw JSON joint
    values in canonical order, or None where the hand is untracked).

    The numbers are left to :func:`_joint_block` (one frame) or :func:`_joint_arrays` (a whole file).
    """
    if not isinstance(obj, dict):
        raise FormatError(path, f"expected a JSON object per line, found {type(obj).__name__}", line=lineno)
    ts = finite_number(obj.get("timestamp"))
    if ts is None:
        raise FormatError(path, f"'timestamp' must be a finite number of microseconds, found "
                                f"{obj.get('timestamp', '<missing>')!r:.40}", line=lineno)
    hands = obj.get("hands", [])
    pointables = obj.get("pointables", [])
    if not isinstance(hands, list) or not isinstance(pointables, list):
        raise FormatError(path, "'hands' and 'pointables' must be lists", line=lineno)
    raw: list[list[object] | None] = [None, None]  # per slot: JSON values, their numbers checked later
    slot_of_id: dict[object, int] = {}
    for hand in hands:
        if not isinstance(hand, dict):
            raise FormatError(path, "each hand must be a JSON object", line=lineno)
        kind = hand.get("type")
        if kind not in HANDS:
            raise FormatError(path, f"hand 'type' must be 'right' or 'left', found {kind!r:.40}", line=lineno)
        slot = HANDS.index(kind)
        if raw[slot] is not None:
            continue  # a second hand of the same side: keep the first, as Leap's own API does
        if "id" not in hand:
            raise FormatError(path, f"{kind} hand has no 'id' (pointables refer to their hand by it)", line=lineno)
        hid = _hand_id(path, lineno, f"{kind} hand 'id'", hand["id"])
        if "wrist" not in hand:
            raise FormatError(path, f"{kind} hand (id {hid!r}) has no 'wrist'", line=lineno)
        raw[slot] = [hand["wrist"], *_NO_FINGERS]
        slot_of_id[hid] = slot
    found = [0, 0]  # per slot: bit f set once finger f has its pointable
    for p in pointables:
        if not isinstance(p, dict):
            raise FormatError(path, "each pointable must be a JSON object", line=lineno)
        hid = p.get("handId")
        if type(hid) is not int and type(hid) is not str:  # the common case without a call; else check it
            hid = _hand_id(path, lineno, "pointable 'handId'", hid)
        slot = slot_of_id.get(hid)
        if slot is None:
            continue  # pointable of an ignored or unknown hand
        f = p.get("type")
        if type(f) is not int or not 0 <= f <= 4:
            raise FormatError(path, f"pointable 'type' must be 0..4 (thumb..pinky), found {f!r:.40}", line=lineno)
        if found[slot] >> f & 1:
            raise FormatError(path, f"{HANDS[slot]} hand has two pointables of type {f}", line=lineno)
        try:
            raw[slot][_FINGER_SLICES[f]] = _JOINT_VALUES(p)  # type: ignore[index]
        except KeyError:
            key = next(k for k in LEAP_JOINT_FIELDS if k not in p)
            raise FormatError(path, f"{HANDS[slot]} hand finger {f} has no '{key}'", line=lineno) from None
        found[slot] |= 1 << f
    for slot in (0, 1):
        if raw[slot] is not None and found[slot] != _ALL_FINGERS:
            if slot == 1 and raw[0] is not None:
                _joint_block(path, lineno, 0, raw[0])  # the right hand's numbers are checked before the left's fingers
            missing = [f for f in range(5) if not found[slot] >> f & 1]
            raise FormatError(path, f"{HANDS[slot]} hand is tracked but finger(s) {missing} have no pointable "
                                    "(expected all five, types 0..4)", line=lineno)
    return float(ts), raw


def parse_leap_frame(obj: object, path: Path, lineno: int) -> tuple[float, np.ndarray, np.ndarray]:
    """One frame -> (timestamp_us, joints (2, 21, 3) Leap mm, tracked (2,))."""
    ts, raw = _frame_vectors(obj, path, lineno)
    joints = np.zeros((2, N_JOINTS, 3), dtype=np.float64)
    tracked = np.zeros(2, dtype=bool)
    for slot, values in enumerate(raw):
        if values is not None:
            joints[slot] = _joint_block(path, lineno, slot, values)
            tracked[slot] = True
    return ts, joints, tracked


def _joint_arrays(path: Path, blocks: list[tuple[int, int, list[object]]], vectors: list[object]) -> np.ndarray:
    """The raw joint values of many hands -> (hands, 21, 3) float64.

    blocks: (line, slot, its 21 raw values) per hand; vectors: all their raw values, concatenated.
    Fast path, C loops only: every vector a 3-sequence, every coordinate an int or a float (bools,
    strings, nulls and nested values fail), one conversion of the whole file that converts each
    value as :func:`_joint_block` does (``float(value)``). Anything unusual falls back to
    :func:`_joint_block`, hand by hand in file order, which names the first bad field and its line.
    """
    if not blocks:
        return np.zeros((0, N_JOINTS, 3), dtype=np.float64)
    try:
        flat = list(itertools.chain.from_iterable(vectors)) if set(map(len, vectors)) == {3} else None
        if flat is not None and set(map(type, flat)) <= _PLAIN_NUMBERS:
            out = np.fromiter(flat, dtype=np.float64, count=len(flat))
            if np.isfinite(out).all():
                return out.reshape(len(blocks), N_JOINTS, 3)
    except (TypeError, OverflowError):  # a value without a length (a number, null); an integer beyond float range
        pass
    return np.stack([_joint_block(path, lineno, slot, values) for lineno, slot, values in blocks])


def _check_joint_blocks(path: Path, blocks: list[tuple[int, int, list[object]]]) -> None:
    """Raise the FormatError of the first hand in ``blocks`` whose joint values are bad, if any."""
    for lineno, slot, values in blocks:
        _joint_block(path, lineno, slot, values)


def leap_matrix(value: object, source: str | Path) -> np.ndarray:
    """Validate a 4x4 row-major Leap-mm -> radar-m matrix with last row [0, 0, 0, 1]."""
    rows = value if isinstance(value, (list, tuple)) else None
    if rows is None or len(rows) != 4 or not all(isinstance(r, (list, tuple)) and len(r) == 4 for r in rows):
        raise FormatError(source, f"leap_to_radar must be a 4x4 row-major matrix (4 lists of 4 numbers), "
                                  f"found {value!r:.80}")
    numbers = [[finite_number(v) for v in r] for r in rows]
    if any(v is None for r in numbers for v in r):
        raise FormatError(source, f"leap_to_radar must hold 16 finite numbers, found {value!r:.80}")
    m = np.asarray(numbers, dtype=np.float64)
    if not np.allclose(m[3], [0, 0, 0, 1]):
        raise FormatError(source, f"leap_to_radar last row must be [0, 0, 0, 1], found {m[3].tolist()}")
    if not abs(np.linalg.det(m[:3, :3])) > 1e-12:
        raise FormatError(source, "leap_to_radar is singular (its 3x3 part has determinant 0)")
    return m


def _loads(raw: bytes, line: str) -> object:
    """One JSON line: pydantic-core's parser (about twice as fast as the standard library's, the
    largest cost of reading a Leap file); anything it refuses goes through ``json.loads``, which
    either accepts it as well or raises the error reported to the user (with its column)."""
    try:
        return pydantic_core.from_json(raw)
    except ValueError:
        return json.loads(line)


@contextlib.contextmanager
def _gc_paused() -> Iterator[None]:
    """The cyclic garbage collector paused: parsed JSON holds no reference cycles (reference counting
    frees it), while the raw joint values kept until their batch is converted would make every
    collection pass walk them again: measured, 8.9-12.2 ms against 6.1-6.4 ms for a 261-frame file, as
    collections come with what else the process holds (in bench_ingest they are rare: no change)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def read_leap_jsonl(path: str | Path, leap_to_radar: np.ndarray | list, radar_start_us: float) -> HandSequence:
    """Read ``leap.jsonl`` into a radar-frame HandSequence; time 0 is the start of radar frame 0.

    Hands beyond one per side are dropped (the first of each side is kept); where there were any,
    ``attrs`` counts them: ``extra_hands`` and ``extra_hand_frames`` (the frames that held them)."""
    path = Path(path)
    m = leap_matrix(leap_to_radar.tolist() if isinstance(leap_to_radar, np.ndarray) else leap_to_radar, path)
    stamps: list[float] = []
    blocks: list[tuple[int, int, list[object]]] = []  # (line, slot, raw joint values) of tracked hands not yet converted
    vectors: list[object] = []  # the raw joint values of those blocks, concatenated
    converted: list[np.ndarray] = []  # (hands, 21, 3) Leap mm of the blocks converted so far, in file order
    where: list[int] = []  # 2 * frame index + slot of every tracked hand
    extra = [0, 0]  # hands beyond one per side that _frame_vectors drops, and the frames holding them
    try:
        fh = path.open("rb")  # bytes: a decoding error is then reported with its line number
    except OSError as exc:
        raise FormatError(path, f"cannot read: {exc.strerror}") from None
    with fh, _gc_paused():
        try:
            for lineno, raw in enumerate(fh, start=1):
                try:
                    line = raw.decode("utf-8")
                except UnicodeDecodeError:
                    raise FormatError(path, "not UTF-8 text", line=lineno) from None
                if not line.strip():
                    continue
                try:
                    obj = _loads(raw, line)
                except json.JSONDecodeError as exc:
                    raise FormatError(path, f"invalid JSON ({exc.msg} at column {exc.colno})", line=lineno) from None
                except ValueError as exc:  # e.g. an integer literal beyond Python's 4300-digit conversion limit
                    raise FormatError(path, f"invalid JSON ({exc})", line=lineno) from None
                except RecursionError:
                    raise FormatError(path, "JSON nested too deeply", line=lineno) from None
                ts, per_slot = _frame_vectors(obj, path, lineno)
                n_extra = len(obj.get("hands", ())) - (per_slot[0] is not None) - (per_slot[1] is not None)
                if n_extra:  # counted so that the quality gate can say so (handradar.data.quality)
                    extra[0] += n_extra
                    extra[1] += 1
                for slot, values in enumerate(per_slot):
                    if values is not None:
                        blocks.append((lineno, slot, values))
                        vectors.extend(values)
                        where.append(2 * len(stamps) + slot)
                if stamps and ts <= stamps[-1]:
                    raise FormatError(path, f"timestamps must increase: {ts:.0f} us follows {stamps[-1]:.0f} us",
                                      line=lineno)
                stamps.append(ts)
                if len(blocks) >= _BATCH_HANDS:
                    converted.append(_joint_arrays(path, blocks, vectors))
                    blocks, vectors = [], []
        except FormatError:
            # joint numbers are checked a batch of lines at a time; a bad one on an earlier line (or
            # earlier on this one) comes first in the file, so it is the error to report
            _check_joint_blocks(path, blocks)
            raise
    converted.append(_joint_arrays(path, blocks, vectors))  # before the frame count: a bad number comes earlier
    if len(stamps) < 2:
        raise FormatError(path, f"expected at least 2 frames, found {len(stamps)}")
    joints_mm = np.zeros((len(stamps), 2, N_JOINTS, 3), dtype=np.float64)
    mask = np.zeros((len(stamps), 2), dtype=bool)
    joints_mm.reshape(-1, N_JOINTS, 3)[where] = np.concatenate(converted)  # a view: (frames * 2, ...) rows
    mask.reshape(-1)[where] = True
    radar = joints_mm @ m[:3, :3].T + m[:3, 3]
    too_big = ~(np.abs(radar) < 1e6).all(axis=(-2, -1)) & mask  # metres; float32 would overflow far beyond
    if too_big.any():
        t = int(np.argmax(too_big.any(axis=1)))
        raise FormatError(path, f"joint coordinates of frame {t + 1} are {np.abs(radar[t]).max():.3g} m from the "
                                "radar after leap_to_radar; expected a hand within metres")
    times = (np.asarray(stamps) - float(radar_start_us)) * 1e-6
    attrs = {"extra_hands": extra[0], "extra_hand_frames": extra[1]} if extra[0] else {}
    return HandSequence(radar.astype(np.float32), times, mask, source=str(path), attrs=attrs)


# A tracked hand from the wrist to its farthest joint: 17-21 cm for an adult's open hand (wrist to
# middle fingertip), about 9 cm in a fist. The bounds leave room for small hands and tracking error
# and still catch a unit slip (a factor of 10 or more).
HAND_LENGTH_RANGE_M = (0.03, 0.30)
TYPICAL_HAND_LENGTH_M = 0.18
# Leap tracks hands within about 0.6 m of its sensor, which sits beside the radar
MAX_HAND_DISTANCE_M = 3.0


def _length(m: float) -> str:
    """A length in metres, written in the unit that reads best."""
    return f"{m * 1e3:.3g} mm" if m < 0.01 else f"{m * 1e2:.3g} cm" if m < 1 else f"{m:.3g} m"


def _unit_hint(factor: float) -> str:
    """The likely unit slip behind hands ``factor`` times their typical size (within a factor of 5)."""
    slips = {
        -3: "likely the Leap coordinates are in metres instead of millimetres",
        -1: "likely the Leap coordinates are in centimetres instead of millimetres",
        3: "likely leap_to_radar in meta.json keeps millimetres instead of converting them to metres "
           "(expected a scale of 0.001)",
    }
    decades = math.log10(factor) if factor > 0 else -math.inf
    for exponent, hint in slips.items():
        if abs(decades - exponent) <= math.log10(5):
            return hint
    return "check the units of the Leap coordinates (millimetres) and of leap_to_radar (millimetres to metres)"


def check_hand_geometry(seq: HandSequence, source: str | Path) -> None:
    """Fail unless the tracked hands of a radar-frame ``seq`` are hand-sized and near the radar.

    Hand length (wrist to the farthest joint) and distance (joint centroid to the radar) are the
    medians over all tracked hand frames, so a few glitched frames do not decide; a unit slip in
    leap.jsonl or in leap_to_radar scales every frame and is caught.
    """
    pos = seq.positions[seq.mask].astype(np.float64)  # (tracked hand frames, 21, 3) metres
    if not len(pos):
        return  # untracked throughout: the recording's tracked-hands check reports it
    length = float(np.median(np.linalg.norm(pos - pos[:, :1], axis=-1).max(axis=-1)))
    lo, hi = HAND_LENGTH_RANGE_M
    if not lo <= length <= hi:
        raise FormatError(source, f"after leap_to_radar the hands measure {_length(length)} from the wrist to the "
                                  f"farthest joint (median of {len(pos)} tracked hand frames); expected "
                                  f"{_length(lo)} to {_length(hi)}: "
                                  f"{_unit_hint(length / TYPICAL_HAND_LENGTH_M)}")
    distance = float(np.median(np.linalg.norm(pos.mean(axis=1), axis=-1)))
    if distance > MAX_HAND_DISTANCE_M:
        raise FormatError(source, f"after leap_to_radar the hands are {_length(distance)} from the radar (median of "
                                  f"{len(pos)} tracked hand frames); expected within {_length(MAX_HAND_DISTANCE_M)}: "
                                  "check the translation column of leap_to_radar in meta.json (metres)")


def leap_frames_from_sequence(seq: HandSequence, radar_to_leap: np.ndarray, radar_start_us: float,
                              *, finger_width_mm: float = 18.0) -> Iterable[dict]:
    """Leap frames (dicts) for a radar-frame sequence: the inverse of :func:`read_leap_jsonl`."""
    m = np.asarray(radar_to_leap, dtype=np.float64)
    mm = seq.positions.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    rate = float(1.0 / np.median(np.diff(seq.times)))  # once, not per frame (O(T^2) otherwise)
    for t in range(seq.n_steps):
        ts = int(round(seq.times[t] * 1e6 + radar_start_us))
        hands, pointables = [], []
        for slot, kind in enumerate(HANDS):
            if not seq.mask[t, slot]:
                continue
            hid = slot + 1
            j = mm[t, slot]
            jr = j.round(3).tolist()  # one conversion per hand: per-joint tolist() dominated the cost
            palm = j[[0, 5, 9, 13, 17]].mean(axis=0)
            direction = j[9] - j[0]
            direction /= np.linalg.norm(direction) + 1e-12
            normal = np.cross(j[5] - j[0], j[17] - j[0]) * (1 if kind == "right" else -1)
            normal /= np.linalg.norm(normal) + 1e-12
            hands.append({"id": hid, "type": kind, "palmPosition": palm.round(3).tolist(),
                          "palmNormal": normal.round(5).tolist(), "direction": direction.round(5).tolist(),
                          "palmWidth": float(np.linalg.norm(j[5] - j[17]).round(3)),
                          "wrist": jr[0], "elbow": (j[0] - 250.0 * direction).round(3).tolist()})
            for f in range(5):
                carp = jr[1] if f == 0 else (j[0] + 0.25 * (j[1 + 4 * f] - j[0])).round(3).tolist()
                p = {"handId": hid, "type": f, "width": finger_width_mm, "carpPosition": carp}
                p.update({k: jr[1 + 4 * f + i] for i, k in enumerate(LEAP_JOINT_FIELDS)})
                pointables.append(p)
        yield {"id": t, "timestamp": ts, "currentFrameRate": rate,
               "hands": hands, "pointables": pointables}


def write_leap_jsonl(path: str | Path, frames: Iterable[dict]) -> None:
    """Write frames, one compact JSON object per line (atomically)."""

    atomic_write_text(path, "".join(json.dumps(f, separators=(",", ":")) + "\n" for f in frames))
