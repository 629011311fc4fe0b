"""handradar-ingest end to end on recordings written by an independent writer (tests/data/writer.py)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

import handradar.data.ingest as ingest_mod
from handradar.data.hdf5 import read_attrs, read_meta_group, validate
from handradar.data.ingest import ingest
from handradar.errors import FormatError
from handradar.radar.chain import ChainConfig
from handradar.vocab import GESTURES
from tests.data.writer import Scene, expected_doppler_row, write_recording
from tests.unprivileged import drop_privileges

REPO = Path(__file__).resolve().parents[2]
SCRIPT = Path(sys.executable).parent / "handradar-ingest"

GOOD = {
    "s01/grasp_1": Scene(gesture="grasp", subject="s01", repetition=1),
    "s01/circle_1": Scene(gesture="circle", subject="s01", repetition=1, angle_deg=30, velocity_m_s=-0.25),
    "s02/slide_2": Scene(gesture="slide", subject="s02", repetition=2, angle_deg=-30, occlusion=True,
                         velocity_m_s=0.12, z0_m=0.25),
    "s02/hand_merge_1": Scene(gesture="hand_merge", subject="s02", repetition=1, extra_meta={"truth": {"noise": 1}}),
}


def run_cli(*args: str, cwd: Path, unprivileged: bool = False) -> subprocess.CompletedProcess:
    """handradar-ingest ``args``; unprivileged: as a user the mode bits bind (tests/unprivileged.py)."""
    env = {**os.environ, "PYTHONPATH": str(REPO / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([str(SCRIPT), *args, f"hydra.run.dir={cwd / 'hydra'}"], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300,
                          preexec_fn=drop_privileges() if unprivileged else None)


@pytest.fixture()
def root(tmp_path) -> Path:
    for name, scene in GOOD.items():
        write_recording(tmp_path / "recs" / name, scene)
    return tmp_path / "recs"


def add_bad(root: Path) -> dict[str, str]:
    """Bad recordings and the reason each must be skipped for."""
    bad = {}
    p = write_recording(root / "bad" / "truncated", Scene())
    data = (p / "adc_data.bin").read_bytes()
    (p / "adc_data.bin").write_bytes(data[:-1000])
    bad["bad/truncated"] = f"size {len(data) - 1000} bytes does not match the .cfg: expected {len(data)} bytes"
    write_recording(root / "bad" / "late_leap", Scene(leap_span_s=(0.3, 2.5)))
    bad["bad/late_leap"] = "Leap data cover 0.300..2.490 s of the radar clock, but the capture spans 0..2.400 s"
    p = write_recording(root / "bad" / "no_subject", Scene())
    meta = json.loads((p / "meta.json").read_text())
    del meta["subject"]
    (p / "meta.json").write_text(json.dumps(meta))
    bad["bad/no_subject"] = "missing required field 'subject'"
    write_recording(root / "bad" / "short", Scene(n_frames=10, leap_span_s=(-0.1, 1.1)))
    bad["bad/short"] = "capture has 10 frames, fewer than the 16 of one spectrogram"
    return bad


def check_dataset(out: Path, names: list[str]) -> None:
    assert validate(out) == len(names)
    attrs = read_attrs(out)
    assert attrs["format"] == "handradar.dataset/1" and attrs["classes"] == list(GESTURES)
    assert attrs["config_hash"] and attrs["code_version"]
    meta = read_meta_group(out)
    assert sorted(meta) == ["angle_deg", "gesture", "hands", "occlusion", "recording", "repetition", "subject"]
    order = list(meta["recording"])
    assert sorted(order) == sorted(names)
    with h5py.File(out, "r") as h5:
        labels = h5["labels"][()]
        spec = h5["spectrograms"][()]
        skel = h5["skeletons"][()]
        start = h5["window_start_s"][()]
        assert meta["angle_deg"].dtype == np.float64 and meta["occlusion"].dtype == bool
        assert meta["hands"].dtype == np.int64 and meta["repetition"].dtype == np.int64
    for i, name in enumerate(order):
        scene = GOOD[name]
        assert labels[i] == GESTURES.index(scene.gesture)
        assert meta["gesture"][i] == scene.gesture and meta["subject"][i] == scene.subject
        assert meta["angle_deg"][i] == scene.angle_deg and bool(meta["occlusion"][i]) == scene.occlusion
        assert meta["repetition"][i] == scene.repetition and meta["hands"][i] == 1
        # the motion fills frames 6..21: the chain's window starts there
        assert start[i] == pytest.approx(0.6)
        # the point reflector's Doppler row in every column (closed form from the raw numbers)
        assert (spec[i].argmax(axis=0) == expected_doppler_row(scene.velocity_m_s)).all(), name
        # the skeleton window: 1.6 s at 100 Hz from the window start, the writer's hand at those times
        t = 0.6 + np.arange(160) / 100.0
        assert skel.shape[1:] == (160, 2, 21, 3)
        np.testing.assert_allclose(skel[i, :, 0], scene.joints(t), atol=2e-5)
        assert not skel[i, :, 1].any()


def test_cli_end_to_end(root, tmp_path):
    bad = add_bad(root)
    out = tmp_path / "out" / "x.h5"
    proc = run_cli(f"root={root}", f"out={out}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert lines[-1] == str(out.resolve())  # the contract: the last line is the output path
    # Hydra's log lines (one warning per skipped recording) come first, then the summary
    summary = lines.index(f"ingested {len(GOOD)} of {len(GOOD) + len(bad)} recordings; skipped {len(bad)}")
    lines = lines[summary:]
    for name, reason in bad.items():
        assert any(line.startswith(f"  skipped {name}: ") and reason in line for line in lines), (name, proc.stdout)
    check_dataset(out, list(GOOD))
    assert sorted(p.name for p in out.parent.iterdir()) == ["x.checks.json", "x.h5"]  # no temporary file left beside it


def test_cli_strict_fails_without_writing(root, tmp_path):
    add_bad(root)
    out = tmp_path / "out" / "x.h5"
    proc = run_cli(f"root={root}", f"out={out}", "strict=true", cwd=tmp_path)
    assert proc.returncode == 1
    assert "error:" in proc.stderr and "nothing written" in proc.stderr
    assert "bad/late_leap/leap.jsonl" in proc.stderr  # the first bad recording, named with its file
    assert not out.parent.exists() or list(out.parent.iterdir()) == []


def test_interrupt_leaves_no_file(root, tmp_path, monkeypatch):
    calls = {"n": 0}
    real = ingest_mod.recording_example

    def interrupted(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:  # after two rows were written into the temporary file
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(ingest_mod, "recording_example", interrupted)
    out = tmp_path / "out" / "x.h5"
    with pytest.raises(KeyboardInterrupt):
        ingest(root, out, ChainConfig(), progress=False)
    assert calls["n"] == 3
    assert list(out.parent.iterdir()) == []  # neither x.h5 nor .x.h5.*.part


def test_in_process_skip_and_strict(root, tmp_path):
    bad = add_bad(root)
    out = tmp_path / "y.h5"
    summary = ingest(root, out, ChainConfig(), progress=False)
    assert summary.written == len(GOOD) and summary.found == len(GOOD) + len(bad)
    assert dict(summary.by_file) == {"adc_data.bin": 2, "leap.jsonl": 1, "meta.json": 1}
    check_dataset(out, list(GOOD))
    with pytest.raises(FormatError, match="bad/late_leap/leap.jsonl"):
        ingest(root, tmp_path / "z.h5", ChainConfig(), progress=False, strict=True)
    assert not (tmp_path / "z.h5").exists()


def _set_cfg(folder: Path, old: str, new: str) -> None:
    cfg = (folder / "radar.cfg").read_text()
    assert old in cfg
    (folder / "radar.cfg").write_text(cfg.replace(old, new))


IDLE_300 = ("profileCfg 0 77 338.8", "profileCfg 0 77 300")  # idle time 338.8 -> 300 us


def test_mixed_radar_configs_are_skipped(root, tmp_path):
    _set_cfg(write_recording(root / "zz_other", Scene()), *IDLE_300)
    summary = ingest(root, tmp_path / "m.h5", ChainConfig(), progress=False)
    assert summary.written == len(GOOD)
    (name, reason), = summary.skipped
    assert name == "zz_other" and reason == (
        f"{root / 'zz_other' / 'radar.cfg'}: radar configuration differs from the reference recording s01/circle_1's "
        "in idle_time_s: 0.0003 here, 0.0003388 in s01/circle_1 (the reference has the most common configuration, "
        "4 of 5 recordings; ties go to the first in sorted order); ingest one configuration per dataset")


def test_odd_configuration_sorting_first_does_not_win(root, tmp_path):
    """The odd recording sorts first: the majority's configuration is still the reference."""
    _set_cfg(write_recording(root / "a_odd", Scene()), *IDLE_300)
    out = tmp_path / "m.h5"
    summary = ingest(root, out, ChainConfig(), progress=False)
    assert summary.written == len(GOOD) and [n for n, _ in summary.skipped] == ["a_odd"]
    assert "differs from the reference recording s01/circle_1's in idle_time_s: 0.0003 here" in summary.skipped[0][1]
    check_dataset(out, list(GOOD))
    assert read_attrs(out)["radar"].idle_time_s == pytest.approx(338.8e-6)  # the file carries the majority's radar


@pytest.mark.parametrize("changed", ["bc", "ad"])
def test_tied_configurations_keep_the_first_in_sorted_order(tmp_path, changed):
    """Two configurations, two recordings each: the one of recording a (first in sorted order) is the reference."""
    for name in "abcd":
        p = write_recording(tmp_path / "recs" / name, Scene(gesture="circle"))
        if name in changed:
            _set_cfg(p, "profileCfg 0 77 338.8", "profileCfg 0 76.5 300")
    summary = ingest(tmp_path / "recs", tmp_path / "t.h5", ChainConfig(), progress=False)  # out outside the input
    assert summary.written == 2 and [n for n, _ in summary.skipped] == ["b", "c"]
    here, there = ("7.65e+10", "0.0003"), ("7.7e+10", "0.0003388")
    if changed == "ad":
        here, there = there, here
    for _, reason in summary.skipped:
        assert (f"in start_freq_hz: {here[0]} here, {there[0]} in a; idle_time_s: {here[1]} here, {there[1]} in a "
                "(the reference has the most common configuration, 2 of 4 recordings; ties go to the first in "
                "sorted order)") in reason


def test_capture_length_and_gain_do_not_split_a_dataset(root, tmp_path):
    """numFrames (the capture length), RX gain and ADC bits leave the chain's output unchanged."""
    write_recording(root / "long", Scene(n_frames=30, leap_span_s=(-0.1, 3.1)))
    _set_cfg(write_recording(root / "gain", Scene()), "76.22 1 256 10000 0 0 30", "76.22 1 256 10000 0 0 36")
    _set_cfg(root / "gain", "adcCfg 2 1", "adcCfg 1 1")
    summary = ingest(root, tmp_path / "g.h5", ChainConfig(), progress=False)
    assert summary.skipped == [] and summary.written == len(GOOD) + 2


def test_strict_stops_at_a_differing_configuration(root, tmp_path):
    _set_cfg(write_recording(root / "a_odd", Scene()), *IDLE_300)
    with pytest.raises(FormatError, match=r"a_odd/radar.cfg: radar configuration differs from the reference "
                                          r"recording s01/circle_1's in idle_time_s"):
        ingest(root, tmp_path / "s.h5", ChainConfig(), progress=False, strict=True)
    assert not (tmp_path / "s.h5").exists()


def test_folder_without_meta_json_is_counted_and_reported(root, tmp_path):
    (write_recording(root / "s03" / "no_meta", Scene()) / "meta.json").unlink()
    bad = add_bad(root)
    summary = ingest(root, tmp_path / "n.h5", ChainConfig(), progress=False)
    assert summary.found == len(GOOD) + len(bad) + 1 and summary.written == len(GOOD)
    reasons = dict(summary.skipped)
    assert reasons["s03/no_meta"] == (f"{root / 's03' / 'no_meta' / 'meta.json'}: no such file; the folder holds "
                                      "radar.cfg, adc_data.bin, leap.jsonl but no meta.json (labels, radar_start_us, "
                                      "leap_to_radar), so it is not a recording")
    assert summary.by_file["meta.json"] == 2  # no_meta and bad/no_subject
    assert summary.report().startswith(f"ingested {len(GOOD)} of {len(GOOD) + len(bad) + 1} recordings; "
                                       f"skipped {len(bad) + 1}")


def test_nothing_to_ingest(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(FormatError, match="no recordings found"):
        ingest(tmp_path / "empty", tmp_path / "e.h5", ChainConfig(), progress=False)
    with pytest.raises(FormatError, match="output path is a directory"):
        ingest(tmp_path / "empty", tmp_path, ChainConfig(), progress=False)
    write_recording(tmp_path / "only_bad", Scene(n_frames=10, leap_span_s=(-0.1, 1.1)))
    with pytest.raises(FormatError, match="none of the 1 recordings could be ingested"):
        ingest(tmp_path / "only_bad", tmp_path / "e.h5", ChainConfig(), progress=False)
    assert not (tmp_path / "e.h5").exists()


# ---- the command's failures: unwritable output, missing arguments, SIGTERM and SIGKILL -----------------
def test_cli_output_under_a_file_fails_in_one_line(root, tmp_path):
    blocker = tmp_path / "taken"
    blocker.write_text("a file where a folder is needed")
    for out in (blocker / "x.h5", blocker / "sub" / "x.h5"):
        proc = run_cli(f"root={root}", f"out={out}", cwd=tmp_path)
        assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
        assert proc.stderr.splitlines()[-1] == f"error: {blocker}: Not a directory (nothing written to {out})"


def test_cli_read_only_output_folder_fails_in_one_line(root, tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:  # unprivileged: root writes into read-only folders
        proc = run_cli(f"root={root}", f"out={folder / 'x.h5'}", cwd=tmp_path, unprivileged=True)
    finally:
        folder.chmod(0o700)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.splitlines()[-1] == f"error: {folder}: Permission denied (nothing written to {folder / 'x.h5'})"
    assert list(folder.iterdir()) == []


def test_cli_without_root_prints_usage(tmp_path):
    proc = run_cli(f"out={tmp_path / 'x.h5'}", cwd=tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.splitlines() == [
        "usage: handradar-ingest root=DIR out=FILE.h5 [strict=true] [allow_truncated=true] [iq_swap=true] [key=value ...]",
        "error: missing value for root (give root=...)"]


# The command with its second recording held up for a minute: the dataset's temporary file exists
# (the first row is written) when the test signals it.
HELD_UP = """
import sys, time
import handradar.data.ingest as ingest
real, calls = ingest.recording_example, []
def held_up(*args, **kwargs):
    calls.append(1)
    if len(calls) == 2:
        time.sleep(60)
    return real(*args, **kwargs)
ingest.recording_example = held_up
from handradar.cli.ingest import main
sys.argv[0] = "handradar-ingest"
main()
"""


def start_held_up(root: Path, out: Path, cwd: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen([sys.executable, "-c", HELD_UP, f"root={root}", f"out={out}",
                             f"hydra.run.dir={cwd / 'hydra'}"], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while not list(out.parent.glob(f".{out.name}.*.part")):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"no temporary file appeared: {proc.communicate()[1][-2000:]}")
        time.sleep(0.05)
    return proc


def test_cli_sigterm_is_an_interrupt(root, tmp_path):
    """timeout, SLURM and container runtimes stop a job with SIGTERM: one line, no file, exit 128 + 15."""
    out = tmp_path / "out" / "x.h5"
    proc = start_held_up(root, out, tmp_path)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 143
    assert stderr.splitlines()[-1] == f"interrupted (SIGTERM); nothing written to {out}"
    assert list(out.parent.iterdir()) == []  # neither x.h5 nor its temporary file


def test_cli_sigkill_leftover_is_removed_by_the_next_run(root, tmp_path):
    out = tmp_path / "out" / "x.h5"
    proc = start_held_up(root, out, tmp_path)
    proc.kill()  # SIGKILL: nothing runs on the way out
    proc.communicate(timeout=60)
    (stale,) = out.parent.glob(f".{out.name}.*.part")
    assert stale.name.startswith(f".x.h5.{proc.pid}@")
    ingest(root, out, ChainConfig(), progress=False)
    assert sorted(p.name for p in out.parent.iterdir()) == ["x.checks.json", "x.h5"]
    check_dataset(out, list(GOOD))
