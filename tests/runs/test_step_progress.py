"""A fit without a progress bar logs its steps, with elapsed time and what is left."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import pytest

from handradar.training import StepProgress


def test_step_progress_logs_at_most_every_interval(caplog: pytest.LogCaptureFixture):
    now = [0.0]
    cb = StepProgress("pretrain", interval_s=60, clock=lambda: now[0])
    trainer = SimpleNamespace(global_step=100, max_steps=1000, global_rank=0)
    cb.on_train_start(trainer, None)  # resumed at step 100: the rate counts only the steps taken now
    with caplog.at_level(logging.INFO, logger="handradar.training"):
        for step, t in [(110, 30.0), (200, 60.0), (210, 90.0), (300, 120.0)]:
            trainer.global_step, now[0] = step, t
            cb.on_train_batch_end(trainer, None, None, None, 0)
    # 100 steps in 60 s: 800 left take 8 min; 200 steps in 120 s: 700 left take 7 min
    assert caplog.messages == ["pretrain: step 200/1000 (elapsed 1:00, about 8:00 left)",
                               "pretrain: step 300/1000 (elapsed 2:00, about 7:00 left)"]


def test_step_progress_without_a_step_budget(caplog: pytest.LogCaptureFixture):
    now = [0.0]
    cb = StepProgress("radar_only", interval_s=0, clock=lambda: now[0])
    trainer = SimpleNamespace(global_step=0, max_steps=-1, global_rank=0)
    cb.on_train_start(trainer, None)
    trainer.global_step, now[0] = 5, 3.0
    with caplog.at_level(logging.INFO, logger="handradar.training"):
        cb.on_train_batch_end(trainer, None, None, None, 0)
    assert caplog.messages == ["radar_only: step 5 (elapsed 0:03)"]


@pytest.mark.parametrize("bar", [True, False])
def test_make_trainer_adds_it_only_without_a_progress_bar(tmp_path, bar: bool):
    from omegaconf import OmegaConf

    from handradar.training import make_trainer

    cfg = OmegaConf.create({"_target_": "lightning.pytorch.Trainer", "accelerator": "cpu", "max_steps": 3,
                            "enable_progress_bar": bar, "enable_model_summary": False})
    trainer = make_trainer(cfg, ckpt_dir=tmp_path / "pretrain" / "checkpoints", seed=1)
    names = [cb.name for cb in trainer.callbacks if isinstance(cb, StepProgress)]
    assert names == ([] if bar else ["pretrain"])
