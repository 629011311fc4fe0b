"""MLflow tracking for every job (train.py, diagnose.py): one run per job, safe for parallel jobs on one SQLite store.

Parallel sweep jobs (joblib, SLURM arrays on a shared file system) writing to one SQLite file
hit two known failures: the schema-migration race when several processes create a fresh
database at once, and ``database is locked`` when writers collide. Every store operation here
runs under an exclusive lock file beside the database (``<db>.lock``, ``fcntl.flock``) with
SQLAlchemy's NullPool (no connection outlives its operation), so exactly one process touches
the file at a time; a short retry on ``database is locked`` covers writers that do not take the
lock (an ``mlflow ui`` reading the store). Stores that are not SQLite files (an MLflow server)
need no lock.

:class:`Tracker` is picklable (the client is created lazily), so Lightning's ddp_spawn can carry
it into worker processes through :class:`handradar.training.TrackerLogger`. :func:`tracked_run`
is the one place a job's run starts and ends. This module does
not import torch or Lightning (the table builder and the tests' worker processes start fast).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from handradar.atomic import file_lock
from handradar.provenance import machine, read_source
from handradar.runs.hydra import invocation

log = logging.getLogger(__name__)
T = TypeVar("T")

MAX_PARAM_LEN = 500  # MLflow's limit on a parameter value
TAG_PREFIX = "handradar."
# MLflow 3's UI shows an experiment as GenAI or as model training. Releases that read the experiment's kind take
# it from this tag; later ones (3.17: mlflow/server/js) ignore it for a sidebar switch kept in the browser, GenAI
# unless a link says otherwise: DASHBOARD_VIEW.
EXPERIMENT_KIND_TAG, MODEL_TRAINING = "mlflow.experimentKind", "custom_model_development"
DASHBOARD_VIEW = "workflowType=machine_learning"


def sqlite_path(tracking_uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` URI (None for other stores)."""
    prefix = "sqlite:///"
    return Path(tracking_uri[len(prefix):]) if tracking_uri.startswith(prefix) else None


def store_exists(tracking_uri: str) -> bool:
    """False for a SQLite store whose file is not there yet: a reader must not create it (any other store: True)."""
    db = sqlite_path(tracking_uri)
    return db is None or db.is_file()


def flatten(obj: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(obj, Mapping):
        out: dict[str, Any] = {}
        for k, v in obj.items():
            out.update(flatten(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: obj}


class Tracker:
    """One MLflow run. ``enabled=False`` makes every call a no-op (logger=none)."""

    def __init__(self, tracking_uri: str, experiment_name: str, *, artifact_location: str | None = None,
                 enabled: bool = True, retries: int = 8) -> None:
        self.tracking_uri = tracking_uri
        self.experiment_name = experiment_name
        self.artifact_location = artifact_location
        self.enabled = enabled
        self.retries = retries
        self.run_id: str | None = None
        self._client = None

    # -- plumbing ------------------------------------------------------------------------------
    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_client"] = None
        return state

    def _lock_path(self) -> Path | None:
        db = sqlite_path(self.tracking_uri)
        return None if db is None else db.with_name(db.name + ".lock")

    def _call(self, fn: Callable[[Any], T]) -> T:
        """Run ``fn(client)`` under the store lock, retrying a locked database."""
        delay = 0.05
        for attempt in range(self.retries + 1):
            try:
                with file_lock(self._lock_path()):
                    if self._client is None:
                        self._client = self._make_client()
                    return fn(self._client)
            except Exception as exc:  # MlflowException / OperationalError wrap the SQLite error
                if "database is locked" not in str(exc) or attempt == self.retries:
                    raise
                log.warning("MLflow store busy (%s); retrying in %.2f s", exc, delay)
                time.sleep(delay)
                delay = min(delay * 2, 2.0)
        raise AssertionError("unreachable")

    def _make_client(self):
        # NullPool: a pooled connection would keep the SQLite file open (and possibly locked)
        # between our serialised operations.
        os.environ.setdefault("MLFLOW_SQLALCHEMYSTORE_POOLCLASS", "NullPool")
        os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
        from mlflow import MlflowClient

        db = sqlite_path(self.tracking_uri)
        if db is not None:
            db.parent.mkdir(parents=True, exist_ok=True)
        return MlflowClient(tracking_uri=self.tracking_uri)

    # -- run life cycle -----------------------------------------------------------------------
    def start(self, *, run_id: str | None = None, run_name: str | None = None,
              tags: Mapping[str, str] | None = None) -> str | None:
        """Resume ``run_id`` when it exists in the store (an interrupted job), else create a run."""
        if not self.enabled:
            return None

        def start(client) -> str:
            if run_id is not None:
                try:
                    run = client.get_run(run_id)
                    if run.info.lifecycle_stage == "active":
                        client.update_run(run_id, status="RUNNING")
                        return run_id
                except Exception:  # the store was cleared: start afresh
                    pass
            exp = client.get_experiment_by_name(self.experiment_name)
            if exp is None:
                location = None if self.artifact_location is None else Path(self.artifact_location).resolve().as_uri()
                exp_id = client.create_experiment(self.experiment_name, artifact_location=location,
                                                  tags={EXPERIMENT_KIND_TAG: MODEL_TRAINING})
            else:
                exp_id = exp.experiment_id
                if exp.tags.get(EXPERIMENT_KIND_TAG) != MODEL_TRAINING:  # stores made before the tag existed
                    client.set_experiment_tag(exp_id, EXPERIMENT_KIND_TAG, MODEL_TRAINING)
            return client.create_run(exp_id, run_name=run_name, tags=dict(tags or {})).info.run_id

        self.run_id = self._call(start)
        return self.run_id

    def end(self, status: str = "FINISHED") -> None:
        if self.enabled and self.run_id is not None:
            self._call(lambda c: c.set_terminated(self.run_id, status=status))

    # -- logging ------------------------------------------------------------------------------
    def log_params(self, params: Mapping[str, Any]) -> None:
        """Flattened (``a.b.c``) parameters; values longer than MLflow's limit are cut.

        MLflow refuses to change a logged parameter, and a resumed run logs its config again: keys
        already present are skipped (a changed value, e.g. a moved data file, is only warned about).
        """
        if not self.enabled:
            return
        from mlflow.entities import Param

        flat = {k: str(v)[:MAX_PARAM_LEN] for k, v in flatten(params).items()}
        existing = self._call(lambda c: c.get_run(self.run_id).data.params)
        changed = sorted(k for k, v in flat.items() if k in existing and existing[k] != v)
        if changed:
            log.warning("MLflow run %s keeps its first values of %s", self.run_id, changed)
        items = [Param(k, v) for k, v in sorted(flat.items()) if k not in existing]
        for i in range(0, len(items), 100):  # MLflow's batch limit for params
            self._call(lambda c, chunk=items[i:i + 100]: c.log_batch(self.run_id, params=chunk))

    def set_tags(self, tags: Mapping[str, Any]) -> None:
        if not self.enabled:
            return
        from mlflow.entities import RunTag

        items = [RunTag(k, str(v)) for k, v in tags.items()]
        self._call(lambda c: c.log_batch(self.run_id, tags=items))

    def log_metrics(self, metrics: Mapping[str, float], step: int | None = None) -> None:
        if not self.enabled or not metrics:
            return
        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        items = [Metric(k, float(v), now, int(step or 0)) for k, v in metrics.items()
                 if v is not None and math.isfinite(float(v))]
        for i in range(0, len(items), 1000):
            self._call(lambda c, chunk=items[i:i + 1000]: c.log_batch(self.run_id, metrics=chunk))

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        if self.enabled:
            self._call(lambda c: c.log_artifact(self.run_id, str(path), artifact_path))

    def log_dataset(self, name: str, digest: str, source: str | Path, context: str = "training") -> None:
        """The run's input data as an MLflow dataset input (the UI's Dataset column): its name, content
        digest and location."""
        if not self.enabled:
            return
        from mlflow.entities import Dataset, DatasetInput, InputTag

        ds = Dataset(name=name, digest=digest, source_type="local", source=json.dumps({"uri": str(source)}))
        item = DatasetInput(ds, tags=[InputTag("mlflow.data.context", context)])
        self._call(lambda c: c.log_inputs(self.run_id, datasets=[item]))

    def log_dict(self, obj: Any, name: str) -> None:
        if self.enabled:
            self._call(lambda c: c.log_dict(self.run_id, obj, name))


def dashboard_links(tracking_uri: str, base_url: str) -> dict[str, str]:
    """{experiment name: its page in the MLflow dashboard serving ``tracking_uri`` at ``base_url``, opened as
    model training} for every experiment of the store but MLflow's own ``Default`` (none before the first run)."""
    if not store_exists(tracking_uri):
        return {}
    exps = Tracker(tracking_uri, "")._call(lambda c: c.search_experiments())
    return {e.name: f"{base_url.rstrip('/')}/#/experiments/{e.experiment_id}?{DASHBOARD_VIEW}"
            for e in sorted(exps, key=lambda e: e.name) if e.name != "Default"}


@dataclass(frozen=True)
class DataRef:
    """The dataset a run reads: a readable name, its content digest, where it lies and, for a folder that
    recorded it, the command that wrote it (handradar.provenance.read_source)."""

    name: str
    digest: str
    path: Path
    source: str | None = None

    @classmethod
    def of(cls, data_cfg: Mapping | None, path: str | Path, digest: str) -> DataRef:
        """Named after the recordings folder (``data.root``) or the file (``data.path``) a job was
        pointed at, else after the file itself (the reference world's cached dataset)."""
        d = dict(data_cfg or {})
        label = Path(str(d["root"])).name if d.get("root") else Path(str(d.get("path") or path)).stem
        return cls(label, digest, Path(path), read_source(d["root"]) if d.get("root") else None)

    def run_name(self, preset: str, seed: int) -> str:
        """``<preset>-<data>-seed<seed>``: runs of one preset on several data sets are told apart."""
        return f"{preset}-{self.name}-seed{seed}"


@contextlib.contextmanager
def tracked_run(tracker: Tracker, *, run_name: str, tags: Mapping[str, Any], config: Mapping | None = None,
                run_id: str | None = None, dataset: DataRef | None = None) -> Iterator[str | None]:
    """A job's MLflow run: started (or resumed when ``run_id`` is in the store) with ``handradar.``
    tags, the resolved ``config`` (params + ``config.yaml``) and its ``dataset`` as an input, ended
    FINISHED, or KILLED / FAILED when the job raises. Yields the run id (None for a disabled tracker).
    Every run also gets ``command`` (the Hydra job's command line, when there is one), ``machine`` and, where its
    data folder recorded it, ``data_source`` tags unless ``tags`` gives them: what ``make tables`` prints beside
    each result."""
    where = {"machine": machine(), **({"command": cmd} if (cmd := invocation()) else {}),
             **({"data_source": dataset.source} if dataset is not None and dataset.source else {})}
    prefixed = {f"{TAG_PREFIX}{k}": str(v) for k, v in {**where, **tags}.items()}
    rid = tracker.start(run_id=run_id, run_name=run_name, tags=prefixed)
    if tracker.enabled:
        tracker.set_tags(prefixed)  # a resumed run keeps its first tags otherwise
        if config is not None:
            tracker.log_params(config)
            tracker.log_dict(dict(config), "config.yaml")
        if dataset is not None and rid != run_id:  # a new run (a resumed one has its input)
            tracker.log_dataset(dataset.name, dataset.digest, dataset.path)
    try:
        yield rid
    except BaseException as exc:
        with contextlib.suppress(Exception):
            tracker.end("KILLED" if isinstance(exc, KeyboardInterrupt) else "FAILED")
        raise
    tracker.end("FINISHED")


if __name__ == "__main__":  # make mlflow-ui: the links to open before the dashboard starts
    import sys

    for name, url in dashboard_links(*sys.argv[1:3]).items():
        print(f"{name}: {url}")
