"""No diagnosis code reads meta.json ``truth``: scrambling it leaves the report unchanged."""

from __future__ import annotations

import json
from pathlib import Path

from handradar.data.ingest import ingest
from handradar.data.recording import read_truth
from handradar.gap.data import load_dataset
from handradar.gap.diagnosis import DiagnosisConfig, diagnose
from tests.data.writer import Scene, write_recording
from tests.gap.conftest import builder

GAP_SRC = Path(__file__).resolve().parents[2] / "src" / "handradar" / "gap"


def _recordings(root: Path, truth: dict) -> None:
    for i in range(6):
        write_recording(root / f"rec{i}", Scene(gesture=("grasp", "circle", "slide")[i % 3], subject=f"s{i % 2}",
                                                velocity_m_s=-0.1 - 0.02 * i, repetition=i,
                                                extra_meta={"truth": {**truth, "i": i}}))


def _report(root: Path, out: Path, chain, radar) -> dict:
    ingest(root, out, chain, progress=False)
    data = load_dataset(out)
    cfg = DiagnosisConfig(candidates=["antenna_pattern", "palm", "noise"], radarweightnet=False, n_boot=200)
    rep = diagnose(data, builder(data.radar, data.chain), {}, cfg, progress=False).report
    rep.pop("timings_s")
    return rep


def test_scrambled_truth_gives_the_same_report(tmp_path, radar, chain):
    _recordings(tmp_path / "a", {"effects": {"palm": {"enabled": True, "radius_m": 0.03}}, "cause": "palm"})
    _recordings(tmp_path / "b", {"effects": {"noise": {"enabled": False}}, "cause": "noise", "scrambled": [1, 2]})
    assert read_truth(tmp_path / "a" / "rec0") != read_truth(tmp_path / "b" / "rec0")
    ra = _report(tmp_path / "a", tmp_path / "a.h5", chain, radar)
    rb = _report(tmp_path / "b", tmp_path / "b.h5", chain, radar)
    assert json.dumps(ra, sort_keys=True) == json.dumps(rb, sort_keys=True)


def test_only_the_benchmark_scoring_mentions_truth():
    # the diagnosis modules never read truth: only benchmark.py (scoring, from the world config it made) may
    for f in GAP_SRC.glob("*.py"):
        if f.name != "benchmark.py":
            text = f.read_text()
            assert "read_truth" not in text and '"truth"' not in text and "'truth'" not in text, f.name
