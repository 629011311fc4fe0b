"""Every config and preset composes with Hydra's compose API and instantiates what it names."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import lightning.pytorch as pl
import pytest
import torch
from hydra.utils import get_class, instantiate
from omegaconf import OmegaConf

from handradar.config import config_dir, experiments_dir
from handradar.data.datasets import (
    DatasetFile,
    RecordingsFolder,
    ReferenceWorld,
    import_callable,
)
from handradar.data.measured import MeasuredDataset
from handradar.models.cgan import Discriminator, Generator
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig
from handradar.runs.mlflow import Tracker
from handradar.sim.factory import SimFactory
from handradar.sim.simulator import Simulator
from handradar.vocab import MEASURED_VARIANTS
from tests.tasks.fakes import compose_train

REPO = Path(__file__).resolve().parents[2]
PRESETS = sorted(p.stem for p in (experiments_dir() / "experiment").glob("*.yaml"))
DIAGNOSE_PRESETS = {"gap_benchmark"}  # diagnose.py's: tests/gap/test_cli.py, tests/config/test_gap_benchmark_presets.py
TRAIN_PRESETS = [p for p in PRESETS if p not in DIAGNOSE_PRESETS]
PAPER_VARIANTS = ["radar_only", "model_synth", "enhanced_synth", "model_synth_only"]  # make run's comparison


def test_presets_exist():
    assert set(PRESETS) >= {"few_shot_5pct", "few_shot_20pct", "few_shot_50pct", "ood_angle", "ood_subject",
                            "ood_hands", "ood_occlusion", "external_pretrain"}
    # one benchmark preset: worlds and sizes compose (world=..., benchmark.size=...), no preset per pair
    assert [p for p in PRESETS if p.startswith("gap_benchmark")] == ["gap_benchmark"]


@pytest.mark.parametrize("preset", TRAIN_PRESETS)
def test_preset_composes_and_instantiates(preset: str, tmp_path: Path):
    cfg = compose_train([f"+experiment={preset}", f"paths.log_dir={tmp_path}"])
    assert cfg.task_name == preset
    OmegaConf.resolve(cfg)  # every interpolation resolves
    net = instantiate(cfg.model.net, num_classes=10)
    assert net(torch.rand(2, 1, 64, 32)).shape == (2, 10)
    opt = instantiate(cfg.model.optimizer)(net.parameters())
    assert isinstance(opt, torch.optim.Optimizer)
    assert isinstance(instantiate(cfg.cgan.generator, num_classes=10), Generator)
    assert isinstance(instantiate(cfg.cgan.discriminator, num_classes=10), Discriminator)
    assert isinstance(instantiate(cfg.trainer), pl.Trainer)
    tracker = instantiate(cfg.logger)
    assert isinstance(tracker, Tracker) and tracker.tracking_uri == f"sqlite:///{tmp_path}/mlflow/mlflow.db"
    assert tracker.experiment_name == preset
    # the default data: the reference world; the measured preset's: Xia et al.'s manifest
    data_kind = MeasuredDataset if preset == "measured" else ReferenceWorld
    assert isinstance(instantiate(cfg.data.dataset), data_kind)
    assert isinstance(instantiate(cfg.radar), RadarConfig) and isinstance(instantiate(cfg.chain), ChainConfig)
    assert callable(instantiate(cfg.synth.provider)) and callable(instantiate(cfg.synth.external_provider))
    sim = SimFactory.from_config(cfg.sim, instantiate(cfg.radar), instantiate(cfg.chain))()
    assert isinstance(sim, Simulator) and not list(sim.effects)  # the paper's model by default
    if cfg.job == "variants":
        assert list(cfg.variants) == (PAPER_VARIANTS if preset != "data_efficiency" else
                                      ["radar_only", "model_synth", "model_synth_only"])
        assert cfg.split.kind in ("few_shot", "ood")
    elif preset == "measured":
        assert callable(import_callable(cfg.job)) and Path(cfg.data.manifest).name == "xia2021.yaml"
        assert set(cfg.variants) <= set(MEASURED_VARIANTS) and cfg.split.val_per_class > 0
    elif preset == "synth_fit":
        assert callable(import_callable(cfg.job))
        assert [dict(p) for p in cfg.synth_fit.phases] == [{"epochs": 20, "lr": 5e-4, "batch_size": 32},
                                                          {"epochs": 50, "lr": 1e-4, "batch_size": 16}]
    else:
        assert cfg.job == "external_pretrain"
        assert cfg.data.dhg.root is None and Path(cfg.data.sfinge3d.root).name == "sfinge3d"
        assert list(cfg.finetune.fractions) == [0.05, 0.10]


def test_few_shot_fractions():
    got = {p: compose_train([f"+experiment={p}"]).split.fraction for p in ("few_shot_5pct", "few_shot_20pct", "few_shot_50pct")}
    assert got == {"few_shot_5pct": 0.05, "few_shot_20pct": 0.2, "few_shot_50pct": 0.5}


@pytest.mark.parametrize("model,cls", [("resnet18", "handradar.models.classifiers.resnet18"),
                                       ("resnet50", "handradar.models.classifiers.resnet50")])
def test_model_switch(model: str, cls: str):
    cfg = compose_train([f"model={model}"])
    assert cfg.model.net._target_ == cls
    net = instantiate(cfg.model.net, num_classes=4)
    assert net.fc.out_features == 4 and net.conv1.in_channels == 1


def test_data_sources(tmp_path: Path):
    h = compose_train(["data=hdf5", f"data.path={tmp_path}/x.h5"])
    assert isinstance(instantiate(h.data.dataset), DatasetFile)
    r = compose_train(["data=recordings", f"data.root={tmp_path}", f"paths.cache_dir={tmp_path}/cache"])
    src = instantiate(r.data.dataset)
    assert isinstance(src, RecordingsFolder) and isinstance(src.chain, ChainConfig)
    assert src.cache_dir == tmp_path / "cache" / "datasets"
    with pytest.raises(Exception, match="data.path"):  # a missing mandatory value is named
        OmegaConf.to_container(compose_train(["data=hdf5"]).data, resolve=True, throw_on_missing=True)


@pytest.mark.parametrize("trainer", ["cpu", "gpu", "ddp"])
def test_trainer_configs(trainer: str):
    cfg = compose_train([f"trainer={trainer}"])
    assert cfg.trainer._target_ == "lightning.pytorch.Trainer"
    if trainer == "ddp":
        assert cfg.trainer.strategy == "ddp" and cfg.trainer.devices == 2
    # instantiable here (CPU): the same config with the CPU accelerator
    overrides = {"accelerator": "cpu", "precision": "32-true"}
    if trainer == "ddp":
        overrides["strategy"] = "ddp_spawn"
    t = instantiate(OmegaConf.merge(cfg.trainer, overrides))
    assert isinstance(t, pl.Trainer)
    assert t.max_steps == cfg.trainer.max_steps


@pytest.mark.parametrize("launcher,cls", [("joblib", "hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher"),
                                          ("slurm", "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher")])
def test_launchers(launcher: str, cls: str):
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("train", overrides=[f"hydra/launcher={launcher}"], return_hydra_config=True)
    node = cfg.hydra.launcher
    assert node._target_ == cls
    params = {k: v for k, v in OmegaConf.to_container(node).items() if k != "_target_"}
    launcher_obj = get_class(cls)(**params)  # the plugin accepts every field
    assert launcher_obj is not None
    if launcher == "slurm":
        assert node.max_num_timeout > 0  # a job killed at its time limit is resubmitted and resumes


def test_hydra_callbacks_and_searchpath():
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("train", return_hydra_config=True)
    assert get_class(cfg.hydra.callbacks.job_report._target_).__name__ == "JobReport"
    assert cfg.hydra.searchpath == [f"file://{experiments_dir()}"]
    assert "experiment" not in cfg  # presets are appended with +experiment=


def test_experiment_from_any_working_directory(tmp_path: Path):
    """``python train.py +experiment=few_shot_5pct`` finds the preset outside the repository."""
    out = subprocess.run([sys.executable, str(REPO / "train.py"), "+experiment=ood_subject", "--cfg", "job"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=120,
                         env={**__import__("os").environ, "PYTHONPATH": str(REPO / "src")})
    assert out.returncode == 0, out.stderr
    cfg = OmegaConf.create(out.stdout)
    assert cfg.task_name == "ood_subject" and cfg.split.ood == "subject"


def test_logger_none_is_a_disabled_tracker():
    tracker = instantiate(compose_train(["logger=none"]).logger)
    assert isinstance(tracker, Tracker) and not tracker.enabled and tracker.start() is None


def test_smoke_debug_config_overrides_the_preset():
    """make smoke: +debug=smoke after the preset shrinks the world, the variants and the steps."""
    cfg = compose_train(["+experiment=few_shot_5pct", "+debug=smoke"])
    assert cfg.task_name == "smoke" and cfg.split.fraction == 0.34 and cfg.split.test == "fixed"
    assert list(cfg.variants) == ["radar_only", "model_synth", "model_synth_only"]
    assert cfg.trainer.max_steps == 30 and cfg.synth.fit_sim == "effects"
    n = len(cfg.world.gestures) * cfg.world.subjects * len(cfg.world.angles_deg) * cfg.world.repetitions
    assert n == 60


def test_variants_all_names_every_variant():
    from handradar.tasks.train import VARIANTS, variant_names

    cfg = compose_train(["+experiment=ood_hands", "variants=all"])
    assert variant_names(cfg.variants) == list(VARIANTS)
    with pytest.raises(ValueError, match="unknown variant 'radar'.*variants=all"):
        variant_names(["radar"])

