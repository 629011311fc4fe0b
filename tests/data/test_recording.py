"""Recording folders: loading, meta.json validation, Leap coverage, fuzzing of meta.json."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from handradar.data.recording import (
    GESTURES,
    RecordingMeta,
    check_folder,
    load_recording,
    parse_meta,
    read_meta,
    read_truth,
    write_meta,
)
from handradar.errors import FormatError
from tests.data.writer import (
    ADC_START_S,
    F0_HZ,
    LEAP_TO_RADAR,
    SLOPE_HZ_S,
    C,
    Scene,
    chirp_times,
    write_recording,
)

META = {"format": "handradar.recording/1", "gesture": "grasp", "subject": "s01", "angle_deg": 30, "hands": 1,
        "occlusion": True, "repetition": 2, "radar_start_us": 1200000, "leap_to_radar": LEAP_TO_RADAR}


def test_load_recording(tmp_path):
    scene = Scene(gesture="finger_wave", subject="s03", angle_deg=-30, repetition=5, extra_meta={"truth": {"a": 1}})
    rec = load_recording(write_recording(tmp_path / "r", scene))
    assert rec.adc.shape == (24, 128, 1, 256) and rec.n_frames == 24 and rec.duration_s == pytest.approx(2.4)
    assert rec.meta.label == GESTURES.index("finger_wave")
    assert rec.meta.labels() == {"gesture": "finger_wave", "subject": "s03", "angle_deg": -30.0, "hands": 1,
                                 "occlusion": False, "repetition": 5}
    # skeleton on the radar clock: t = 0 is radar frame 0
    np.testing.assert_allclose(rec.skeleton.times[[0, -1]], [-0.1, 2.49], atol=1e-9)
    np.testing.assert_allclose(rec.skeleton.positions[:, 0], scene.joints(rec.skeleton.times), atol=2e-6)
    # the first sample of each chirp is S_TX conj(S_RX) at t_adc: A exp(+j 2 pi (tau (f0 + S t_adc) - S tau^2 / 2)),
    # tau = 2 R / c, R the hand centre's range then
    tau = 2 * np.linalg.norm(scene.centre(chirp_times(24)), axis=-1) / C
    first = 3000 * np.exp(2j * np.pi * (tau * (F0_HZ + SLOPE_HZ_S * ADC_START_S) - SLOPE_HZ_S * tau ** 2 / 2))
    np.testing.assert_allclose(rec.adc[..., 0, 0], first, atol=1.0)
    assert not hasattr(rec.meta, "truth") and read_truth(rec.folder) == {"a": 1}


def test_meta_round_trip(tmp_path):
    meta = parse_meta(META, "m.json")
    write_meta(tmp_path, meta, truth={"noise": {"snr_db": 20}})
    assert read_meta(tmp_path) == meta
    assert read_truth(tmp_path) == {"noise": {"snr_db": 20}}
    assert isinstance(meta, RecordingMeta) and meta.subject == "s01" and meta.angle_deg == 30.0


@pytest.mark.parametrize(("change", "fragment"), [
    ({"format": "handradar.recording/2"}, "'format' must be 'handradar.recording/1'"),
    ({"gesture": "wave"}, "unknown gesture 'wave'; expected one of grasp"),
    ({"gesture": None}, "missing required field 'gesture'"),
    ({"subject": None}, "missing required field 'subject'"),
    ({"subject": ""}, "non-empty subject"),
    ({"angle_deg": "30"}, "field 'angle_deg' must be degrees, found '30'"),
    ({"angle_deg": 10**400}, "field 'angle_deg' must be a finite number"),
    ({"angle_deg": float("inf")}, "must be a finite number"),
    ({"hands": 3}, "field 'hands' must be 1 or 2, found 3"),
    ({"hands": True}, "field 'hands' must be 1 or 2, found True"),
    ({"occlusion": 1}, "field 'occlusion' must be true or false, found 1"),
    ({"repetition": 2.5}, "field 'repetition' must be an integer"),
    ({"repetition": 10**30}, "'repetition' is out of range"),
    ({"radar_start_us": None}, "missing required field 'radar_start_us'"),
    ({"leap_to_radar": None}, "missing required field 'leap_to_radar'"),
    ({"leap_to_radar": [[1, 0, 0, 0]] * 4}, "last row must be [0, 0, 0, 1]"),
    ({"leap_to_radar": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "4x4"),
])
def test_meta_errors(tmp_path, change, fragment):
    obj = {**META, **change}
    obj = {k: v for k, v in obj.items() if v is not None}
    path = tmp_path / "meta.json"
    path.write_text(json.dumps(obj))
    with pytest.raises(FormatError) as info:
        read_meta(tmp_path)
    assert str(info.value).startswith(str(path)) and fragment in str(info.value), str(info.value)


def test_meta_file_errors(tmp_path):
    path = tmp_path / "meta.json"
    path.write_text("{")
    with pytest.raises(FormatError, match="invalid JSON"):
        read_meta(tmp_path)
    path.write_bytes(b"\xff{}")
    with pytest.raises(FormatError, match="not UTF-8"):
        read_meta(tmp_path)
    path.write_text("[" * 100000)
    with pytest.raises(FormatError, match="meta.json"):
        read_meta(tmp_path)
    path.write_text('{"repetition": ' + "9" * 5000 + "}")
    with pytest.raises(FormatError, match="invalid JSON"):
        read_meta(tmp_path)
    path.write_text("[]")
    with pytest.raises(FormatError, match="expected a JSON object, found list"):
        read_meta(tmp_path)


def test_missing_files(tmp_path):
    with pytest.raises(FormatError, match="no such directory"):
        check_folder(tmp_path / "nope")
    rec = write_recording(tmp_path / "r", Scene())
    (rec / "leap.jsonl").unlink()
    with pytest.raises(FormatError, match="missing file.s. leap.jsonl"):
        load_recording(rec)


def test_leap_must_cover_the_capture(tmp_path):
    late = write_recording(tmp_path / "late", Scene(leap_span_s=(0.2, 2.5)))
    with pytest.raises(FormatError, match=r"late/leap.jsonl: Leap data cover 0.200..2.490 s .* spans 0..2.400 s"):
        load_recording(late)
    early = write_recording(tmp_path / "early", Scene(leap_span_s=(-0.1, 2.2)))
    with pytest.raises(FormatError, match="check radar_start_us"):
        load_recording(early)
    # within the tolerance: accepted
    load_recording(write_recording(tmp_path / "ok", Scene(leap_span_s=(0.04, 2.37))))


def test_announced_hands_must_be_tracked(tmp_path):
    rec = write_recording(tmp_path / "r", Scene())
    meta = json.loads((rec / "meta.json").read_text())
    meta["hands"] = 2
    (rec / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(FormatError, match="meta.json says 2 hand.s. but 1 are tracked"):
        load_recording(rec)


def test_truncated_capture_needs_permission(tmp_path):
    rec = write_recording(tmp_path / "r", Scene())
    data = (rec / "adc_data.bin").read_bytes()
    (rec / "adc_data.bin").write_bytes(data[:-8])
    with pytest.raises(FormatError, match="adc_data.bin: size"):
        load_recording(rec)
    with pytest.warns(UserWarning, match="last frame truncated"):
        assert load_recording(rec, allow_truncated=True).n_frames == 23


TEMPLATE_HAND_LENGTH_M = 0.1911  # the writer's hand, wrist to middle fingertip (tests/hand/template.py)


def _scaled_matrix(scale: float, translation_m=(0.01, -0.02, 0.05)) -> list[list[float]]:
    """The writer's leap_to_radar with its 3x3 part times ``scale`` and another translation."""
    m = np.array(LEAP_TO_RADAR)
    m[:3, :3] *= scale
    m[:3, 3] = translation_m
    return m.tolist()


@pytest.mark.parametrize(("scene", "length_mm", "slip"), [
    # Leap coordinates in metres read as millimetres: the hand comes out 1000 times too small
    (Scene(leap_scale=1e-3), TEMPLATE_HAND_LENGTH_M, "Leap coordinates are in metres instead of millimetres"),
    (Scene(leap_scale=0.1), TEMPLATE_HAND_LENGTH_M * 100, "in centimetres instead of millimetres"),
    # millimetres, but a leap_to_radar that keeps millimetres: 1000 times too large
    (Scene(extra_meta={"leap_to_radar": _scaled_matrix(1000.0)}), TEMPLATE_HAND_LENGTH_M * 1e6,
     "leap_to_radar in meta.json keeps millimetres"),
])
def test_leap_units_must_give_a_hand_sized_hand(tmp_path, scene, length_mm, slip):
    rec = write_recording(tmp_path / "r", scene)
    with pytest.raises(FormatError) as info:
        load_recording(rec)
    msg = str(info.value)
    assert msg.startswith(f"{rec / 'leap.jsonl'}: after leap_to_radar the hands measure ")
    value, unit = re.search(r"measure ([\d.e+]+) (mm|cm|m) from the wrist", msg).groups()
    assert float(value) * {"mm": 1.0, "cm": 10.0, "m": 1e3}[unit] == pytest.approx(length_mm, rel=0.01)
    assert "(median of 260 tracked hand frames); expected 3 cm to 30 cm" in msg and slip in msg


def test_hands_must_be_near_the_radar(tmp_path):
    rec = write_recording(tmp_path / "r", Scene(extra_meta={"leap_to_radar": _scaled_matrix(1.0, (0.01, -0.02, 10.0))}))
    with pytest.raises(FormatError, match=r"leap.jsonl: after leap_to_radar the hands are 10.\d m from the radar "
                                          r"\(median of 260 tracked hand frames\); expected within 3 m"):
        load_recording(rec)


def test_plausible_hands_pass_the_geometry_check(tmp_path):
    # leap_to_radar scaled by 0.3 / 1.45: a 5.7 cm hand near the radar, a 27.7 cm hand about 2.5 m away
    for scale, z_m in ((0.3, 0.05), (1.45, 1.8)):
        rec = write_recording(tmp_path / f"s{scale}", Scene(extra_meta={
            "leap_to_radar": _scaled_matrix(scale, (0.01, -0.02, z_m))}))
        pos = load_recording(rec).skeleton.positions[0, 0]
        assert np.linalg.norm(pos - pos[0], axis=-1).max() == pytest.approx(TEMPLATE_HAND_LENGTH_M * scale, rel=1e-3)
        assert np.linalg.norm(pos.mean(axis=0)) < 3.0


def test_continuous_framing_is_a_radar_cfg_error(tmp_path):
    """numFrames 0 lets adc_data.bin decide the capture length; a longer capture then looked like a
    Leap file too short. radar.cfg is checked first and named."""
    rec = write_recording(tmp_path / "r", Scene())
    (rec / "radar.cfg").write_text((rec / "radar.cfg").read_text().replace("frameCfg 0 0 128 24 ", "frameCfg 0 0 128 0 "))
    (rec / "adc_data.bin").write_bytes((rec / "adc_data.bin").read_bytes() * 2)  # 48 frames, Leap covers 24
    with pytest.raises(FormatError, match=r"r/radar.cfg: frameCfg numFrames is 0 \(continuous framing\); a recording's "
                                          r"radar.cfg must give the number of frames captured \(expected >= 1\)"):
        load_recording(rec)


_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10**25, 10**25), st.just(10**400),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                    st.sampled_from(GESTURES), st.lists(st.integers(0, 2), max_size=4),
                    st.lists(st.lists(st.one_of(st.integers(-2, 2), st.floats(), st.text(max_size=2)),
                                      min_size=3, max_size=5), min_size=3, max_size=5))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(st.sampled_from([*META, "truth", "extra"]), _VALUES, max_size=4),
       st.sets(st.sampled_from(list(META)), max_size=3))
def test_fuzz_meta_parser_only_raises_format_error(changes, removed):
    obj = {k: v for k, v in {**META, **changes}.items() if k not in removed}
    try:
        meta = parse_meta(json.loads(json.dumps(obj)), "fuzz/meta.json")
    except FormatError as exc:
        assert str(exc).startswith("fuzz/meta.json")
        return
    except ValueError as exc:  # json.dumps refuses nothing here, but keep the test honest
        pytest.fail(f"non-FormatError {exc!r}")
    assert meta.gesture in GESTURES and meta.hands in (1, 2) and np.isfinite(meta.angle_deg)
    assert np.isfinite(np.asarray(meta.leap_to_radar)).all()
