"""train.py jobs in process: variants, providers, resume after a crash, external pre-training, errors."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from handradar.errors import FormatError
from handradar.tasks.train import run
from tests.tasks import fakes
from tests.tasks.fakes import compose_train, fake_overrides

FOUR = ["radar_only", "model_synth", "enhanced_synth", "cgan"]
VARIANT_METRICS = {f"test/acc_{v}" for v in (*FOUR, "synth_only", "model_synth_only", "radar_pool")}


def _state(run_dir: Path, tmp: Path, preset: str) -> Path:
    (state,) = [p for p in (tmp / "logs" / preset / "state").iterdir() if p.is_dir()]
    return state


def test_few_shot_job_end_to_end(fake_data: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture):
    fakes.CALLS.clear()
    cfg = compose_train(["+experiment=few_shot_50pct", "split.test=remainder", f"variants=[{','.join(FOUR)}]",
                         *fake_overrides(fake_data, tmp_path), "trainer.max_steps=30", "data.batch_size=16"])
    with caplog.at_level(logging.INFO, logger="handradar.runs.progress"):
        run_dir = run(cfg, run_dir=tmp_path / "run")
    # progress: every planned stage numbered, in order, what it adds made before the variants train on it
    starts = [m.split(" (elapsed")[0] for m in caplog.messages if "(elapsed" in m]
    assert starts == [f"[{i}/9] {s}" for i, s in enumerate(
        ["data", "synthesis (model-based)", "synthesis (RadarWeightNet)", "CGAN samples", *FOUR, "summary"], 1)]
    assert (run_dir / "figures" / "summary.png").stat().st_size > 5000
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert set(metrics) == {f"test/acc_{v}" for v in FOUR}
    assert all(0.0 <= v <= 1.0 for v in metrics.values())
    # learning: 4 real rows per class of well separated patterns
    assert metrics["test/acc_radar_only"] >= 0.8
    assert metrics["test/acc_model_synth"] >= 0.8 and metrics["test/acc_enhanced_synth"] >= 0.8
    for name in ("radar_only", "model_synth", "enhanced_synth", "cgan"):
        cm = json.loads((run_dir / "confusion" / f"{name}.json").read_text())
        assert np.asarray(cm["matrix"]).sum() == 40 and len(cm["classes"]) == 10
        assert (run_dir / "figures" / f"confusion_{name}.png").stat().st_size > 1000
    # the provider got the whole training pool, and only the few-shot rows to fit on
    split = np.load(_state(run_dir, tmp_path, "few_shot_50pct") / "split.npz")
    assert [c["mode"] for c in fakes.CALLS] == ["model", "enhanced"]
    for call in fakes.CALLS:
        assert np.array_equal(call["rows"], split["pool"]) and np.array_equal(call["fit_rows"], split["train"])
        assert call["seed"] == 1
    assert len(split["train"]) == 40 and len(split["test"]) == 40
    # checkpoints of finished variants are removed; results stay
    state = _state(run_dir, tmp_path, "few_shot_50pct")
    assert not list(state.rglob("*.ckpt"))
    assert (state / "radar_only" / "result.json").is_file()


def test_rwn_guard_decision_reruns_only_the_jobs_radarweightnet_synthesis(fake_data: Path, tmp_path: Path):
    """benchmarks/rwn_guard_decision.py: given a finished job's overrides, the provider is asked once more for
    that job's RadarWeightNet rows, on the job's own split, and no classifier is trained."""
    from benchmarks.rwn_guard_decision import main

    overrides = ["+experiment=few_shot_20pct", "variants=[enhanced_synth]", "trainer.fast_dev_run=true", "seed=3",
                 *fake_overrides(fake_data, tmp_path)]
    fakes.CALLS.clear()
    run(compose_train(overrides), run_dir=tmp_path / "run")
    (job_call,) = fakes.CALLS
    fakes.CALLS.clear()
    state = _state(tmp_path / "run", tmp_path, "few_shot_20pct")
    before = sorted(p.relative_to(state) for p in state.rglob("*"))
    out = main(overrides)
    (call,) = fakes.CALLS
    assert call["mode"] == "enhanced" and call["seed"] == 3 and out["overrides"] == overrides
    assert np.array_equal(call["rows"], job_call["rows"]) and np.array_equal(call["fit_rows"], job_call["fit_rows"])
    assert _state(tmp_path / "run", tmp_path, "few_shot_20pct") == state  # the job's own state folder, no other
    assert sorted(p.relative_to(state) for p in state.rglob("*")) == before  # and nothing trained in it


def test_fixed_protocol_synthesises_every_non_test_skeleton(fake_data: Path, tmp_path: Path):
    fakes.CALLS.clear()
    cfg = compose_train(["+experiment=few_shot_20pct", "split.test_fraction=0.25",  # fixed: the default
                         "variants=[radar_only,model_synth]", "trainer.fast_dev_run=true",
                         *fake_overrides(fake_data, tmp_path)])
    run(cfg, run_dir=tmp_path / "run")
    (call,) = fakes.CALLS
    assert len(call["rows"]) == 60 and len(call["fit_rows"]) == 20  # pool 80 - 20 test; 20 % of 8 per class


def test_transfer_variants_train_on_synthetic_alone_and_on_the_pool(fake_data: Path, tmp_path: Path):
    """Train on synthetic, test on real: the classifier sees no real row, and it learns (the fake provider's
    spectrograms are the real rows' class patterns); radar_pool trains on the pool's real rows."""
    fakes.CALLS.clear()
    cfg = compose_train(["+experiment=few_shot_20pct", "variants=[synth_only,model_synth_only,radar_pool]",
                         *fake_overrides(fake_data, tmp_path), "trainer.max_steps=30", "data.batch_size=16"])
    run_dir = run(cfg, run_dir=tmp_path / "run")
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert set(metrics) == {"test/acc_synth_only", "test/acc_model_synth_only", "test/acc_radar_pool"}
    assert min(metrics.values()) >= 0.8
    state = _state(run_dir, tmp_path, "few_shot_20pct")
    split = np.load(state / "split.npz")
    result = {v: json.loads((state / v / "result.json").read_text()) for v in ("synth_only", "model_synth_only", "radar_pool")}
    assert result["synth_only"]["n_real"] == 0 and result["synth_only"]["n_extra"] == len(split["pool"])
    assert result["radar_pool"]["n_real"] == len(split["pool"]) and result["radar_pool"]["n_extra"] == 0
    assert sorted(c["mode"] for c in fakes.CALLS) == ["enhanced", "model"]
    assert all(np.array_equal(c["fit_rows"], split["train"]) for c in fakes.CALLS)  # fitted on the training rows only


def test_ood_hands_job(fake_data: Path, tmp_path: Path):
    fakes.CALLS.clear()
    cfg = compose_train(["+experiment=ood_hands", "variants=all", "trainer.fast_dev_run=true",
                         *fake_overrides(fake_data, tmp_path)])
    run_dir = run(cfg, run_dir=tmp_path / "run")
    assert set(json.loads((run_dir / "metrics.json").read_text())) == VARIANT_METRICS
    split = np.load(_state(run_dir, tmp_path, "ood_hands") / "split.npz")
    labels = np.repeat(np.arange(10)[None], 8, axis=0).ravel()  # write order: rows cycle through classes
    assert set(labels[split["train"]]) == set(range(6)) and set(labels[split["test"]]) == set(range(6, 10))
    # the pool holds the double-hand rows that are not tested: their skeletons reach the synthetic variants
    assert set(labels[np.setdiff1d(fakes.CALLS[0]["rows"], split["train"])]) == set(range(6, 10))


def test_resume_after_crash_matches_uninterrupted_run(fake_data: Path, tmp_path: Path):
    """Crash in epoch 3 of the second variant; the re-run keeps the finished first variant, resumes
    the second from its checkpoint at the start of epoch 3, and ends bit-identical to an
    uninterrupted run (80 rows in batches of 16: 5 steps per epoch, 24 steps in all)."""

    def overrides(root: Path, marker: Path) -> list[str]:
        return ["+experiment=few_shot_50pct", "split.test=remainder", "variants=[radar_only,model_synth]",
                "trainer.max_steps=24",
                "data.batch_size=16", *fake_overrides(fake_data, root, logger="mlflow"),
                "+callbacks.crash._target_=tests.tasks.fakes.CrashOnce", "+callbacks.crash.epoch=3",
                f"+callbacks.crash.marker={marker}", "+callbacks.crash.prefix=model_synth/",
                f"+callbacks.crash.epoch_log={root}/epochs.log"]

    clean = tmp_path / "clean"
    clean.mkdir()
    (clean / "marker").write_text("never crash")
    reference = run(compose_train(overrides(clean, clean / "marker")), run_dir=clean / "run")

    crash = tmp_path / "crash"
    cfg = compose_train(overrides(crash, crash / "marker"))
    with pytest.raises(RuntimeError, match="simulated crash"):
        run(cfg, run_dir=crash / "run1")
    state = _state(crash / "run1", crash, "few_shot_50pct")
    first = state / "radar_only" / "result.json"
    assert first.is_file() and (state / "model_synth" / "checkpoints" / "last.ckpt").is_file()
    assert not (state / "model_synth" / "result.json").exists()
    assert (crash / "run1" / "error.txt").read_text().startswith("RuntimeError")
    first_mtime = first.stat().st_mtime_ns
    (crash / "epochs.log").write_text("")

    resumed = run(cfg, run_dir=crash / "run2")
    epochs = (crash / "epochs.log").read_text().split("\n")
    assert epochs[0] == "model_synth/ 3"  # radar_only not retrained; model_synth resumed at epoch 3
    assert first.stat().st_mtime_ns == first_mtime
    assert json.loads((resumed / "metrics.json").read_text()) == json.loads((reference / "metrics.json").read_text())
    for name in ("radar_only", "model_synth"):
        a = json.loads((_state(resumed, crash, "few_shot_50pct") / name / "result.json").read_text())
        b = json.loads((_state(reference, clean, "few_shot_50pct") / name / "result.json").read_text())
        assert a["weights_hash"] == b["weights_hash"] and a["confusion"] == b["confusion"]

    # one MLflow run for the job, completed by the re-run
    from mlflow import MlflowClient

    client = MlflowClient(f"sqlite:///{crash}/logs/mlflow/mlflow.db")
    (exp,) = [e for e in client.search_experiments() if e.name == "few_shot_50pct"]
    (mrun,) = client.search_runs([exp.experiment_id])
    assert mrun.info.status == "FINISHED"
    assert set(VARIANT_METRICS) & set(mrun.data.metrics) == {"test/acc_radar_only", "test/acc_model_synth"}
    assert mrun.data.tags["handradar.preset"] == "few_shot_50pct" and mrun.data.tags["handradar.code_version"]
    ref_client = MlflowClient(f"sqlite:///{clean}/logs/mlflow/mlflow.db")
    (ref_exp,) = [e for e in ref_client.search_experiments() if e.name == "few_shot_50pct"]
    (ref_run,) = ref_client.search_runs([ref_exp.experiment_id])

    def history(c, r):
        return sorted({(m.step, m.value) for m in c.get_metric_history(r.info.run_id, "model_synth/train/loss")})

    assert history(client, mrun) == history(ref_client, ref_run)
    assert len(history(client, mrun)) == 4  # one per complete epoch (max_steps ends inside epoch 4)
    arts = {a.path for a in client.list_artifacts(mrun.info.run_id)}
    assert {"config.yaml", "confusion", "figures"} <= arts


def test_external_pretrain_job(fake_data: Path, tmp_path: Path):
    fakes.EXTERNAL_CALLS.clear()
    cfg = compose_train(["+experiment=external_pretrain", *fake_overrides(fake_data, tmp_path),
                         "pretrain.max_steps=10", "trainer.max_steps=5"])
    run_dir = run(cfg, run_dir=tmp_path / "run")
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert set(metrics) == {f"test/acc_{init}_{c}c_{p}pct" for init in ("scratch", "pretrained") for c in (10, 5)
                            for p in (5, 10)}
    assert fakes.EXTERNAL_CALLS == ["sfinge3d"]  # pre-trained once, reused by the four fine-tunings
    cm5 = json.loads((run_dir / "confusion" / "pretrained_5c_10pct.json").read_text())
    assert cm5["classes"] == ["grasp", "finger_friction", "finger_wave", "circle", "slide"]
    assert np.asarray(cm5["matrix"]).shape == (5, 5)


def test_external_pretrain_uses_dhg_when_given(fake_data: Path, tmp_path: Path):
    fakes.EXTERNAL_CALLS.clear()
    cfg = compose_train(["+experiment=external_pretrain", *fake_overrides(fake_data, tmp_path),
                         f"data.dhg.root={tmp_path}", "finetune.class_subsets=[null]", "finetune.fractions=[0.5]",
                         "trainer.fast_dev_run=true"])
    run(cfg, run_dir=tmp_path / "run")
    assert fakes.EXTERNAL_CALLS == ["dhg"]


def test_provider_breaking_the_contract_fails_clearly(fake_data: Path, tmp_path: Path):
    cfg = compose_train(["+experiment=few_shot_20pct", "variants=[model_synth]", "trainer.fast_dev_run=true",
                         *fake_overrides(fake_data, tmp_path),
                         "synth.provider._target_=tests.tasks.fakes.wrong_label_provider"])
    with pytest.raises(FormatError, match=r"fake_model_.*\.h5: synthetic row 0 has label"):
        run(cfg, run_dir=tmp_path / "run")
    assert "FormatError" in (tmp_path / "run" / "error.txt").read_text()
    assert not (tmp_path / "run" / "metrics.json").exists()


def test_custom_job_kind(fake_data: Path, tmp_path: Path):
    cfg = compose_train(["job=tests.tasks.fakes.custom_job", *fake_overrides(fake_data, tmp_path)])
    run_dir = run(cfg, run_dir=tmp_path / "run")
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["test/n_rows"] == 80.0 and 0 < metrics["test/ssim_model"] < 1
    with pytest.raises(ValueError, match="job must be"):
        run(compose_train(["job=nonsense", *fake_overrides(fake_data, tmp_path)]), run_dir=tmp_path / "run2")


def test_external_pretrain_fits_on_rows_that_train_every_finetune(fake_data: Path, tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch):
    """The closed loop in Table III: the simulator is fitted on the smallest fraction's rows, which lie in
    every fine-tune's training rows (never in a test set), and the external provider simulates with it."""
    from handradar.tasks.train import Job

    fitted_on, finetunes, provider_sims = [], {}, []
    fitted = {"rcs_exponent": 0.5, "effects": ["tracking_jitter"], "effect_params": {"tracking_jitter": {}}}

    def fitted_sim(self, split):
        fitted_on.append(split.train)
        return fitted

    def provider(source_cfg, *, seed, cache_dir, sim=None):
        provider_sims.append(sim)
        return fakes.fake_external_provider(source_cfg, seed=seed, cache_dir=cache_dir)

    original = Job.train_and_test

    def train_and_test(self, name, sources, test, *args, **kwargs):
        finetunes[name] = (sources[0].rows, np.asarray(test))
        return original(self, name, sources, test, *args, **kwargs)

    monkeypatch.setattr(Job, "fitted_sim", fitted_sim)
    monkeypatch.setattr(Job, "train_and_test", train_and_test)
    monkeypatch.setattr(fakes, "fitted_external_provider", provider, raising=False)
    cfg = compose_train(["+experiment=external_pretrain", *fake_overrides(fake_data, tmp_path),
                         "synth.external_provider._target_=tests.tasks.fakes.fitted_external_provider",
                         "pretrain.max_steps=5", "trainer.max_steps=2"])
    run(cfg, run_dir=tmp_path / "run")
    assert provider_sims == [fitted]
    (fit_rows,) = fitted_on
    assert len(finetunes) == 8
    for name, (train, test) in finetunes.items():  # a fit row of a fine-tune's classes trains it
        assert not np.intersect1d(fit_rows, test).size, name
    assert np.isin(fit_rows, finetunes["scratch_10c_5pct"][0]).all()
    assert np.isin(finetunes["scratch_10c_5pct"][0], finetunes["scratch_10c_10pct"][0]).all()  # nested fractions
    assert np.isin(finetunes["scratch_5c_5pct"][0], finetunes["scratch_10c_5pct"][0]).all()  # nested subsets
