"""Paper-style tables from MLflow runs (experiments/tables.py) and from one job (report.job_table); what a
published row says about where its figures come from."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.stats

from experiments import tables
from handradar.runs.mlflow import Tracker
from handradar.runs.tables import (
    DIRTY_NOTE,
    build_tables,
    group_runs,
    job_overrides,
    job_table,
    mean_std,
    provenance,
    published_command,
    results_markdown,
    stats,
)


def test_stats_and_cells():
    m, s, n = stats([0.5, 0.6, 0.7])
    assert (m, n) == (pytest.approx(0.6), 3) and s == pytest.approx(0.1)
    assert mean_std([0.5, 0.6, 0.7]) == "0.600 ± 0.100 (n=3)"
    assert mean_std([0.25]) == "0.250" and mean_std([]) == "–"
    assert mean_std([0.1, 0.3], signed=True) == "+0.200 ± 0.141 (n=2)" and mean_std([-0.1], signed=True) == "-0.100"
    assert math.isnan(stats([1.0])[1])


def _few(fraction: float, test: str = "remainder") -> dict:
    return {"job": "variants", "split.kind": "few_shot", "split.fraction": str(fraction), "split.test": test}


def test_build_tables_layout():
    records = [
        {"params": _few(0.05), "metrics": {"test/acc_radar_only": 0.4, "test/acc_model_synth": 0.6}},
        {"params": _few(0.05), "metrics": {"test/acc_radar_only": 0.5, "test/acc_model_synth": 0.7}},
        {"params": _few(0.2), "metrics": {"test/acc_radar_only": 0.8}},
        {"params": _few(0.05, "fixed"), "metrics": {"test/acc_cgan": 0.3}},
        {"params": {"job": "variants", "split.kind": "ood", "split.ood": "hands"}, "metrics": {"test/acc_enhanced_synth": 0.55}},
        {"params": {"job": "external_pretrain"}, "metrics": {"test/acc_scratch_10c_5pct": 0.3,
                                                             "test/acc_pretrained_10c_5pct": 0.5,
                                                             "test/acc_pretrained_5c_10pct": 0.9}},
    ]
    t2, t3, t4 = build_tables(records)
    assert t2.sorted_rows() == ["5 %", "20 %", "5 %*"]
    md = t2.markdown()
    assert "| 5 % | 0.450 ± 0.071 (n=2) | 0.650 ± 0.071 (n=2) | – | – |" in md
    assert "| 5 %* | – | – | – | 0.300 |" in md
    assert t3.sorted_rows() == ["10 classes, 5 % (external)", "5 classes, 10 % (external)"]
    assert "| 10 classes, 5 % (external) | 0.300 | 0.500 | +0.200 |" in t3.markdown()
    assert "| 5 classes, 10 % (external) | – | 0.900 | – |" in t3.markdown()  # no scratch arm: no difference
    assert t4.sorted_rows() == ["hands (single → double)"]
    rows = list(csv.reader(io.StringIO(t2.csv())))
    assert rows[0][:4] == ["row", "Radar only mean", "Radar only std", "Radar only n"]
    assert rows[1][:4] == ["5 %", "0.4500", "0.0707", "2"]
    # jobs whose synthetic rows come from a fitted or randomised simulator get rows of their own
    fitted = build_tables([{"params": {**_few(0.05, "fixed"), "synth.fit_sim": "effects"}, "metrics": {"test/acc_model_synth": 0.6}},
                           {"params": {**_few(0.05, "fixed"), "synth.fit_sim": "none"}, "metrics": {"test/acc_model_synth": 0.2}},
                           {"params": {**_few(0.05, "fixed"), "synth.fit_sim": "effects", "synth.samples_per_row": "2",
                                       "synth.randomize.rcs_exponent": "0.1"}, "metrics": {"test/acc_model_synth": 0.4}},
                           {"params": {**_few(0.05, "fixed"), "synth.fit_sim": "effects", "synth.rwn_folds": "2"},
                            "metrics": {"test/acc_enhanced_synth": 0.5}}])[0]
    assert sorted(fitted.sorted_rows()) == ["5 %*", "5 %* [fitted: effects, 2 draws]",
                                            "5 %* [fitted: effects, RadarWeightNet guarded, 2 folds]",
                                            "5 %* [fitted: effects]"]
    # two jobs of the same row and seed (other variants: other job hashes): the latest, listed first, counts
    twice = build_tables([{"params": {**_few(0.05, "fixed"), "seed": "1"}, "metrics": {"test/acc_radar_only": 0.3}},
                          {"params": {**_few(0.05, "fixed"), "seed": "1"}, "metrics": {"test/acc_radar_only": 0.9}},
                          {"params": {**_few(0.05, "fixed"), "seed": "2"}, "metrics": {"test/acc_radar_only": 0.5}}])[0]
    assert "| 5 %* | 0.400 ± 0.141 (n=2) |" in twice.markdown()
    # other data than the default world: rows of their own, never averaged with (or replacing) the world's
    rec = "handradar.data.datasets.RecordingsFolder"
    (other,) = build_tables([{"params": {**_few(0.05, "fixed"), "seed": "1"}, "metrics": {"test/acc_radar_only": 0.3}},
                             {"params": {**_few(0.05, "fixed"), "seed": "1", "data.dataset._target_": rec,
                                         "data.dataset.root": "/data/mine"}, "metrics": {"test/acc_radar_only": 0.9}},
                             {"params": {**_few(0.05, "fixed"), "seed": "1", "data.dataset.world.seed": "101"},
                              "metrics": {"test/acc_radar_only": 0.7}}])
    assert sorted(other.sorted_rows()) == ["5 %*", "5 %* {recordings: mine}", "5 %* {world: seed 101}"]
    # a world is named by the job's Hydra choice (tag), whatever its seed
    (tagged,) = build_tables([{"params": {**_few(0.05, "fixed")}, "tags": {"handradar.world": "strong_jitter"},
                               "metrics": {"test/acc_radar_only": 0.3}}])
    assert tagged.sorted_rows() == ["5 %* {world: strong_jitter}"]
    assert "| 5 %* | 0.300 |" in other.markdown()
    # Table III: a row per simulator; the difference is paired within each seed's job; the latest job of a seed counts
    def pre(seed: str, fit: str, scratch: float, pretrained: float) -> dict:
        return {"params": {"job": "external_pretrain", "pretrain.source": "sfinge3d", "seed": seed, "synth.fit_sim": fit},
                "metrics": {"test/acc_scratch_10c_5pct": scratch, "test/acc_pretrained_10c_5pct": pretrained}}
    (t3,) = build_tables([pre("1", "effects", 0.2, 0.5), pre("2", "effects", 0.4, 0.5), pre("1", "effects", 0.9, 0.9),
                          pre("1", "none", 0.2, 0.1)])
    assert t3.sorted_rows() == ["10 classes, 5 % (sfinge3d)", "10 classes, 5 % (sfinge3d) [fitted: effects]"]
    assert "| 10 classes, 5 % (sfinge3d) [fitted: effects] | 0.300 ± 0.141 (n=2) | 0.500 ± 0.000 (n=2) | +0.200 ± 0.141 (n=2) |" in t3.markdown()
    assert "| 10 classes, 5 % (sfinge3d) | 0.200 | 0.100 | -0.100 |" in t3.markdown()
    # one job's table (what train.py prints)
    assert job_table(_few(0.5), {"test/acc_radar_only": 0.9}).endswith("| 50 % | 0.900 | – | – | – | – | – | – |")


def _log_run(tracker_uri: str, preset: str, params: dict, metrics: dict, job_hash: str, status: str = "FINISHED",
             confusion: np.ndarray | None = None, tmp: Path | None = None) -> None:
    t = Tracker(tracker_uri, preset, artifact_location=str(tmp / "artifacts"))
    t.start(tags={"handradar.preset": preset, "handradar.job_hash": job_hash})
    t.log_params(params)
    t.log_metrics(metrics)
    if confusion is not None:
        f = tmp / f"{job_hash}-radar_only.json"
        f.write_text(json.dumps({"classes": ["a", "b"], "matrix": confusion.tolist()}))
        (tmp / "radar_only.json").write_text(f.read_text())
        t.log_artifact(tmp / "radar_only.json", "confusion")
    t.end(status)


def test_tables_from_mlflow_runs(tmp_path: Path):
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    p = {"job": "variants", "split": {"kind": "few_shot", "fraction": 0.2, "test": "remainder"}}
    for seed, acc in enumerate([0.5, 0.6, 0.7]):
        _log_run(uri, "few_shot_20pct", p, {"test/acc_radar_only": acc}, f"h{seed}", confusion=np.array([[3, 1], [0, 4]]),
                 tmp=tmp_path)
    _log_run(uri, "few_shot_20pct", p, {"test/acc_radar_only": 0.0}, "h9", status="FAILED", tmp=tmp_path)  # ignored
    _log_run(uri, "few_shot_20pct", p, {"test/acc_radar_only": 0.1}, "h0", tmp=tmp_path)  # a newer run of job h0
    ood = {"job": "variants", "split": {"kind": "ood", "ood": "angle"}}
    _log_run(uri, "ood_angle", ood, {"test/acc_model_synth": 0.42}, "o1", tmp=tmp_path)
    _log_run(uri, "unrelated", {"x": 1}, {"test/acc_radar_only": 0.99}, "u", tmp=tmp_path)  # not a handradar preset row
    curve = {"job": "variants", "task_name": "data_efficiency", "seed": 1, "synth": {"fit_sim": "effects"},
             "split": {"kind": "few_shot", "per_class": 1, "test": "fixed"}}
    _log_run(uri, "data_efficiency", curve, {"test/acc_radar_only": 0.15, "test/acc_model_synth": 0.6}, "d1",
             tmp=tmp_path)
    mine = {**curve, "data": {"dataset": {"_target_": "handradar.data.datasets.RecordingsFolder", "root": "/d/mine"}}}
    _log_run(uri, "data_efficiency", mine, {"test/acc_radar_only": 0.11}, "d2", tmp=tmp_path)

    out = tmp_path / "results"
    md = tables.main(["--tracking-uri", uri, "--out", str(out), "--doc", str(tmp_path / "results.md")])
    text = md.read_text()
    # job h0 counts once, with its latest run (0.1): mean of 0.1, 0.6, 0.7
    assert "| 20 % | 0.467 ± 0.321 (n=3) |" in text
    assert "| angle (0° → ±30°) | – | 0.420 | – | – |" in text
    assert "Table III" not in text
    # the data-efficiency runs again as the curve (the same runs as Table II's "1 per class*" row)
    assert "## Data efficiency\n" in text and "| + synthetic (fitted simulator) | 0.600 |" in text
    # a curve on recordings gets a section of its own
    assert "## Data efficiency on {recordings: mine}" in text and "| radar only | 0.110 |" in text
    assert (out / "table2_few_shot.csv").is_file() and (out / "table4_ood.csv").is_file()
    png = out / "confusion" / "few_shot_20pct_radar_only.png"
    assert png.stat().st_size > 1000


def test_tables_without_runs(tmp_path: Path):
    md = tables.main(["--tracking-uri", f"sqlite:///{tmp_path}/empty.db", "--out", str(tmp_path / "r"), "--no-figures",
                      "--doc", str(tmp_path / "results.md")])
    assert "no finished train.py jobs" in md.read_text()
    assert not (tmp_path / "empty.db").exists()  # reading never creates a store


def _tags(seed: int, commit: str = "2381649e5089", **extra) -> dict:
    return {"handradar.seed": str(seed), "handradar.code_version": f"0.1.0+g{commit}", "handradar.preset": "few_shot_5pct",
            **extra}


def test_results_markdown_names_command_commit_seeds_and_machine_of_every_row():
    """docs/results.md from synthetic records: each row lists the runs behind it, seeds folded into one multirun."""
    cmd = "python train.py +experiment=few_shot_5pct 'variants=[radar_only,model_synth]' seed={}"
    machine = "x86_64, 2 CPUs, no GPU"
    records = [{"params": _few(0.05), "metrics": {"test/acc_radar_only": 0.4 + 0.1 * s},
                "provenance": provenance(_tags(s, **{"handradar.command": cmd.format(s), "handradar.machine": machine}), {})}
               for s in (1, 2, 3)]
    # a run logged before the command tag: its Hydra overrides, else its preset and seed (said so)
    records.append({"params": _few(0.2), "metrics": {"test/acc_radar_only": 0.8},
                    "provenance": provenance(_tags(7, "00005318c9ed"), {}, ["+experiment=few_shot_20pct", "seed=7"])})
    records.append({"params": _few(0.5), "metrics": {"test/acc_radar_only": 0.9},
                    "provenance": provenance(_tags(4, "abcdef123456"), {})})
    md = results_markdown(build_tables(records), "`logs/mlflow/mlflow.db` (5 jobs)")
    lines = md.splitlines()
    assert lines[0] == "# handradar results" and "Generated by `make tables`" in md
    assert "| 5 % | 0.600 ± 0.100 (n=3) | – | – | – | – | – | – |" in lines
    assert ("- 5 %: `python train.py -m +experiment=few_shot_5pct 'variants=[radar_only,model_synth]' seed=1,2,3` "
            "at `2381649`, seeds 1, 2, 3, x86_64, 2 CPUs, no GPU") in lines
    assert "- 20 %: `python train.py +experiment=few_shot_20pct seed=7` at `0000531`, seed 7, machine not recorded" in lines
    assert ("- 50 %: `python train.py +experiment=few_shot_5pct seed=4` at `abcdef1`, seed 4, machine not recorded "
            "(command reconstructed from the run's tags)") in lines
    # runs of one row at two commits stay apart: a figure is never credited to code that did not make it
    mixed = group_runs([provenance(_tags(1, "aaaaaaa1"), {}, ["seed=1"]), provenance(_tags(2, "bbbbbbb2"), {}, ["seed=2"])])
    assert [(g["commit"], g["seeds"]) for g in mixed] == [("aaaaaaa", ["1"]), ("bbbbbbb", ["2"])]
    # where outputs and caches went is not part of a command (the job hash leaves paths out)
    moved = group_runs([provenance(_tags(s, **{"handradar.command": f"python train.py paths.log_dir=/x/logs seed={s}"}),
                                   {}) for s in (1, 2)])
    assert [g["command"] for g in moved] == ["python train.py -m seed=1,2"]
    assert "(no finished train.py jobs found)" in results_markdown([], "x")


def test_command_of_an_old_run_comes_from_its_run_folder(tmp_path: Path):
    (tmp_path / ".hydra").mkdir()
    (tmp_path / ".hydra" / "overrides.yaml").write_text("- +experiment=ood_hands\n- seed=2\n")
    assert job_overrides({"handradar.run_dir": str(tmp_path)}) == ["+experiment=ood_hands", "seed=2"]
    assert job_overrides({"handradar.run_dir": str(tmp_path / "gone")}) is None
    assert job_overrides({}) is None


def test_a_published_row_names_its_data_by_how_to_make_them_never_by_a_path():
    """A command's data folder on the machine that ran it reads DIR, said how to make by the command that
    wrote it (the run's handradar.data_source tag); where outputs and caches went is left out."""
    heldout = {**_few(0.05, "fixed"), "data.dataset._target_": "handradar.data.datasets.RecordingsFolder",
               "data.dataset.root": "/work/recs/heldout"}
    mine = {**heldout, "data.dataset.root": "/home/me/captures"}
    cmd = ("python train.py +experiment=few_shot_5pct data=recordings data.root={} paths.log_dir=/work/main/logs "
           "'hydra.run.dir=/tmp/x y' seed={}")
    written = "handradar-world world=heldout out=DIR"
    records = [{"params": heldout, "metrics": {"test/acc_radar_only": 0.5 + s / 10},
                "provenance": provenance(_tags(s, **{"handradar.command": cmd.format("/work/recs/heldout", s),
                                                     "handradar.data_source": written}), heldout)} for s in (1, 2)]
    records.append({"params": mine, "metrics": {"test/acc_radar_only": 0.3},
                    "provenance": provenance(_tags(1, **{"handradar.command": cmd.format("/home/me/captures", 1)}),
                                             mine)})
    md = results_markdown(build_tables(records), "x")
    assert "/work/" not in md and "/home/" not in md and "/tmp/" not in md
    lines = md.splitlines()
    assert ("- 5 %* {recordings: heldout}: `python train.py -m +experiment=few_shot_5pct data=recordings data.root=DIR "
            "seed=1,2` (DIR: written by `handradar-world world=heldout out=DIR`) at `2381649`, seeds 1, 2, "
            "machine not recorded") in lines
    assert ("- 5 %* {recordings: captures}: `python train.py +experiment=few_shot_5pct data=recordings data.root=DIR "
            "seed=1` (DIR: its source not recorded) at `2381649`, seed 1, machine not recorded") in lines
    # a file keeps its name; a relative path (the repository's own) and the rest of the command stay as they are
    assert (published_command("python -m benchmarks.case_folders /work/recs/s36 'benchmark.folders=/w/m/folders.yaml' "
                              "out=data/world '+benchmark.world={subjects: 1}'")
            == "python -m benchmarks.case_folders DIR benchmark.folders=DIR/folders.yaml out=data/world "
               "'+benchmark.world={subjects: 1}'")


def test_a_row_from_a_dirty_tree_is_marked_in_the_table():
    records = [{"params": _few(0.05), "metrics": {"test/acc_radar_only": 0.4},
                "provenance": provenance(_tags(1, "2381649e5089.dirty"), {})},
               {"params": _few(0.05), "metrics": {"test/acc_radar_only": 0.6},
                "provenance": provenance(_tags(2), {})},
               {"params": _few(0.2), "metrics": {"test/acc_radar_only": 0.8}, "provenance": provenance(_tags(1), {})}]
    (few,) = build_tables(records)
    lines = few.markdown().splitlines()
    assert "| 5 % † | 0.500 ± 0.141 (n=2) | – | – | – | – | – | – |" in lines
    assert "| 20 % | 0.800 | – | – | – | – | – | – |" in lines
    assert lines[-1] == DIRTY_NOTE and "`2381649.dirty`" in results_markdown([few], "x")
    assert DIRTY_NOTE not in build_tables(records[1:])[0].markdown()  # a clean table carries no note


def test_measured_rows_per_split_and_k():
    """A measured job's metrics become rows "K per class, <split> {measured: <manifest>}", one column a variant; which
    variants, splits and K come from its parameters, not from the metric names."""
    p = {"job": "handradar.tasks.measured.run_measured", "measured.per_class": "8", "seed": "1",
         "measured.variants": "radar_only,model_synth,model_synth_only", "measured.tests": "A,B",
         "measured.setting": "s1", "data.dataset._target_": "handradar.data.measured.MeasuredDataset",
         "data.dataset.manifest": "/any/where/xia2021.yaml"}
    metrics = {"test/acc_radar_only_A": 0.5, "test/acc_radar_only_B": 0.6, "test/acc_model_synth_only_A": 0.25,
               "test/acc_model_synth_B": 0.7, "val/acc_radar_only": 0.9}
    text = job_table(p, metrics)
    assert "| 8 per class, A {measured: xia2021} | 0.500 | – | – | 0.250 |" in text
    assert "| 8 per class, B {measured: xia2021} | 0.600 | 0.700 | – | – |" in text
    assert "/any/where" not in text and "0.900" not in text  # validation is for choosing, not for the table
    tables = build_tables([{"params": {**p, "measured.per_class": "all"}, "metrics": {"test/acc_radar_only_A": 0.7}},
                           {"params": p, "metrics": metrics}])
    rows = tables[0].sorted_rows()
    assert rows.index("8 per class, A {measured: xia2021}") < rows.index("all per class, A {measured: xia2021}")


def test_measured_gain_is_paired_by_seed_with_its_interval():
    """Each synthetic variant's gain over radar only is the difference within each job (same seed and rows), with a
    95 % Student-t interval over the seeds; a job of another setting gets rows of its own, never mixed in, even when
    it is the latest (the setting most runs share keeps the plain rows)."""
    def job(seed: int, base: float, synth: float, setting: str = "s1") -> dict:
        p = {"job": "handradar.tasks.measured.run_measured", "measured.per_class": "1", "seed": str(seed),
             "measured.variants": "radar_only,model_synth", "measured.tests": "A", "measured.setting": setting,
             "data.dataset._target_": "handradar.data.measured.MeasuredDataset", "data.dataset.manifest": "x.yaml"}
        return {"params": p, "metrics": {"test/acc_radar_only_A": base, "test/acc_model_synth_A": synth}}

    records = [job(1, 0.9, 0.1, setting="s0"), job(1, 0.30, 0.40), job(2, 0.50, 0.55), job(3, 0.40, 0.45)]
    gain = next(t for t in build_tables(records) if t.name == "measured_gain")
    diffs = [0.10, 0.05, 0.05]
    half = scipy.stats.t.ppf(0.975, 2) * np.std(diffs, ddof=1) / np.sqrt(3)
    cell = f"+{np.mean(diffs):.3f} [{np.mean(diffs) - half:+.3f}, +{np.mean(diffs) + half:.3f}] (n=3)"
    assert f"| 1 per class, A {{measured: x}} | {cell} | – | – |" in gain.markdown()
    assert "| 1 per class, A {measured: x} [setting s0] | -0.800 (n=1) | – | – |" in gain.markdown()