"""Training throughput of the classifiers and the wall time of one few-shot job (CPU, 2 threads).

- images/s of ResNet-18 and ResNet-50 training steps (AdamW, batch 32, 1 x 64 x 32 inputs);
- wall time of ``few_shot_5pct`` on a fake 720-row dataset (10 gestures x 72) with fake synthetic
  providers, ResNet-18, and the step budgets given below (the defaults are trainer.max_steps=300,
  cgan.max_steps=3000; the per-step figures scale to them).
"""

from __future__ import annotations

import logging
import tempfile
import time
from functools import partial
from pathlib import Path

import torch

from benchmarks.common import Result, best_time

BATCH = 32
THREADS = 2
JOB_STEPS = 60
JOB_GAN_STEPS = 600


def _images_per_s(factory, repeat: int = 3, steps: int = 3) -> float:
    from torch.nn import functional as F

    net = factory(10)  # (num_classes) -> nn.Module
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3)
    x, y = torch.rand(BATCH, 1, 64, 32), torch.randint(0, 10, (BATCH,))

    def train_steps() -> None:
        for _ in range(steps):
            opt.zero_grad()
            F.cross_entropy(net(x), y).backward()
            opt.step()

    train_steps()  # warm-up
    return steps * BATCH / best_time(train_steps, repeat)


def _few_shot_job(tmp: Path) -> tuple[float, dict]:
    from handradar.tasks.train import run
    from tests.tasks.fakes import compose_train, fake_overrides, write_fake_dataset

    data = write_fake_dataset(tmp / "fake720.h5", per_class=72)
    overrides = [o for o in fake_overrides(data, tmp) if not o.startswith(("model.net", "~model.net", "trainer.max_steps",
                                                                           "cgan.max_steps"))]
    cfg = compose_train(["+experiment=few_shot_5pct", *overrides, f"trainer.max_steps={JOB_STEPS}",
                         f"cgan.max_steps={JOB_GAN_STEPS}", "trainer.enable_progress_bar=False"])
    t0 = time.perf_counter()
    run_dir = run(cfg, run_dir=tmp / "run")
    wall = time.perf_counter() - t0
    import json

    return wall, json.loads((run_dir / "metrics.json").read_text())


def run() -> list[Result]:
    from handradar.models.classifiers import resnet18, resnet50

    torch.set_num_threads(THREADS)
    logging.getLogger("lightning.pytorch").setLevel(logging.ERROR)
    out = [Result(f"{net.__name__} training, stem stride {stride}", _images_per_s(partial(net, stem_stride=stride)),
                  "images/s", f"batch {BATCH}, 1x64x32, {THREADS} threads{note}")
           for net, stride, note in ((resnet18, 2, " (CPU default)"), (resnet18, 1, ""), (resnet50, 1, " (model=resnet50)"))]
    with tempfile.TemporaryDirectory() as tmp:
        wall, metrics = _few_shot_job(Path(tmp))
    acc = ", ".join(f"{k.split('acc_')[1]} {v:.2f}" for k, v in sorted(metrics.items()))
    out.append(Result("few_shot_5pct job (720 fake rows)", wall, "s",
                      f"resnet18, 4 variants x {JOB_STEPS} steps + CGAN {JOB_GAN_STEPS} steps, fake providers; acc: {acc}"))
    return out


if __name__ == "__main__":
    for r in run():
        print(r.row())
