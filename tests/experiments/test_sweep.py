"""train.py as users run it (subprocess): multirun sweeps, parallel jobs on one MLflow store, a
failing job among others, DDP on CPU."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.tasks.fakes import fake_overrides

REPO = Path(__file__).resolve().parents[2]
PAPER_METRICS = {f"test/acc_{v}" for v in ("radar_only", "model_synth", "enhanced_synth", "model_synth_only")}


def train(args: list[str], cwd: Path, timeout: int = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO / "src"), "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, str(REPO / "train.py"), *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=env)


def _report(sweep_root: Path) -> list[dict]:
    (report,) = sweep_root.rglob("jobs.jsonl")
    return sorted((json.loads(line) for line in report.read_text().splitlines()), key=lambda e: e["num"])


def test_tiny_sweep_end_to_end(fake_data: Path, tmp_path: Path):
    out = train(["-m", "+experiment=few_shot_20pct,ood_angle", "seed=1,2", "trainer.fast_dev_run=true",
                 *fake_overrides(fake_data, tmp_path)], cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    jobs = _report(tmp_path / "logs")
    assert [j["status"] for j in jobs] == ["COMPLETED"] * 4
    assert "multirun: 4 of 4 jobs completed, 0 failed" in out.stdout
    for j in jobs:
        metrics = json.loads((Path(j["run_dir"]) / "metrics.json").read_text())
        assert set(metrics) == PAPER_METRICS and all(0 <= v <= 1 for v in metrics.values())
    # every job printed its run directory
    for j in jobs:
        assert j["run_dir"] in out.stdout


def test_failing_job_is_reported_and_others_complete(fake_data: Path, tmp_path: Path):
    missing = tmp_path / "missing.h5"
    overrides = [o for o in fake_overrides(fake_data, tmp_path) if not o.startswith("data.path")]
    out = train(["-m", "+experiment=few_shot_20pct", f"data.path={missing},{fake_data}", "trainer.fast_dev_run=true",
                 "variants=[radar_only]", *overrides], cwd=tmp_path)
    assert out.returncode != 0  # the sweep as a whole reports the failure
    jobs = _report(tmp_path / "logs")
    assert [j["status"] for j in jobs] == ["FAILED", "COMPLETED"]
    assert "dataset file not found" in jobs[0]["error"] and str(missing) in jobs[0]["error"]
    assert json.loads((Path(jobs[1]["run_dir"]) / "metrics.json").read_text())["test/acc_radar_only"] >= 0
    assert "multirun: 1 of 2 jobs completed, 1 failed" in out.stdout
    assert "FAILED" in (next((tmp_path / "logs").rglob("jobs_summary.txt"))).read_text()


def test_single_run_prints_table_and_run_dir_last(fake_data: Path, tmp_path: Path):
    out = train(["+experiment=few_shot_50pct", "trainer.fast_dev_run=true", *fake_overrides(fake_data, tmp_path),
                 "print_table=true"], cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    lines = out.stdout.strip().splitlines()
    run_dir = Path(lines[-1])
    assert (run_dir / "metrics.json").is_file()
    # the job's row of Table II (fixed test split) on its data file, its RadarWeightNet guarded by held-out rows (the default)
    assert any(line.startswith("| 50 %* {file: fake.h5} [RadarWeightNet guarded, 2 folds] |") for line in lines)


def test_single_run_bad_input_exits_with_a_clear_error(tmp_path: Path):
    out = train(["+experiment=few_shot_5pct", "data=hdf5", f"data.path={tmp_path}/nope.h5", f"paths.log_dir={tmp_path}",
                 "logger=none"], cwd=tmp_path)
    assert out.returncode == 1
    assert out.stderr.strip().splitlines()[-1] == f"error: {tmp_path}/nope.h5: dataset file not found (data.path)"


@pytest.mark.slow
def test_parallel_joblib_sweep_logs_every_run(fake_data: Path, tmp_path: Path):
    """Four jobs in four processes write to one fresh SQLite store: four complete MLflow runs."""
    out = train(["-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=4", "+experiment=few_shot_20pct",
                 "seed=1,2,3,4", "trainer.max_steps=8", "threads=1", *fake_overrides(fake_data, tmp_path, logger="mlflow")],
                cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    from mlflow import MlflowClient

    client = MlflowClient(f"sqlite:///{tmp_path}/logs/mlflow/mlflow.db")
    (exp,) = [e for e in client.search_experiments() if e.name == "few_shot_20pct"]
    runs = client.search_runs([exp.experiment_id])
    assert len(runs) == 4
    assert sorted(r.data.tags["handradar.seed"] for r in runs) == ["1", "2", "3", "4"]
    for r in runs:
        assert r.info.status == "FINISHED" and r.data.tags["handradar.world"] == "default"  # make tables: worlds apart
        assert PAPER_METRICS <= set(r.data.metrics)
        assert len(client.get_metric_history(r.info.run_id, "radar_only/train/loss")) >= 1


@pytest.mark.slow
def test_ddp_spawn_on_cpu(fake_data: Path, tmp_path: Path):
    out = train(["+experiment=few_shot_50pct", "trainer=ddp", "trainer.accelerator=cpu", "trainer.devices=2",
                 "trainer.strategy=ddp_spawn", "trainer.precision=32-true", "trainer.sync_batchnorm=false",
                 "trainer.max_steps=6",
                 "variants=[radar_only,model_synth]", *fake_overrides(fake_data, tmp_path)], cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    run_dir = Path(out.stdout.strip().splitlines()[-1])
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert set(metrics) == {"test/acc_radar_only", "test/acc_model_synth"}
    assert all(0 <= v <= 1 for v in metrics.values())
