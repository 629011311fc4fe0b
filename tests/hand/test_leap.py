"""leap.jsonl: a hand-written file with known numbers, bad input, writer round trip, fuzzing."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from handradar.errors import FormatError
from handradar.hand.leap import (
    leap_frames_from_sequence,
    read_leap_jsonl,
    write_leap_jsonl,
)
from handradar.hand.skeleton import HandSequence

# Leap mm -> radar m: radar x = Leap x, radar y = -Leap z, radar z = Leap y (Leap's up is boresight),
# scaled by 1e-3, then shifted by (0.01, -0.02, 0.05) m.
LEAP_TO_RADAR = [[0.001, 0.0, 0.0, 0.01],
                 [0.0, 0.0, -0.001, -0.02],
                 [0.0, 0.001, 0.0, 0.05],
                 [0.0, 0.0, 0.0, 1.0]]
RADAR_START_US = 1_005_000

FRAME_1 = """{"id": 100, "timestamp": 1000000, "currentFrameRate": 90.9,
 "hands": [{"id": 7, "type": "right", "palmPosition": [5, 212, -70], "palmNormal": [0, -1, 0],
            "direction": [0, 0, -1], "palmWidth": 80.0, "wrist": [10, 200, -30], "elbow": [10, 150, 220]}],
 "pointables": [
  {"handId": 7, "type": 0, "width": 19, "carpPosition": [30, 205, -35], "mcpPosition": [30, 205, -35],
   "pipPosition": [45, 215, -50], "dipPosition": [55, 222, -62], "btipPosition": [62, 228, -72]},
  {"handId": 7, "type": 1, "width": 18, "carpPosition": [20, 210, -40], "mcpPosition": [25, 215, -100],
   "pipPosition": [27, 218, -140], "dipPosition": [28, 219, -165], "btipPosition": [29, 220, -185]},
  {"handId": 7, "type": 2, "width": 18, "carpPosition": [5, 210, -40], "mcpPosition": [5, 216, -105],
   "pipPosition": [5, 219, -150], "dipPosition": [5, 220, -178], "btipPosition": [5, 221, -200]},
  {"handId": 7, "type": 3, "width": 17, "carpPosition": [-10, 210, -40], "mcpPosition": [-15, 214, -100],
   "pipPosition": [-17, 217, -142], "dipPosition": [-18, 218, -168], "btipPosition": [-19, 219, -188]},
  {"handId": 7, "type": 4, "width": 16, "carpPosition": [-25, 208, -38], "mcpPosition": [-33, 212, -90],
   "pipPosition": [-36, 214, -123], "dipPosition": [-38, 215, -143], "btipPosition": [-39, 216, -160]}]}"""
FRAME_2 = '{"id": 101, "timestamp": 1011000, "currentFrameRate": 90.9, "hands": [], "pointables": []}'

# canonical joint order: wrist; thumb mcp(=CMC) pip(=MCP) dip(=IP) btip; then mcp pip dip btip per finger
LEAP_MM = np.array([
    [10, 200, -30],
    [30, 205, -35], [45, 215, -50], [55, 222, -62], [62, 228, -72],
    [25, 215, -100], [27, 218, -140], [28, 219, -165], [29, 220, -185],
    [5, 216, -105], [5, 219, -150], [5, 220, -178], [5, 221, -200],
    [-15, 214, -100], [-17, 217, -142], [-18, 218, -168], [-19, 219, -188],
    [-33, 212, -90], [-36, 214, -123], [-38, 215, -143], [-39, 216, -160],
], dtype=float)


def frame_3() -> dict:
    """Frame 1 a little later, the right hand 10 mm further along Leap x, plus a left hand (x mirrored)."""
    f = json.loads(FRAME_1)
    f["id"], f["timestamp"] = 102, 1022000
    for obj in [*f["hands"], *f["pointables"]]:
        for k, v in obj.items():
            if k.endswith("Position") or k in ("wrist", "elbow"):
                v[0] += 10
    left = copy.deepcopy(f["hands"][0])
    left.update(id=9, type="left", wrist=[-left["wrist"][0], *left["wrist"][1:]])
    f["hands"].append(left)
    for p in list(f["pointables"]):
        q = copy.deepcopy(p)
        q["handId"] = 9
        for k in ("carpPosition", "mcpPosition", "pipPosition", "dipPosition", "btipPosition"):
            q[k][0] = -q[k][0]
        f["pointables"].append(q)
    return f


def write(tmp_path, lines: list[str], name: str = "leap.jsonl"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def test_reproduces_hand_written_joints(tmp_path):
    path = write(tmp_path, [FRAME_1.replace("\n", ""), FRAME_2, json.dumps(frame_3())])
    seq = read_leap_jsonl(path, LEAP_TO_RADAR, RADAR_START_US)
    np.testing.assert_allclose(seq.times, [-0.005, 0.006, 0.017], atol=1e-12)
    assert seq.mask.tolist() == [[True, False], [False, False], [True, True]]
    right = seq.positions[0, 0]
    # worked by hand: wrist [10, 200, -30] mm -> (0.010 + 0.01, 0.030 - 0.02, 0.200 + 0.05) m
    np.testing.assert_allclose(right[0], [0.020, 0.010, 0.250], atol=1e-6)
    np.testing.assert_allclose(right[1], [0.040, 0.015, 0.255], atol=1e-6)  # thumb CMC from mcpPosition
    np.testing.assert_allclose(right[4], [0.072, 0.052, 0.278], atol=1e-6)  # thumb tip
    np.testing.assert_allclose(right[8], [0.039, 0.165, 0.270], atol=1e-6)  # index tip
    np.testing.assert_allclose(right[17], [-0.023, 0.070, 0.262], atol=1e-6)  # pinky MCP, not carpPosition
    # every joint: the same affine map, applied independently here
    expected = np.stack([(0.001 * x + 0.01, -0.001 * z - 0.02, 0.001 * y + 0.05) for x, y, z in LEAP_MM])
    np.testing.assert_allclose(seq.positions[0, 0], expected, atol=1e-6)
    np.testing.assert_allclose(seq.positions[2, 0], expected + [0.010, 0, 0], atol=1e-6)
    mirrored = np.stack([(-0.001 * (x + 10) + 0.01, -0.001 * z - 0.02, 0.001 * y + 0.05) for x, y, z in LEAP_MM])
    np.testing.assert_allclose(seq.positions[2, 1], mirrored, atol=1e-6)
    assert not seq.positions[1].any()  # no hands: zeros, untracked
    # bone lengths survive the scale: index proximal |[27,218,-140] - [25,215,-100]| mm
    assert seq.bone_lengths()[0, 0, 4] == pytest.approx(np.linalg.norm([2, 3, -40]) * 1e-3, rel=1e-5)


def test_writer_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    pos = rng.uniform(-0.1, 0.4, size=(5, 2, 21, 3)).astype(np.float32)
    mask = np.array([[1, 0], [1, 1], [0, 0], [0, 1], [1, 1]], dtype=bool)
    seq = HandSequence(pos, np.arange(5) * 0.01 - 0.02, mask)
    m = np.array(LEAP_TO_RADAR)
    write_leap_jsonl(tmp_path / "leap.jsonl", leap_frames_from_sequence(seq, np.linalg.inv(m), RADAR_START_US))
    back = read_leap_jsonl(tmp_path / "leap.jsonl", m, RADAR_START_US)
    assert (back.mask == mask).all()
    np.testing.assert_allclose(back.positions, seq.positions, atol=2e-6)  # mm rounded to 1e-3
    np.testing.assert_allclose(back.times, seq.times, atol=1e-6)


# ---- bad input -------------------------------------------------------------------------------------
def _expect(tmp_path, lines, *fragments, line=None):
    path = write(tmp_path, lines)
    with pytest.raises(FormatError) as info:
        read_leap_jsonl(path, LEAP_TO_RADAR, RADAR_START_US)
    msg = str(info.value)
    assert msg.startswith(str(path)), msg
    for frag in fragments:
        assert frag in msg, msg
    if line is not None:
        assert info.value.line == line
    return msg


def _frame(**changes) -> dict:
    f = json.loads(FRAME_1)
    f.update(changes)
    return f


def test_non_increasing_timestamps(tmp_path):
    _expect(tmp_path, [FRAME_1.replace("\n", ""), json.dumps(_frame(timestamp=1000000))],
            "timestamps must increase: 1000000 us follows 1000000 us", line=2)
    _expect(tmp_path, [FRAME_1.replace("\n", ""), json.dumps(_frame(timestamp=999000))], "999000 us follows", line=2)


def test_nan_and_missing_joints(tmp_path):
    f = _frame()
    f["pointables"][2]["pipPosition"] = [float("nan"), 1, 2]
    _expect(tmp_path, [json.dumps(f)], "right finger 2 pipPosition", "three finite numbers", line=1)
    f = _frame()
    del f["pointables"][3]["dipPosition"]
    _expect(tmp_path, [json.dumps(f)], "finger 3 has no 'dipPosition'")
    f = _frame()
    del f["pointables"][4]
    _expect(tmp_path, [json.dumps(f)], "finger(s) [4] have no pointable")
    f = _frame()
    f["hands"][0]["wrist"] = [1, 2]
    _expect(tmp_path, [json.dumps(f)], "right hand wrist", "expected [x, y, z]")
    f = _frame()
    del f["hands"][0]["wrist"]
    _expect(tmp_path, [json.dumps(f)], "has no 'wrist'")


def test_malformed_lines(tmp_path):
    _expect(tmp_path, [FRAME_2, "{not json"], "invalid JSON", line=2)
    _expect(tmp_path, ["[1, 2]"], "expected a JSON object per line, found list")
    _expect(tmp_path, [json.dumps(_frame(timestamp="soon"))], "'timestamp' must be a finite number")
    _expect(tmp_path, [json.dumps(_frame(timestamp=10**400))], "'timestamp' must be a finite number")
    f = _frame()
    f["hands"][0]["type"] = "middle"
    _expect(tmp_path, [json.dumps(f)], "hand 'type' must be 'right' or 'left'")
    f = _frame()
    f["hands"][0]["id"] = [7]
    _expect(tmp_path, [json.dumps(f)], "hand 'id' must be an integer id")
    f = _frame()
    f["pointables"][0]["handId"] = {"a": 1}
    _expect(tmp_path, [json.dumps(f)], "pointable 'handId' must be an integer id")
    f = _frame()
    f["pointables"][1]["type"] = 0
    _expect(tmp_path, [json.dumps(f)], "two pointables of type 0")
    _expect(tmp_path, [FRAME_2], "expected at least 2 frames, found 1")
    _expect(tmp_path, [FRAME_2.replace("1011000", "1" * 5000)], "invalid JSON", "4300", line=1)
    _expect(tmp_path, [FRAME_2, json.dumps(_frame(timestamp=2000000)).replace("[29, 220, -185]", "[1e300, 0, 0]")],
            "frame 2 are 1e+297 m from the radar", "expected a hand within metres")
    path = tmp_path / "leap.jsonl"
    path.write_bytes(FRAME_2.encode() + b"\n\xff\xfe\n")
    with pytest.raises(FormatError, match=r"leap.jsonl:2: not UTF-8"):
        read_leap_jsonl(path, LEAP_TO_RADAR, RADAR_START_US)
    path.write_text(FRAME_2 + "\n" + "[" * 100000 + "\n")
    with pytest.raises(FormatError, match=r"leap.jsonl:2"):
        read_leap_jsonl(path, LEAP_TO_RADAR, RADAR_START_US)
    with pytest.raises(FormatError, match="cannot read"):
        read_leap_jsonl(tmp_path / "none.jsonl", LEAP_TO_RADAR, RADAR_START_US)


@pytest.mark.parametrize(("matrix", "fragment"), [
    ([[1, 0, 0, 0]] * 4, "last row must be [0, 0, 0, 1]"),
    ([[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]], "singular"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], "4x4"),
    ([[1, 0, 0, "0"], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "16 finite numbers"),
    ([[1, 0, 0, 10**400], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "16 finite numbers"),
])
def test_bad_calibration_matrix(tmp_path, matrix, fragment):
    path = write(tmp_path, [FRAME_2, FRAME_2.replace("1011000", "1012000")])
    with pytest.raises(FormatError, match="leap_to_radar") as info:
        read_leap_jsonl(path, matrix, 0)
    assert fragment in str(info.value)


# ---- fuzzing -----------------------------------------------------------------------------------------
_JSON_VALUES = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-10**30, 10**30), st.floats(allow_nan=True, allow_infinity=True),
              st.text(max_size=5), st.just(10**400)),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=4), children, max_size=3),
    max_leaves=8,
)


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, (*prefix, i))


@settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.data())
def test_fuzz_leap_reader_only_raises_format_error(tmp_path, data):
    frames = [json.loads(FRAME_1), frame_3()]
    k = data.draw(st.integers(0, 1))
    paths = [p for p in _paths(frames[k]) if p]
    for _ in range(data.draw(st.integers(1, 3))):
        p = data.draw(st.sampled_from(paths))
        parent = frames[k]
        try:
            for key in p[:-1]:
                parent = parent[key]
            if data.draw(st.booleans()):
                parent[p[-1]] = data.draw(_JSON_VALUES)
            elif isinstance(parent, dict):
                del parent[p[-1]]
        except (KeyError, IndexError, TypeError):
            pass  # an earlier mutation removed the path
    lines = [json.dumps(f) for f in frames]
    if data.draw(st.booleans()):
        lines.insert(data.draw(st.integers(0, 2)), data.draw(st.text(max_size=30)))
    path = tmp_path / "fuzz.jsonl"
    path.write_bytes("\n".join(lines).encode("utf-8", errors="surrogatepass"))  # lone surrogates included
    try:
        seq = read_leap_jsonl(path, LEAP_TO_RADAR, RADAR_START_US)
    except FormatError as exc:
        assert str(exc).startswith(str(path))
        return
    assert np.all(np.isfinite(seq.positions)) and seq.n_steps >= 2
