"""handradar-ingest end to end on recordings written by an independent writer (tests/data/writer.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
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

REPO = Path(__file__).resolve().parents[2]
SCRIPT = Path(sys.executable).parent / "handradar-ingest"

GOOD = {
    "s01/grasp_1": Scene(gesture="grasp", subject="s01", repetition=1),
    "s01/circle_1": Scene(gesture="circle", subject="s01", repetition=1, angle_deg=30, velocity_m_s=-0.25),
    "s02/slide_2": Scene(gesture="slide", subject="s02", repetition=2, angle_deg=-30, occlusion=True,
                         velocity_m_s=0.12, z0_m=0.25),
    "s02/hand_merge_1": Scene(gesture="hand_merge", subject="s02", repetition=1, extra_meta={"truth": {"noise": 1}}),
}


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([str(SCRIPT), *args, f"hydra.run.dir={cwd / 'hydra'}"], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


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
    assert [p.name for p in out.parent.iterdir()] == ["x.h5"]  # no temporary file left beside it


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


def test_mixed_radar_configs_are_skipped(root, tmp_path):
    p = write_recording(root / "zz_other", Scene())
    cfg = (p / "radar.cfg").read_text().replace("profileCfg 0 77 338.8", "profileCfg 0 77 300")
    (p / "radar.cfg").write_text(cfg)
    summary = ingest(root, tmp_path / "m.h5", ChainConfig(), progress=False)
    assert summary.written == len(GOOD)
    assert summary.skipped[0][0] == "zz_other" and "differs from the first recording's" in summary.skipped[0][1]


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
