"""Compact benchmark records and the summary table ``make gap-report`` renders from them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from experiments.gap_report import main as gap_report
from handradar.errors import FormatError
from handradar.gap.records import (
    benchmark_record,
    load_records,
    record_name,
    summary_markdown,
    validate_record,
)
from handradar.provenance import commit_of
from handradar.runs.tables import DIRTY_NOTE, dirty, published_command

REPO = Path(__file__).resolve().parents[2]


def _record(world: str, size: int, palm_cause: str = "palm", version: str = "0.1.0+gabc123def456", **extra) -> dict:
    results = [{"case": "palm", "truth": "palm", "cause": palm_cause, "correct": palm_cause == "palm",
                "true_gap_closed": 0.125, "true_ci95": [0.1, 0.15], "true_rank": 1, "top_candidate": "palm",
                "top_gap_closed": 0.125, "recordings_needed": 620 if palm_cause == "inconclusive" else None, "rows": size},
               {"case": "nothing", "truth": "none", "cause": "none", "correct": True, "true_gap_closed": None, "rows": size}]
    scores = {"effects_correct": int(palm_cause == "palm"), "effects_total": 1, "controls_correct": 1, "controls_total": 1,
              "effects_inconclusive": int(palm_cause == "inconclusive"), "controls_inconclusive": 0,
              "mean_true_gap_closed": 0.125, "mean_after_gap_closed": 0.1}
    settings = {"code_version": version, "seed": 3, "minutes": 12.34, "threads": 2, "rows": size}
    rec = benchmark_record(results, scores, settings, world=world, size=size, world_version="world/3",
                           machine="x86_64, 2 CPUs, no GPU", command=f"python diagnose.py world={world}")
    return {**rec, **extra}


def test_record_keeps_provenance_and_each_verdict():
    r = _record("heldout", 36, "inconclusive", "0.1.0+gabc123def456.dirty")
    assert validate_record(r, "x") is r and record_name(r) == "heldout_36.json"
    assert (r["commit"], r["seeds"], r["wall_min"], r["world_version"]) == ("abc123d.dirty", [3], 12.3, "world/3")
    assert r["cases"][0]["cause"] == "inconclusive" and r["cases"][0]["recordings_needed"] == 620
    assert "rows" not in r["cases"][0]  # only what the table needs
    assert commit_of("0.1.0") == "0.1.0" and commit_of("0.1.0+gf6f3eb43bb4e") == "f6f3eb4"


def test_summary_table_one_column_per_run_legend_once():
    records = [_record("heldout", 36, "inconclusive"), _record("default", 240), _record("heldout2", 36, "occlusion"),
               _record("heldout", 240, "none", variants=[{"name": "one_split", "what": "one split", "command": "cmd v",
                                                           "commit": "1234567", "world_version": "world/2",
                                                           "scores": {"effects_correct": 0, "effects_total": 1,
                                                                      "controls_correct": 1, "controls_total": 1,
                                                                      "effects_inconclusive": 1,
                                                                      "controls_inconclusive": 0}}])]
    md = summary_markdown(sorted(records, key=lambda r: (-r["size"], r["world"] != "default")))
    lines = md.splitlines()
    assert "| case (truth) | default 240 | heldout 240 | heldout 36 | heldout2 36 |" in lines
    # palm is judged "must not mislead": none, or inconclusive leading with it, is found but undecided
    assert ("| palm (palm) | ✓ (+0.125) | (✓) none (+0.125) | (✓) inconclusive ~620 (+0.125) "
            "| ✗ occlusion (+0.125) |") in lines
    assert "| nothing (none) | ✓ | ✓ | ✓ | ✓ |" in lines
    assert "| **effects named** | **1 of 1** | **0 of 1** | **0 of 1** | **0 of 1** |" in lines
    assert "| **effects found** | 1 of 1 | 1 of 1 | 1 of 1 | 0 of 1 |" in lines
    assert "| **wrong causes** | **0** | **0** | **0** | **1** |" in lines
    assert md.count("(✓): found but undecided") == 1  # the legend, written once
    assert "`python diagnose.py world=heldout` at `abc123d` (world/3), seed 3, x86_64, 2 CPUs, no GPU" in md
    assert DIRTY_NOTE not in md
    assert "one split" not in md  # settings tried stay in the records (docs/gap_validation.md lists them)
    assert "(no records in somewhere)" in summary_markdown([], "somewhere")


def test_the_summary_names_no_path_and_marks_a_dirty_run():
    """A record's folders read DIR, said how to make by the command that wrote them (their manifest's first
    line); where outputs and caches went is left out; a run from a dirty tree is marked in the table."""
    folders = _record("folders-s36", 36, command="python diagnose.py +experiment=gap_benchmark "
                      "benchmark.folders=/work/recs/s36/folders.yaml paths.log_dir=/work/main/logs threads=2",
                      data_source="python -m benchmarks.case_folders /work/recs/s36 world=scatterers benchmark.size=36")
    md = summary_markdown([_record("default", 240, version="0.1.0+gabc123def456.dirty"), folders])
    assert "/work/" not in md
    assert "| case (truth) | default 240 † | folders-s36 36 |" in md.splitlines() and DIRTY_NOTE in md
    assert ("- **folders-s36 36**: `python diagnose.py +experiment=gap_benchmark benchmark.folders=DIR/folders.yaml "
            "threads=2` (DIR: written by `python -m benchmarks.case_folders DIR world=scatterers benchmark.size=36`) "
            "at `abc123d` (world/3)") in md
    # the benchmark writes the folders' source into the record it publishes
    settings = {"code_version": "0.1.0+gabc123def456", "data_source": folders["data_source"]}
    assert benchmark_record([], folders["scores"], settings, world="folders-s36", size=36, world_version="recordings",
                            machine="m", command="c")["data_source"] == folders["data_source"]


def test_no_published_record_names_a_path_or_is_from_a_dirty_tree():
    """The kept records: commands as published (handradar.runs.tables.published_command leaves them as they are),
    no run from a working tree with uncommitted changes."""
    for path in sorted((REPO / "results" / "gap_benchmark").rglob("*.json")):
        obj = json.loads(path.read_text())
        for record in [obj, *obj.get("variants", [])]:
            if "command" in record:
                assert published_command(record["command"]) == record["command"], path
        assert not dirty(obj.get("commit", "")), path


def test_load_records_orders_runs_and_names_a_bad_file(tmp_path: Path):
    for r in (_record("heldout3", 36), _record("heldout", 240), _record("default", 36), _record("default", 240)):
        (tmp_path / record_name(r)).write_text(json.dumps(r))
    assert [record_name(r) for r in load_records(tmp_path)] == ["default_240.json", "heldout_240.json",
                                                                "default_36.json", "heldout3_36.json"]
    broken = _record("heldout2", 36)
    del broken["commit"]
    (tmp_path / "heldout2_36.json").write_text(json.dumps(broken))
    with pytest.raises(FormatError, match=r"heldout2_36.json: missing commit$"):
        load_records(tmp_path)
    (tmp_path / "heldout2_36.json").write_text("{")
    with pytest.raises(FormatError, match=r"heldout2_36.json:1: not JSON \(Expecting"):
        load_records(tmp_path)


def test_gap_report_writes_the_table_and_the_published_one_is_current(tmp_path: Path, capsys):
    (tmp_path / "default_240.json").write_text(json.dumps(_record("default", 240)))
    out = gap_report(["--results", str(tmp_path), "--out", str(tmp_path / "report.md")])
    printed = capsys.readouterr().out
    assert out.read_text() in printed and printed.rstrip().endswith(str(out))
    # the kept records: the eight base runs, the scatterers world's and its 36 cases as folders, each with its command, commit and world version; docs/gap_report.md
    # is generated from them (make gap-report) and must not drift from them
    published = load_records(REPO / "results" / "gap_benchmark")
    assert {(r["world"], r["size"]) for r in published} == {(w, n) for w in ("default", "heldout", "heldout2", "heldout3")
                                                            for n in (240, 36)} | {("scatterers", 240), ("scatterers", 36),
                                                                                     ("folders-scatterers_36", 36)}
    assert all(r["command"].startswith("python diagnose.py +experiment=gap_benchmark ") for r in published)
    assert (REPO / "docs" / "gap_report.md").read_text() == summary_markdown(published)
