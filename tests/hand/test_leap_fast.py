"""The fast leap.jsonl reader (whole-file joint conversion) against straightforward references.

- Values: a reference reader written from the format description, one joint at a time, on a
  recording with two hands, one-hand and hand-less frames, dropped frames (timestamp gaps),
  a duplicate hand, a pointable of an unknown hand, shuffled pointables and integer coordinates.
- Errors: a line-by-line reader built on :func:`parse_leap_frame` (the reader as it was before
  the fast path); the fast reader must name the same first problem of the file, with its line.
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from handradar.errors import FormatError
from handradar.hand import leap
from handradar.hand.leap import parse_leap_frame, read_leap_jsonl
from tests.hand.test_leap import (
    _JSON_VALUES,
    FRAME_1,
    LEAP_TO_RADAR,
    RADAR_START_US,
    _paths,
    frame_3,
)

FIELDS = ("mcpPosition", "pipPosition", "dipPosition", "btipPosition")
PERIOD_US = 8696  # 115 Hz


def reference_read(path, matrix, radar_start_us):
    """leap.jsonl -> (radar-frame positions float32, times s, mask), straight from the format:
    the first hand of each side counts; its wrist, then mcp/pip/dip/btip of pointables 0..4."""
    m = np.asarray(matrix, dtype=np.float64)
    stamps, joints, masks = [], [], []
    for line in path.read_text().splitlines():
        if not line.strip():
            continue
        frame = json.loads(line)
        j = np.zeros((2, 21, 3))
        tracked = [False, False]
        slot_of = {}
        for hand in frame["hands"]:
            slot = ["right", "left"].index(hand["type"])
            if tracked[slot]:
                continue
            tracked[slot] = True
            slot_of[hand["id"]] = slot
            j[slot, 0] = [float(v) for v in hand["wrist"]]
        for p in frame["pointables"]:
            if p["handId"] in slot_of:
                for k, field in enumerate(FIELDS):
                    j[slot_of[p["handId"]], 1 + 4 * p["type"] + k] = [float(v) for v in p[field]]
        stamps.append(float(frame["timestamp"]))
        joints.append(j)
        masks.append(tracked)
    mask = np.array(masks)
    radar = (np.stack(joints) @ m[:3, :3].T + m[:3, 3]).astype(np.float32)
    radar[~mask] = 0.0
    return radar, (np.array(stamps) - radar_start_us) * 1e-6, mask


def _vec(rng) -> list:
    """Leap mm as the device writes them (3 decimals), now and then whole numbers as JSON integers."""
    v = np.round(rng.uniform(-150, 350, 3), 3)
    return [int(x) if rng.random() < 0.15 else float(x) for x in v]


def _hand(rng, hid: int, side: str) -> tuple[dict, list[dict]]:
    hand = {"id": hid, "type": side, "palmPosition": _vec(rng), "palmNormal": [0, -1, 0], "wrist": _vec(rng),
            "elbow": _vec(rng)}
    pointables = [{"handId": hid, "type": f, "width": 18.0, "carpPosition": _vec(rng),
                   **{k: _vec(rng) for k in FIELDS}} for f in range(5)]
    return hand, pointables


def mixed_recording(seed: int, n: int = 120) -> list[dict]:
    """Frames with both hands, one hand, none (tracking lost), gaps of lost frames, a duplicate right
    hand and a stray pointable; hands and pointables in random order."""
    rng = np.random.default_rng(seed)
    frames, ts = [], RADAR_START_US - 50_000
    for i in range(n):
        ts += PERIOD_US * (3 if rng.random() < 0.1 else 1)  # ~10 % of gaps: two frames dropped
        kind = rng.choice(["both", "right", "left", "none", "duplicate"], p=[0.4, 0.2, 0.15, 0.15, 0.1])
        hands, pointables = [], []
        sides = {"both": ["right", "left"], "right": ["right"], "left": ["left"], "none": [],
                 "duplicate": ["right", "left", "right"]}[kind]
        for k, side in enumerate(sides):
            h, p = _hand(rng, 10 * i + k, side)
            hands.append(h)
            pointables += p
        if rng.random() < 0.2:
            pointables.append({"handId": 99_999, "type": 1, **{k: _vec(rng) for k in FIELDS}})
        if kind != "duplicate":  # the duplicate keeps its order: the first right hand is the one read
            rng.shuffle(hands)
        rng.shuffle(pointables)
        frames.append({"id": i, "timestamp": int(ts), "hands": hands, "pointables": pointables})
    return frames


@pytest.mark.parametrize("batch", [5, leap._BATCH_HANDS])
@pytest.mark.parametrize("seed", [0, 1])
def test_fast_reader_matches_reference_reader(tmp_path, monkeypatch, batch, seed):
    monkeypatch.setattr(leap, "_BATCH_HANDS", batch)  # 5: many conversion batches, none aligned to frames
    frames = mixed_recording(seed)
    lines = [json.dumps(f) for f in frames]
    lines.insert(40, "   ")  # a blank line is skipped
    path = tmp_path / "leap.jsonl"
    path.write_text("\n".join(lines) + "\n")
    seq = read_leap_jsonl(path, LEAP_TO_RADAR, RADAR_START_US)
    positions, times, mask = reference_read(path, LEAP_TO_RADAR, RADAR_START_US)
    # the recording has every case in it
    assert mask.all(axis=1).any() and (~mask.any(axis=1)).any() and (mask[:, 0] != mask[:, 1]).any()
    assert (np.diff(times) > 2 * PERIOD_US * 1e-6).any()
    assert seq.mask.tolist() == mask.tolist()
    np.testing.assert_array_equal(seq.times, times)
    assert seq.positions.dtype == np.float32
    np.testing.assert_array_equal(seq.positions, positions)  # bit for bit


# ---- errors: the first problem of the file, as a frame-at-a-time reader finds it -------------------
def line_by_line_read(path, matrix, radar_start_us):
    """read_leap_jsonl one frame at a time (parse_leap_frame converts and checks each frame's numbers)."""
    m = leap.leap_matrix(matrix, path)
    stamps, frames, masks = [], [], []
    with path.open("rb") as fh:
        for lineno, raw in enumerate(fh, start=1):
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError:
                raise FormatError(path, "not UTF-8 text", line=lineno) from None
            if not line.strip():
                continue
            try:
                obj = json.loads(line)
            except json.JSONDecodeError as exc:
                raise FormatError(path, f"invalid JSON ({exc.msg} at column {exc.colno})", line=lineno) from None
            except ValueError as exc:
                raise FormatError(path, f"invalid JSON ({exc})", line=lineno) from None
            ts, joints, tracked = parse_leap_frame(obj, path, lineno)
            if stamps and ts <= stamps[-1]:
                raise FormatError(path, f"timestamps must increase: {ts:.0f} us follows {stamps[-1]:.0f} us",
                                  line=lineno)
            stamps.append(ts)
            frames.append(joints)
            masks.append(tracked)
    if len(stamps) < 2:
        raise FormatError(path, f"expected at least 2 frames, found {len(stamps)}")
    radar = np.stack(frames) @ m[:3, :3].T + m[:3, 3]
    mask = np.stack(masks)
    too_big = ~(np.abs(radar) < 1e6).all(axis=(-2, -1)) & mask
    if too_big.any():
        t = int(np.argmax(too_big.any(axis=1)))
        raise FormatError(path, f"joint coordinates of frame {t + 1} are {np.abs(radar[t]).max():.3g} m from the "
                                "radar after leap_to_radar; expected a hand within metres")
    return radar.astype(np.float32), (np.asarray(stamps) - float(radar_start_us)) * 1e-6, mask


def _outcome(reader, path):
    try:
        out = reader(path, LEAP_TO_RADAR, RADAR_START_US)
    except FormatError as exc:
        return "error", str(exc), exc.line
    if isinstance(out, tuple):
        positions, times, mask = out
        positions = np.where(mask[..., None, None], positions, 0).astype(np.float32)
    else:
        positions, times, mask = out.positions, out.times, out.mask
    return "ok", positions.tobytes(), times.tobytes(), mask.tobytes()


def _frames(n: int) -> list[dict]:
    out = []
    for i in range(n):
        f = frame_3() if i % 2 else json.loads(FRAME_1)
        f["timestamp"] = 1_000_000 + 10_000 * i
        out.append(f)
    return out


def _set(frame: dict, pointable: int, field: str, value) -> dict:
    frame = copy.deepcopy(frame)
    frame["pointables"][pointable][field] = value
    return frame


@pytest.mark.parametrize(("case", "line", "fragment"), [
    # a bad number on line 1 comes before invalid JSON on line 2
    ("number then bad json", 1, "right finger 2 pipPosition: expected three finite numbers"),
    # the right hand's numbers are checked before the left hand's missing finger on the same line
    ("right number, left finger missing", 2, "right finger 0 btipPosition: expected three finite numbers"),
    # a bad number on a line comes before its out-of-order timestamp
    ("number and timestamp", 2, "right finger 1 dipPosition: expected three finite numbers"),
    # a single-frame file with a bad number: the number, not the frame count
    ("one frame, bad number", 1, "right hand wrist: expected three finite numbers"),
    # a bad number far into the file, after several conversion batches
    ("late number", 6, "left finger 4 mcpPosition: expected three finite numbers"),
    # a structural error after clean batches
    ("late structure", 8, "finger 3 has no 'pipPosition'"),
])
def test_first_problem_of_the_file_is_reported(tmp_path, monkeypatch, case, line, fragment):
    monkeypatch.setattr(leap, "_BATCH_HANDS", 3)
    frames = _frames(9)
    if case == "number then bad json":
        frames[0] = _set(frames[0], 2, "pipPosition", [float("nan"), 1, 2])
        lines = [json.dumps(frames[0]), "{not json"]
    else:
        if case == "right number, left finger missing":
            frames[1] = _set(frames[1], 0, "btipPosition", [1, True, 2])
            frames[1]["pointables"] = [p for p in frames[1]["pointables"] if not (p["handId"] == 9 and p["type"] == 3)]
        elif case == "number and timestamp":
            frames[1] = _set(frames[1], 1, "dipPosition", ["1.5", 2, 3])
            frames[1]["timestamp"] = frames[0]["timestamp"]
        elif case == "one frame, bad number":
            frames = [copy.deepcopy(frames[0])]
            frames[0]["hands"][0]["wrist"] = [1, 2, None]
        elif case == "late number":
            frames[5] = _set(frames[5], 9, "mcpPosition", [1, 2, 10**400])  # pointable 9: the left pinky
        else:
            del frames[7]["pointables"][3]["pipPosition"]
            frames[8] = _set(frames[8], 0, "pipPosition", [0, 0, float("inf")])  # later: not the one reported
        lines = [json.dumps(f) for f in frames]
    path = tmp_path / "leap.jsonl"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(FormatError) as info:
        read_leap_jsonl(path, LEAP_TO_RADAR, RADAR_START_US)
    assert info.value.line == line and fragment in str(info.value) and str(info.value).startswith(str(path))
    assert _outcome(read_leap_jsonl, path) == _outcome(line_by_line_read, path)


@settings(max_examples=300, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.data())
def test_fuzz_fast_reader_agrees_with_frame_at_a_time_reader(tmp_path, data):
    """Mutated files: the same error (message and line) or bit-identical sequences."""
    frames = _frames(data.draw(st.integers(1, 5)))
    for _ in range(data.draw(st.integers(0, 3))):
        k = data.draw(st.integers(0, len(frames) - 1))
        p = data.draw(st.sampled_from([p for p in _paths(frames[k]) if p]))
        parent = frames[k]
        try:
            for key in p[:-1]:
                parent = parent[key]
            choice = data.draw(st.integers(0, 2))
            if choice == 0:
                parent[p[-1]] = data.draw(_JSON_VALUES)
            elif choice == 1:
                parent[p[-1]] = data.draw(st.sampled_from([True, None, "1.5", 0, 1, [1, 2, 3], [True, 0, 0], ["1", 2, 3],
                                                           [1, 2], [[1], 2, 3], 10**400, 1e308 * 10]))
            elif isinstance(parent, dict):
                del parent[p[-1]]
        except (KeyError, IndexError, TypeError):
            pass  # an earlier mutation removed the path
    lines = [json.dumps(f) for f in frames]
    if data.draw(st.booleans()):
        lines.insert(data.draw(st.integers(0, len(lines))), data.draw(st.sampled_from(["", " ", "{bad", "[]", "7"])))
    path = tmp_path / "fuzz.jsonl"
    path.write_bytes("\n".join(lines).encode("utf-8", errors="surrogatepass"))
    batch = data.draw(st.sampled_from([1, 2, 3, 2048]))
    old, leap._BATCH_HANDS = leap._BATCH_HANDS, batch
    try:
        assert _outcome(read_leap_jsonl, path) == _outcome(line_by_line_read, path)
    finally:
        leap._BATCH_HANDS = old
