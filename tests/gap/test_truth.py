"""No diagnosis code reads meta.json ``truth``: scrambling it leaves the report unchanged."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py

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
    # the diagnosis modules never read truth: only benchmark.py (scoring, from the world config it made) and
    # records.py (the benchmark's scored results, kept and rendered after every diagnosis has run) may
    for f in GAP_SRC.glob("*.py"):
        if f.name not in ("benchmark.py", "records.py"):
            text = f.read_text()
            assert "read_truth" not in text and '"truth"' not in text and "'truth'" not in text, f.name


def test_the_worlds_stored_configuration_never_reaches_the_diagnosis(tmp_path, radar, chain):
    """A world dataset carries its settings in the attribute ``world_config``: the diagnosis must fit
    everything from the data, so two files that differ only there give the same report."""
    _recordings(tmp_path / "a", {})
    ingest(tmp_path / "a", tmp_path / "base.h5", chain, progress=False)
    reports = []
    for i, world in enumerate(({"effects": {"palm": {"enabled": True}}}, {"effects": {"noise": {"snr_db": -6}}})):
        path = tmp_path / f"w{i}.h5"
        shutil.copy(tmp_path / "base.h5", path)
        with h5py.File(path, "a") as h5:
            h5.attrs["world_config"] = json.dumps(world)
        data = load_dataset(path)
        cfg = DiagnosisConfig(candidates=["antenna_pattern", "palm", "noise"], radarweightnet=False, n_boot=200)
        rep = diagnose(data, builder(data.radar, data.chain), {}, cfg, progress=False).report
        rep.pop("timings_s")
        reports.append(json.dumps(rep, sort_keys=True))
    assert reports[0] == reports[1]
    for f in GAP_SRC.glob("*.py"):  # and no diagnosis module names it
        assert "world_config" not in f.read_text() or f.name == "benchmark.py", f.name
