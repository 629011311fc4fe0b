"""MLflow tracking: one run per job, resumable, picklable, and no lost run with parallel writers."""

from __future__ import annotations

import multiprocessing as mp
import pickle
from pathlib import Path

import pytest

from handradar.runs.mlflow import (
    EXPERIMENT_KIND_TAG,
    MODEL_TRAINING,
    DataRef,
    Tracker,
    dashboard_links,
    sqlite_path,
    tracked_run,
)
from handradar.provenance import machine, write_source
from handradar.training import TrackerLogger


def _client(uri: str):
    from mlflow import MlflowClient

    return MlflowClient(tracking_uri=uri)


def test_run_life_cycle_and_resume(tmp_path: Path):
    uri = f"sqlite:///{tmp_path}/mlflow/mlflow.db"
    t = Tracker(uri, "exp-a", artifact_location=str(tmp_path / "artifacts"))
    run_id = t.start(run_name="job", tags={"handradar.preset": "x"})
    t.log_params({"model": {"lr": 0.001, "name": "resnet18"}, "long": "y" * 900})
    t.log_metrics({"a/train/loss": 1.5, "nan": float("nan")}, step=3)
    t.log_dict({"k": 1}, "config.yaml")
    t.end("FAILED")  # an interrupted job

    again = Tracker(uri, "exp-a")
    assert again.start(run_id=run_id) == run_id  # the re-run completes the same run
    again.log_params({"model": {"lr": 0.001, "name": "resnet18"}, "data": "moved.h5"})  # logged again: no error
    again.log_metrics({"test/acc": 0.75})
    again.end()
    run = _client(uri).get_run(run_id)
    assert run.info.status == "FINISHED"
    assert run.data.params["model.lr"] == "0.001" and len(run.data.params["long"]) == 500
    assert run.data.params["data"] == "moved.h5"
    assert run.data.metrics == {"a/train/loss": 1.5, "test/acc": 0.75}
    assert run.data.tags["handradar.preset"] == "x"
    assert run.info.artifact_uri.startswith((tmp_path / "artifacts").as_uri())
    assert [a.path for a in _client(uri).list_artifacts(run_id)] == ["config.yaml"]
    # an unknown run id (the store was cleared) starts a new run
    assert Tracker(uri, "exp-a").start(run_id="0" * 32) != run_id


def test_disabled_tracker_is_a_no_op(tmp_path: Path):
    t = Tracker("", "x", enabled=False)
    assert t.start() is None
    t.log_params({"a": 1})
    t.log_metrics({"b": 2.0})
    t.end()


def test_tracker_and_logger_pickle(tmp_path: Path):
    uri = f"sqlite:///{tmp_path}/m.db"
    t = Tracker(uri, "e")
    t.start()
    logger = pickle.loads(pickle.dumps(TrackerLogger(t)))  # what ddp_spawn does
    logger.log_metrics({"radar_only/train/loss": 0.5, "epoch": 2}, step=7)
    logger.log_metrics({"other": 1.0}, step=7)
    hist = _client(uri).get_metric_history(t.run_id, "radar_only/train/loss")
    assert [(m.step, m.value) for m in hist] == [(2, 0.5)]  # epoch metrics are logged against the epoch
    assert [m.step for m in _client(uri).get_metric_history(t.run_id, "other")] == [7]
    assert sqlite_path(uri) == tmp_path / "m.db" and sqlite_path("http://host:5000") is None


def _parallel_job(uri: str, k: int, n_epochs: int) -> None:
    t = Tracker(uri, f"preset-{k % 2}")  # two experiments created concurrently by two processes each
    t.start(run_name=f"job{k}", tags={"handradar.job_hash": f"h{k}"})
    t.log_params({"seed": k, "cfg": {"a": k, "b": [1, 2]}})
    for epoch in range(n_epochs):
        t.log_metrics({"radar_only/train/loss": 1.0 / (epoch + 1), "radar_only/train/acc": epoch / n_epochs}, step=epoch)
    t.log_metrics({"test/acc_radar_only": 0.5 + k / 100})
    t.end()


def test_parallel_jobs_on_a_fresh_sqlite_store_lose_no_run(tmp_path: Path):
    """Four processes start at once on a database that does not exist yet (schema creation race),
    then write concurrently ("database is locked"); every run must be complete."""
    uri = f"sqlite:///{tmp_path}/mlflow/mlflow.db"
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    procs = [ctx.Process(target=_parallel_job, args=(uri, k, 25)) for k in range(4)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(180)
    assert [p.exitcode for p in procs] == [0, 0, 0, 0]
    client = _client(uri)
    exps = {e.name: e.experiment_id for e in client.search_experiments()}
    assert {"preset-0", "preset-1"} <= set(exps)
    runs = client.search_runs([exps["preset-0"], exps["preset-1"]])
    assert len(runs) == 4
    for run in runs:
        k = int(run.data.params["seed"])
        assert run.info.status == "FINISHED"
        assert run.data.metrics["test/acc_radar_only"] == pytest.approx(0.5 + k / 100)
        assert len(client.get_metric_history(run.info.run_id, "radar_only/train/loss")) == 25


def test_a_reviewer_tells_runs_apart_in_the_dashboard(tmp_path: Path):
    """What the MLflow UI shows, read through the client: a model-training experiment, runs named after
    preset, data and seed, the data set as the run's input, and the job's tags."""
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = _client(uri)
    ids = []
    for root, digest in (("/data/lab_a", "aaaa1111"), ("/data/lab_b", "bbbb2222")):
        ref = DataRef.of({"root": root, "dataset": {"_target_": "x"}}, tmp_path / f"recordings-{digest}.h5", digest)
        with tracked_run(Tracker(uri, "diagnose"), run_name=ref.run_name("diagnose", 0), tags={"preset": "diagnose"},
                         config={"seed": 0}, dataset=ref) as rid:
            ids.append(rid)
    exp = client.get_experiment_by_name("diagnose")
    assert exp.tags[EXPERIMENT_KIND_TAG] == MODEL_TRAINING  # opens as model training, not GenAI
    runs = [client.get_run(i) for i in ids]
    assert [r.info.run_name for r in runs] == ["diagnose-lab_a-seed0", "diagnose-lab_b-seed0"]
    inputs = [r.inputs.dataset_inputs for r in runs]
    assert [(d[0].dataset.name, d[0].dataset.digest) for d in inputs] == [("lab_a", "aaaa1111"), ("lab_b", "bbbb2222")]
    assert inputs[0][0].tags[0].value == "training" and "recordings-aaaa1111.h5" in inputs[0][0].dataset.source
    assert all(r.data.tags["handradar.preset"] == "diagnose" and r.info.status == "FINISHED" for r in runs)
    # every run says what ran it (make tables prints it beside the result); outside Hydra there is no command
    assert all(r.data.tags["handradar.machine"] == machine() and "handradar.command" not in r.data.tags for r in runs)
    # a file named by data.path is named after its stem; the world's cached file after itself
    assert DataRef.of({"path": "/x/my_capture.h5"}, "/x/my_capture.h5", "d").name == "my_capture"
    assert DataRef.of({}, "/cache/world/world-0123abcd.h5", "d").name == "world-0123abcd"
    # an older store's experiment without the kind tag gets it on the next run
    client.delete_experiment_tag(exp.experiment_id, EXPERIMENT_KIND_TAG)
    assert EXPERIMENT_KIND_TAG not in client.get_experiment_by_name("diagnose").tags
    Tracker(uri, "diagnose").start(run_name="again")
    assert client.get_experiment_by_name("diagnose").tags[EXPERIMENT_KIND_TAG] == MODEL_TRAINING


def test_a_run_on_a_folder_that_says_how_it_was_made_is_tagged_with_it(tmp_path: Path):
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    folder = tmp_path / "heldout"
    folder.mkdir()
    write_source(folder, "handradar-world world=heldout out=DIR")
    ref = DataRef.of({"root": str(folder)}, tmp_path / "recordings-ab.h5", "ab")
    assert (ref.name, ref.source) == ("heldout", "handradar-world world=heldout out=DIR")
    with tracked_run(Tracker(uri, "train"), run_name="r", tags={}, dataset=ref) as rid:
        pass
    assert _client(uri).get_run(rid).data.tags["handradar.data_source"] == "handradar-world world=heldout out=DIR"
    assert DataRef.of({"root": str(tmp_path / "mine")}, tmp_path / "x.h5", "cd").source is None  # not recorded


def test_dashboard_links_open_every_experiment_as_model_training(tmp_path: Path):
    """MLflow 3.17's UI ignores the experiment's kind tag for a switch kept in the browser (GenAI unless a link
    says otherwise): make mlflow-ui prints links that open each experiment as model training."""
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    assert dashboard_links(uri, "http://127.0.0.1:5000") == {} and not (tmp_path / "mlflow.db").exists()
    for name in ("train", "diagnose"):
        Tracker(uri, name).start(run_name="r")
    ids = {e.name: e.experiment_id for e in _client(uri).search_experiments()}
    assert dashboard_links(uri, "http://127.0.0.1:5000/") == {
        name: f"http://127.0.0.1:5000/#/experiments/{ids[name]}?workflowType=machine_learning"
        for name in ("diagnose", "train")}
