"""The training recipe (conf/recipe/, handradar.tasks.train.recipe_steps / recipe_scheduler): a length counted in
passes over the fit's rows with a floor of steps, the cosine schedule, and the presets' choices."""

from __future__ import annotations

import pytest
import torch

from handradar.tasks.train import recipe_scheduler, recipe_steps
from tests.tasks.fakes import compose_train


@pytest.mark.parametrize(("rows", "batch", "epochs", "floor", "steps"), [
    (8, 64, 30, 500, 500),        # 8 rows: one batch a pass, the floor holds
    (2880, 64, 30, 500, 1350),    # 45 batches a pass (the last one short) x 30
    (2881, 64, 30, 0, 1380),      # 46 batches a pass
    (100, 32, 1, 0, 4),
])
def test_steps_are_passes_over_the_rows_with_a_floor(rows, batch, epochs, floor, steps):
    assert recipe_steps({"epochs": epochs, "min_steps": floor}, rows, batch) == steps


def test_steps_recipe_leaves_the_trainer_its_steps():
    assert recipe_steps({"epochs": None}, 100, 32) is None and recipe_steps({}, 100, 32) is None
    with pytest.raises(ValueError, match="recipe.epochs must be >= 1"):
        recipe_steps({"epochs": 0}, 100, 32)


def test_cosine_schedule_falls_to_zero_over_the_fit():
    opt = torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=1.0)
    sched = recipe_scheduler({"schedule": "cosine"}, {"scheduler": None}, 10)(opt)
    lrs = []
    for _ in range(10):
        opt.step()
        sched.step()
        lrs.append(opt.param_groups[0]["lr"])
    assert lrs[4] == pytest.approx(0.5 * (1 + torch.cos(torch.tensor(torch.pi * 5 / 10)).item()))
    assert lrs[-1] == pytest.approx(0.0, abs=1e-12) and all(a >= b for a, b in zip(lrs, lrs[1:]))
    assert recipe_scheduler({"schedule": "constant"}, {"scheduler": None}, 10) is None
    with pytest.raises(ValueError, match="recipe.schedule must be constant or cosine"):
        recipe_scheduler({"schedule": "linear"}, {"scheduler": None}, 10)


def test_presets_keep_or_change_the_recipe():
    """The paper's presets keep ResNet-18 trained for trainer.max_steps without augmentation; the measured preset
    trains every variant with the compact CNN and the small-data recipe."""
    paper = compose_train(["+experiment=few_shot_5pct"])
    assert paper.model.net._target_.endswith("resnet18") and paper.recipe.epochs is None and not paper.recipe.augment
    measured = compose_train(["+experiment=measured"])
    assert measured.model.net._target_.endswith("compact_cnn") and measured.recipe.epochs >= 1
    assert measured.recipe.augment._target_.endswith("SpectrogramAugment") and measured.recipe.schedule == "cosine"
