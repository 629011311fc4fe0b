"""The quality gate (handradar.data.quality): each check on recordings written to fail it, from two
sources (the independent writer of tests/data/writer.py and the reference world), clean recordings
untouched, the issue's probe cases each with a named one-line answer, and the measures' closed forms."""

from __future__ import annotations

import json
import math
import re
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from handradar.data.examples import recording_example
from handradar.data.hdf5 import open_writer, read_meta_group, read_quality_group, validate
from handradar.data.ingest import ingest
from handradar.data.quality import (
    MAX_INTERP_GAP_S,
    RecordingQuality,
    _jump_outliers,
    adc_figures,
    adc_findings,
    drop_outliers,
    long_gap_steps,
    longest_gap_s,
    view_outside,
)
from handradar.data.recording import load_recording, read_radar
from handradar.errors import FormatError
from handradar.hand.skeleton import HandSequence
from handradar.radar.chain import ChainConfig
from handradar.vocab import GESTURES
from handradar.world.config import WorldConfig
from handradar.world.generate import RecordingSpec
from handradar.world.generate import write_recording as write_world_recording
from tests.data.writer import Scene, write_recording

CHAIN = ChainConfig()
HAND_KEYS = ("wrist", "palmPosition", "elbow")
POINTABLE_KEYS = ("carpPosition", "mcpPosition", "pipPosition", "dipPosition", "btipPosition")


# ---- two sources of clean recordings, copied for each test ------------------------------------
@pytest.fixture(scope="module")
def sources(tmp_path_factory, radar) -> dict[str, Path]:
    """One clean recording per source: the independent writer's (24 frames, 100 Hz Leap, one right
    hand on boresight) and a reference world's (17 frames, 115 Hz Leap with dropouts, jitter, a sync
    offset and a calibration error)."""
    base = tmp_path_factory.mktemp("sources")
    world = WorldConfig(capture_frames=17, subjects=1, repetitions=1, angles_deg=(0.0,), workers=1)
    return {"writer": write_recording(base / "writer", Scene()),
            "world": write_world_recording(world, radar, RecordingSpec("circle", 0, 0.0, 0), base / "world")}


def copy_of(src: Path, dest: Path) -> Path:
    shutil.copytree(src, dest)
    return dest


def distinct_copy(src: Path, dest: Path) -> Path:
    """A clean copy that is no duplicate: every 7th ADC value one count up, the hands 1 mm to the side."""
    copy_of(src, dest)
    data = np.frombuffer((dest / "adc_data.bin").read_bytes(), "<i2").copy()
    data[::7] += 1
    (dest / "adc_data.bin").write_bytes(data.tobytes())
    write_frames(dest, [move_hand(f, 1.0, (1, 0, 0)) if f["hands"] else f for f in frames(dest)])
    return dest


def frames(folder: Path) -> list[dict]:
    return [json.loads(line) for line in (folder / "leap.jsonl").read_text().splitlines() if line.strip()]


def write_frames(folder: Path, fr: list[dict]) -> None:
    (folder / "leap.jsonl").write_text("".join(json.dumps(f) + "\n" for f in fr))


def radar_times(folder: Path, fr: list[dict]) -> np.ndarray:
    start = json.loads((folder / "meta.json").read_text())["radar_start_us"]
    return (np.array([f["timestamp"] for f in fr], dtype=np.float64) - start) * 1e-6


def capture_s(folder: Path) -> float:
    radar = read_radar(folder)
    return radar.n_frames * radar.frame_period_s


def edit_meta(folder: Path, **changes) -> None:
    meta = json.loads((folder / "meta.json").read_text())
    meta.update(changes)
    (folder / "meta.json").write_text(json.dumps(meta))


def move_hand(frame: dict, scale: float = 1.0, shift_mm: tuple[float, float, float] = (0, 0, 0), *,
              hand_id: object = None, kind: str | None = None) -> dict:
    """A copy of ``frame`` whose hands (or, with ``hand_id``, a new copy of its first hand) are scaled
    and shifted in Leap millimetres."""
    frame = json.loads(json.dumps(frame))

    def move(v):
        return [scale * x + d for x, d in zip(v, shift_mm)]

    hands = frame["hands"]
    if hand_id is not None:  # a new hand: a copy of the first, under another id (and side)
        h = {**hands[0], "id": hand_id, "type": kind or hands[0]["type"]}
        ps = [{**p, "handId": hand_id} for p in frame["pointables"] if p["handId"] == hands[0]["id"]]
        for k in HAND_KEYS:
            h[k] = move(h[k])
        for p in ps:
            for k in POINTABLE_KEYS:
                p[k] = move(p[k])
        frame["hands"].append(h)
        frame["pointables"].extend(ps)
        return frame
    for h in hands:
        for k in HAND_KEYS:
            h[k] = move(h[k])
    for p in frame["pointables"]:
        for k in POINTABLE_KEYS:
            p[k] = move(p[k])
    return frame


def run(root: Path, tmp_path: Path, **kw):
    out = tmp_path / "out" / "d.h5"
    return ingest(root, out, CHAIN, progress=False, **kw), out


def reason(summary, name: str) -> str:
    return dict(summary.skipped)[name]


def messages(summary, name: str) -> list[str]:
    return [f"{x.level}: {x.message}" for x in summary.quality.rows[name].findings]


# ---- the probe cases: each a named one-line answer --------------------------------------
def zero_adc(folder: Path) -> None:
    n = (folder / "adc_data.bin").stat().st_size
    (folder / "adc_data.bin").write_bytes(bytes(n))


def rail_adc(folder: Path) -> None:
    n = (folder / "adc_data.bin").stat().st_size // 2
    (folder / "adc_data.bin").write_bytes(np.full(n, 32767, "<i2").tobytes())


def scale_40_percent(folder: Path) -> None:
    fr = frames(folder)
    rng = np.random.default_rng(0)
    picked = set(rng.choice(len(fr), int(0.4 * len(fr)), replace=False).tolist())
    write_frames(folder, [move_hand(f, 1000.0) if i in picked and f["hands"] else f for i, f in enumerate(fr)])


def hole_1s(folder: Path) -> None:
    fr = frames(folder)
    t = radar_times(folder, fr)
    mid = capture_s(folder) / 2  # inside the spectrogram window for both sources
    write_frames(folder, [f for f, ti in zip(fr, t) if not mid - 0.5 <= ti < mid + 0.5])


def every_40th(folder: Path) -> None:
    fr = frames(folder)
    write_frames(folder, [f for i, f in enumerate(fr) if i % 40 == 0 or i == len(fr) - 1])  # the span still covered


def other_side(frame: dict) -> str:
    return "left" if frame["hands"][0]["type"] == "right" else "right"


def second_hand(folder: Path) -> None:
    """meta.json keeps hands = 1; leap.jsonl gains the other side's hand 15 cm away in every frame."""
    write_frames(folder, [move_hand(f, 1.0, (150, 0, 0), hand_id=98, kind=other_side(f)) if f["hands"] else f
                          for f in frames(folder)])


def third_hand(folder: Path) -> None:
    """Two hands announced and tracked, and a third (a second hand of one side) in every frame."""
    out = []
    for f in frames(folder):
        if f["hands"]:
            f = move_hand(f, 1.0, (150, 0, 0), hand_id=98, kind=other_side(f))
            f = move_hand(f, 1.0, (-150, 0, 0), hand_id=99)
        out.append(f)
    write_frames(folder, out)
    edit_meta(folder, hands=2)


def mirrored_calibration(folder: Path) -> None:
    m = json.loads((folder / "meta.json").read_text())["leap_to_radar"]
    m[2] = [-v for v in m[2]]  # radar z negated: the hand below the radar
    edit_meta(folder, leap_to_radar=m)


def huge_angle(folder: Path) -> None:
    edit_meta(folder, angle_deg=1e300)


PROBES = {  # case: (corruption, verdict, pattern of the answer)
    "all-zero adc_data.bin": (zero_adc, "skip", r"adc_data.bin: every I and Q sample is 0: the capture holds no signal"),
    "every sample +32767": (rail_adc, "skip", r"adc_data.bin: every RX channel is constant \(I = \+32767, Q = \+32767 "
                                              r"throughout, 100% of the values at the ADC limits\)"),
    "40 % of Leap frames x1000": (scale_40_percent, "skip", r"leap.jsonl: \d+ of \d+ tracked hand frames \((3[5-9]|4\d)%\) are "
                                                            r"outliers: \d+ outside the plausible volume or not "
                                                            r"hand-shaped \(farthest joint \d+ m from the radar"),
    "1 s tracking hole": (hole_1s, "skip", r"leap.jsonl: tracked hands cover 3\d% of the spectrogram window "
                                           r"\(longest gap 1\.0\d s, .*tracking mostly missing"),
    "every 40th Leap frame": (every_40th, "skip", r"leap.jsonl: tracked hands cover \d% of the spectrogram window "
                                                  r"\(longest gap 0\.[34]\d s, Leap rate 2\.\d+ Hz"),
    "meta hands=1, two hands in Leap": (second_hand, "warn", r"meta.json says 1 hand\(s\) but leap.jsonl tracks 2 "
                                                             r"over at least 50% of the window"),
    "a third hand": (third_hand, "warn", r"\d+ hand\(s\) beyond one right and one left hand in \d+ frames were "
                                         r"dropped"),
    "mirrored calibration": (mirrored_calibration, "skip", r"meta.json: leap_to_radar mirrors space \(its 3x3 part "
                                                           r"has determinant -1e-09 < 0"),
    "angle_deg 1e300": (huge_angle, "skip", r"meta.json: angle_deg 1e\+300 is not a direction: expected -180..180"),
}


@pytest.mark.parametrize("source", ["writer", "world"])
@pytest.mark.parametrize("case", list(PROBES))
def test_probe_cases_get_a_named_answer(sources, tmp_path, source, case):
    corrupt, verdict, pattern = PROBES[case]
    root = tmp_path / "recs"
    distinct_copy(sources[source], root / "clean")
    corrupt(copy_of(sources[source], root / "bad"))
    summary, out = run(root, tmp_path)
    print(case, source, summary.report())
    assert summary.quality.rows["clean"].verdict == "ok"
    assert summary.quality.rows["bad"].verdict == verdict
    if verdict == "skip":
        answer = reason(summary, "bad")
        assert "\n" not in answer and re.search(pattern, answer), answer
        assert str(root / "bad") in answer and "(quality gate: " in answer
        assert list(read_meta_group(out)["recording"]) == ["clean"]
    else:
        assert any(re.search(pattern, m) for m in messages(summary, "bad")), messages(summary, "bad")
        assert sorted(read_meta_group(out)["recording"]) == ["bad", "clean"]
        q = read_quality_group(out)
        rows = list(read_meta_group(out)["recording"])
        assert q["verdict"][rows.index("bad")] == "warn" and q["verdict"][rows.index("clean")] == "ok"
    assert f"  bad " in summary.report()  # in the console table


@pytest.mark.parametrize("source", ["writer", "world"])
def test_copies_are_kept_and_named(sources, tmp_path, source):
    """50 copies of one recording (5 of the slower world's): every row kept, every copy named with the first."""
    n = 50 if source == "writer" else 5
    root = tmp_path / "recs"
    for i in range(n):
        copy_of(sources[source], root / f"copy_{i:02d}")
    summary, out = run(root, tmp_path)
    assert summary.written == n and summary.quality.counts() == {"ok": 1, "warn": n - 1, "skip": 0}
    for i in range(1, n):
        (m,) = messages(summary, f"copy_{i:02d}")
        assert m.startswith("warn: same adc_data.bin and leap.jsonl content as copy_00 (kept; copies leak across "
                            "train/test splits")
    q, rows = read_quality_group(out), list(read_meta_group(out)["recording"])
    assert [q["duplicate_of"][rows.index(f"copy_{i:02d}")] for i in range(n)] == [""] + ["copy_00"] * (n - 1)


def test_same_leap_data_alone_is_a_duplicate(sources, tmp_path):
    root = tmp_path / "recs"
    copy_of(sources["writer"], root / "a")
    b = copy_of(sources["writer"], root / "b")
    data = np.frombuffer((b / "adc_data.bin").read_bytes(), "<i2").copy()
    data[::7] += 1  # another capture, the same tracking
    (b / "adc_data.bin").write_bytes(data.tobytes())
    summary, _ = run(root, tmp_path)
    assert messages(summary, "b") == ["warn: same leap.jsonl content as a (kept; copies leak across train/test "
                                      "splits: the dataset's quality/duplicate_of names the first)"]


# ---- each threshold on a recording written to fail it ------------------------------------------
def set_rails(folder: Path, share: float) -> None:
    """``share`` of the I and Q values (every k-th) set to +32767 or -32768, alternately."""
    data = np.frombuffer((folder / "adc_data.bin").read_bytes(), "<i2").copy()
    idx = np.arange(0, data.size, int(round(1 / share)))
    data[idx] = np.where(np.arange(idx.size) % 2, 32767, -32768)
    (folder / "adc_data.bin").write_bytes(data.tobytes())


@pytest.mark.parametrize("source", ["writer", "world"])
@pytest.mark.parametrize(("share", "verdict"), [(0.0005, "ok"), (0.004, "warn"), (0.02, "skip")])
def test_clipping_thresholds(sources, tmp_path, source, share, verdict):
    """0.1 % of the values at the rails warns, 1 % skips (a Gaussian signal's clipping distortion at
    -39 and -27 dB against the chain's 30 dB dynamic range)."""
    root = tmp_path / "recs"
    set_rails(copy_of(sources[source], root / "r"), share)
    summary, _ = run(root, tmp_path, check=True)
    q = summary.quality.rows["r"]
    assert q.verdict == verdict and q.figures["clipped_share"] == pytest.approx(share, rel=0.01)
    if verdict != "ok":
        assert re.search(rf"{share:.2%} of the I and Q values sit at the ADC limits", messages(summary, "r")[0])


def test_dead_rx_channel_is_named(tmp_path):
    root = tmp_path / "recs"
    write_recording(root / "dead", Scene(rx_gains=(1.0, 1.0, 0.0, 1.0)))
    write_recording(root / "weak", Scene(rx_gains=(1.0, 1.0, 0.05, 1.0), z0_m=0.45))  # -26 dB
    write_recording(root / "fine", Scene(rx_gains=(1.0, 0.5, 0.3, 1.0), z0_m=0.4))  # -10.5 dB at worst
    summary, _ = run(root, tmp_path)
    assert summary.written == 3
    assert messages(summary, "dead") == ["warn: RX3 is dead (-inf dB against the median channel; threshold -20 dB)"]
    assert re.fullmatch(r"warn: RX3 is dead \(-2[56] dB against the median channel; threshold -20 dB\)",
                        messages(summary, "weak")[0])
    assert summary.quality.rows["fine"].verdict == "ok"


def test_few_jumps_are_dropped_and_reinterpolated(sources, tmp_path):
    """Three single frames 20 cm off (20 m/s at 100 Hz, over the 10 m/s limit): dropped, filled from their
    neighbours, the stored skeleton the clean one's to 0.1 mm."""
    root = tmp_path / "recs"
    copy_of(sources["writer"], root / "clean")
    bad = copy_of(sources["writer"], root / "jumps")
    data = np.frombuffer((bad / "adc_data.bin").read_bytes(), "<i2").copy()
    data[::97] += 1  # no duplicate of the clean capture
    (bad / "adc_data.bin").write_bytes(data.tobytes())
    fr = frames(bad)
    for i in (90, 130, 170):  # radar time 0.8, 1.2, 1.6 s: inside the window
        fr[i] = move_hand(fr[i], 1.0, (200, 0, 0))
    write_frames(bad, fr)
    summary, out = run(root, tmp_path)
    assert messages(summary, "jumps") == ["warn: 3 outlier hand frames dropped (3 jumping faster than 10 m/s); 3 "
                                          "re-interpolated, 0 left untracked"]
    rows = list(read_meta_group(out)["recording"])
    with h5py.File(out) as h5:
        sk, mask = h5["skeletons"][()], h5["hand_mask"][()]
    np.testing.assert_allclose(sk[rows.index("jumps")], sk[rows.index("clean")], atol=1e-4)
    assert mask[rows.index("jumps")].tolist() == mask[rows.index("clean")].tolist()


@pytest.mark.parametrize("source", ["writer", "world"])
def test_a_far_block_is_left_untracked(sources, tmp_path, source):
    """0.15 s of frames x1000 (about 6 % of the frames): dropped; the gap they leave is longer than
    MAX_INTERP_GAP_S, so those steps are untracked in the row, not interpolated across."""
    root = tmp_path / "recs"
    bad = copy_of(sources[source], root / "block")
    fr = frames(bad)
    t = radar_times(bad, fr)
    mid = capture_s(bad) / 2
    block = (t >= mid) & (t < mid + 0.15)
    write_frames(bad, [move_hand(f, 1000.0) if b and f["hands"] else f for f, b in zip(fr, block)])
    summary, out = run(root, tmp_path)
    q = summary.quality.rows["block"]
    assert q.verdict == "warn" and q.figures["outliers_interpolated"] == 0
    assert q.figures["longest_gap_s"] > 0.15
    with h5py.File(out) as h5:
        sk, mask, start = h5["skeletons"][0], h5["hand_mask"][0], h5["window_start_s"][0]
    steps = start + np.arange(len(mask)) / 100.0
    inside = (steps > mid + 0.01) & (steps < mid + 0.14)
    assert not mask[inside].any() and np.abs(sk).max() < 1.0  # nothing 100s of metres away is stored


@pytest.mark.parametrize(("hole_s", "verdicts"), [(0.08, {"gap": None, "coverage": None}),
                                                  (0.3, {"gap": "warn", "coverage": "warn"})])
def test_gap_and_coverage_thresholds(sources, tmp_path, hole_s, verdicts):
    """A hole shorter than MAX_INTERP_GAP_S is bridged (and the row unchanged); a 0.3 s hole is marked
    untracked: coverage 1.3 / 1.6 = 81 %, below the 90 % warning."""
    root = tmp_path / "recs"
    bad = copy_of(sources["writer"], root / "hole")
    fr = frames(bad)
    t = radar_times(bad, fr)
    write_frames(bad, [f for f, ti in zip(fr, t) if not 1.0 < ti < 1.0 + hole_s])
    summary, out = run(root, tmp_path)
    q = summary.quality.rows["hole"]
    levels = {f.check: f.level for f in q.findings}
    assert {k: levels.get(k) for k in verdicts} == verdicts
    assert q.figures["longest_gap_s"] == pytest.approx(hole_s + 0.01, abs=0.011)
    with h5py.File(out) as h5:
        mask = h5["hand_mask"][0, :, 0]
    assert mask.mean() == pytest.approx(q.figures["coverage"])
    if hole_s > MAX_INTERP_GAP_S:
        assert q.figures["coverage"] == pytest.approx(1 - hole_s / 1.6, abs=0.02)
    else:
        assert mask.all()


def test_slow_leap_rate_warns(sources, tmp_path):
    """Every 3rd frame of a 100 Hz stream: 33 Hz, under two samples per 50 ms column; the 30 ms
    gaps are still bridged, so only the rate is named."""
    root = tmp_path / "recs"
    bad = copy_of(sources["writer"], root / "slow")
    fr = frames(bad)
    write_frames(bad, [f for i, f in enumerate(fr) if i % 3 == 0 or i == len(fr) - 1])
    summary, _ = run(root, tmp_path)
    assert messages(summary, "slow") == ["warn: Leap frames come at 33.3 Hz (median interval); expected at least "
                                         "40 Hz, two per 50 ms STFT column"]


def test_hand_outside_the_view_is_skipped(sources, tmp_path):
    """The writer's hand 1 m across boresight at 0.5 m height (63 deg off boresight, 1.1 m away: beyond
    both the 60 deg beam and the 0.7 m range gate); the world's moved 1 m by its calibration."""
    root = tmp_path / "recs"
    write_recording(root / "aside", Scene(x0_m=1.0))
    world = copy_of(sources["world"], root / "world_aside")
    m = json.loads((world / "meta.json").read_text())["leap_to_radar"]
    m[0][3] += 1.0
    edit_meta(world, leap_to_radar=m)
    summary, _ = run(root, tmp_path, check=True)
    for name in ("aside", "world_aside"):
        assert re.search(r"the hand is outside the radar's view for 100% of the tracked window \(more than 60 deg off "
                         r"boresight or outside the range gate; skipped above 50%\)", reason(summary, name))


def test_skew_calibration_is_skipped(sources, tmp_path):
    root = tmp_path / "recs"
    bad = copy_of(sources["writer"], root / "skew")
    m = json.loads((bad / "meta.json").read_text())["leap_to_radar"]
    m[0][0] *= 1.2  # 20 % more along radar x: no rigid mounting
    edit_meta(bad, leap_to_radar=m)
    summary, _ = run(root, tmp_path, check=True)
    assert "leap_to_radar is not a rotation times a scale: its singular values differ by 20% (expected equal " \
           "within 5%)" in reason(summary, "skew")


# ---- clean recordings: untouched ---------------------------------------------------------------
def test_clean_recordings_ingest_exactly_as_without_the_gate(sources, tmp_path):
    """Every row of clean recordings (writer scenes and reference-world recordings with their dropouts,
    jitter and sync offset) equals the pre-gate pipeline's (load_recording + recording_example), bit for bit."""
    root = tmp_path / "recs"
    copy_of(sources["world"], root / "world_circle")
    write_recording(root / "grasp", Scene())
    write_recording(root / "slide", Scene(gesture="slide", velocity_m_s=0.12, z0_m=0.25, angle_deg=-30))
    summary, out = run(root, tmp_path)
    assert summary.quality.counts() == {"ok": 3, "warn": 0, "skip": 0} and summary.written == 3
    rows = list(read_meta_group(out)["recording"])
    with h5py.File(out) as h5:
        spec, sk, mask, start = (h5[k][()] for k in ("spectrograms", "skeletons", "hand_mask", "window_start_s"))
    for i, name in enumerate(rows):
        ex = recording_example(load_recording(root / name), CHAIN, 100.0)
        np.testing.assert_array_equal(spec[i], ex.spectrogram)
        np.testing.assert_array_equal(sk[i], ex.skeleton.positions)
        np.testing.assert_array_equal(mask[i], ex.skeleton.mask)
        assert start[i] == ex.window_start_s
    q = read_quality_group(out)
    assert set(q["verdict"]) == {"ok"} and (q["coverage"] > 0.9).all() and (q["clipped_share"] == 0).all()
    checks = json.loads((out.parent / "d.checks.json").read_text())["quality"]
    assert checks["counts"] == {"ok": 3, "warn": 0, "skip": 0} and checks["thresholds"]["max_interp_gap_s"] == 0.1


def test_check_writes_nothing(sources, tmp_path):
    root = tmp_path / "recs"
    copy_of(sources["writer"], root / "clean")
    zero_adc(copy_of(sources["writer"], root / "dead"))
    before = sorted(p for p in tmp_path.rglob("*"))
    summary = ingest(root, None, CHAIN, progress=False, check=True)
    assert sorted(p for p in tmp_path.rglob("*")) == before
    report = summary.report()
    assert report.startswith("checked; would ingest 1 of 2 recordings; skipped 1")
    assert "quality gate: 1 ok, 0 kept with warnings, 1 skipped (of 2 checked)" in report


def test_cli_check_reports_without_writing(sources, tmp_path):
    from tests.data.test_ingest import run_cli

    root = tmp_path / "recs"
    copy_of(sources["writer"], root / "clean")
    huge_angle(copy_of(sources["writer"], root / "angle"))
    proc = run_cli(f"root={root}", "check=true", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "checked; would ingest 1 of 2 recordings; skipped 1" in proc.stdout
    assert "angle_deg 1e+300 is not a direction" in proc.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hydra", "recs"]


def test_strict_stops_at_a_recording_the_gate_skips(sources, tmp_path):
    root = tmp_path / "recs"
    zero_adc(copy_of(sources["writer"], root / "dead"))
    with pytest.raises(FormatError, match=r"dead/adc_data.bin: every I and Q sample is 0"):
        run(root, tmp_path, strict=True)


# ---- the dataset's quality group ---------------------------------------------------------------
def test_quality_fields_are_validated(tmp_path, radar, chain):
    path = tmp_path / "d.h5"
    with open_writer(path, classes=GESTURES, radar=radar, chain=chain, skeleton_rate_hz=10.0, n_steps=4,
                     config_hash="h") as w:
        for i in range(3):
            fields = {**RecordingQuality().row_fields(), "coverage": 0.5 * i}
            w.append(np.zeros((64, 32), np.float32), i, np.zeros((4, 2, 21, 3), np.float32), np.ones((4, 2), bool),
                     0.0, {"gesture": GESTURES[i]}, quality=fields)
    assert validate(path) == 3 and read_quality_group(path)["coverage"].tolist() == [0.0, 0.5, 1.0]
    with h5py.File(path, "a") as h5:
        h5["quality/coverage"][1] = 1.5
    with pytest.raises(FormatError, match=r"quality/coverage must be shares in \[0, 1\]"):
        validate(path)
    with h5py.File(path, "a") as h5:
        del h5["quality/coverage"]
        h5["quality/coverage"] = np.zeros(2)
    with pytest.raises(FormatError, match=r"quality/coverage must have shape \(3,\), found \(2,\)"):
        validate(path)


# ---- the measures against closed forms ---------------------------------------------------------
def test_adc_figures_count_the_rails_and_channel_powers():
    rng = np.random.default_rng(1)
    adc = (rng.normal(0, 100, (4, 16, 3, 32)) + 1j * rng.normal(0, 100, (4, 16, 3, 32))).round().astype(np.complex64)
    adc[:, :, 2] *= 0.1  # RX3: 20 dB down in power
    adc[0, 1, 0, :5] = 32767 + 0j  # 5 real rails (the imaginary parts stay), in a chirp the power skips
    adc[1, 1, 1, 0] = -32768 - 32768j  # two more
    fig = adc_figures(adc)
    assert fig["clipped_share"] == 7 / (2 * adc.size)
    assert fig["rx_power_db"][2] == pytest.approx(-20, abs=1.0)
    assert not fig["all_zero"] and fig["constant_rx"] == []
    assert adc_figures(adc, adc_bits=12)["clipped_share"] == 7 / (2 * adc.size)  # 12-bit rails at +-2047
    adc[:, :, 1] = 5 + 3j
    fig = adc_figures(adc)
    assert fig["constant_rx"] == [(1, 5 + 3j)]
    q = RecordingQuality()
    adc_findings(fig, q)
    assert [f.message for f in q.findings] == ["RX2 is dead (-inf dB against the median channel; threshold -20 dB)"]


def test_view_outside_the_beam_and_the_gate():
    def hand_at(r, deg):
        c = np.array([r * math.sin(math.radians(deg)), 0.0, r * math.cos(math.radians(deg))])
        return np.broadcast_to(c, (1, 1, 21, 3))

    gate = (0.08, 0.70)
    got = [bool(view_outside(hand_at(r, a), np.ones((1, 1), bool), gate)[0, 0])
           for r, a in [(0.3, 59.0), (0.3, 61.0), (0.3, -61.0), (0.05, 0.0), (0.75, 0.0), (0.3, 170.0)]]
    assert got == [False, True, True, True, True, True]


def test_long_gaps_and_the_longest_gap():
    times = np.array([0.0, 0.05, 0.30, 0.35, 0.40])
    at = np.array([0.02, 0.05, 0.10, 0.29, 0.30, 0.37, 0.5])
    assert long_gap_steps(times, at).tolist() == [False, False, True, True, False, False, False]
    seq = HandSequence(np.zeros((5, 2, 21, 3)), times, [[1, 0], [1, 0], [0, 0], [1, 0], [1, 0]])
    assert longest_gap_s(seq, 0.0, 0.4) == pytest.approx(0.30)  # 0.05 .. 0.35: the untracked sample does not count
    assert longest_gap_s(seq, 0.36, 1.0) == pytest.approx(0.60)  # the last tracked sample at 0.4


def test_jumps_flag_the_frames_out_there_not_those_after():
    t = np.arange(20) / 100.0
    pos = np.zeros((20, 21, 3))
    pos[:, :, 2] = 0.3 + 0.5 * t[:, None]  # 0.5 m/s: plausible
    pos[[4, 5, 12], :, 0] += 0.4  # out and back (two frames), and a single spike: 40 m/s
    out = _jump_outliers(pos, t, np.ones(20, bool))
    assert np.flatnonzero(out).tolist() == [4, 5, 12]
    seq = HandSequence(np.stack([pos, np.zeros_like(pos)], 1), t, np.tile([True, False], (20, 1)))
    cleaned, n = drop_outliers(seq, np.stack([out, np.zeros(20, bool)], 1))
    assert n == 3 and cleaned.mask[:, 0].all()
    np.testing.assert_allclose(cleaned.positions[:, 0, :, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(cleaned.positions[:, 0, :, 2], np.broadcast_to(0.3 + 0.5 * t[:, None], (20, 21)), atol=1e-6)
    # the same spike with its neighbours 0.2 s apart (beyond MAX_INTERP_GAP_S): untracked, not filled
    sparse = HandSequence(seq.positions, np.r_[t[:13], t[13:] + 0.2], seq.mask)
    cleaned, n = drop_outliers(sparse, np.stack([np.arange(20) == 12, np.zeros(20, bool)], 1))
    assert n == 0 and not cleaned.mask[12, 0] and cleaned.mask[11, 0] and cleaned.mask[13, 0]


def test_a_format_failure_after_the_gate_is_not_counted_by_it(tmp_path):
    """A capture shorter than one window fails in the chain, after the capture checks: reported as a
    format failure only, not as a recording the gate passed."""
    root = tmp_path / "recs"
    write_recording(root / "good", Scene())
    write_recording(root / "short", Scene(n_frames=10, leap_span_s=(-0.1, 1.1), z0_m=0.4))
    summary, _ = run(root, tmp_path)
    assert "fewer than the 16 of one spectrogram" in reason(summary, "short")
    assert list(summary.quality.rows) == ["good"] and summary.quality.counts()["ok"] == 1
