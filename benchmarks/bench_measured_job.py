"""One measured job as `make measured` runs it: K = 8 real rows per class, all four variants, cold, on 2 cores.

``python train.py +experiment=measured split.per_class=8 seed=1`` on Xia et al.'s images (``handradar-fetch
dataset=xia2021``, or CI's ../shared copy) with empty caches: the label-free fit of the unknowns, the synthetic rows,
then radar only, + synthetic, synthetic only (whose classifier later jobs of the seed share) and pre-training, each by
the preset's compact CNN and small-data recipe (conf/recipe/small_data.yaml). The compact CNN's training speed is
reported on its own (images/s, batch 64, 1 x 64 x 64, the recipe's augmentations) beside ResNet-18's, the network
the recipe replaced. Timed stages come from the job's own stage log.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from benchmarks.common import Result, best_time
from handradar.provenance import REPO_ROOT

THREADS = int(os.environ.get("HANDRADAR_BENCH_THREADS", "2"))
BATCH = 64


def _images_per_s(net: torch.nn.Module, augment: torch.nn.Module | None, steps: int = 5) -> float:
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3)
    x, y = torch.rand(BATCH, 1, 64, 64), torch.randint(0, 8, (BATCH,))

    def train_steps() -> None:
        for _ in range(steps):
            opt.zero_grad()
            torch.nn.functional.cross_entropy(net(augment(x) if augment else x), y).backward()
            opt.step()

    train_steps()
    return steps * BATCH / best_time(train_steps, 3)


def run() -> list[Result]:
    from handradar.models.augment import SpectrogramAugment
    from handradar.models.classifiers import compact_cnn, resnet18

    torch.set_num_threads(THREADS)
    import yaml

    aug = SpectrogramAugment(**{k: v for k, v in yaml.safe_load((REPO_ROOT / "conf" / "recipe" / "small_data.yaml")
                                                                .read_text())["augment"].items() if k != "_target_"})
    out = [Result("compact CNN training", _images_per_s(compact_cnn(8), aug), "images/s",
                  f"batch {BATCH}, 1x64x64, the recipe's augmentations, {THREADS} threads"),
           Result("resnet18 training (stem stride 2)", _images_per_s(resnet18(8, stem_stride=2), None), "images/s",
                  f"batch {BATCH}, 1x64x64, {THREADS} threads")]
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "train.py", "+experiment=measured", "split.per_class=8", "seed=1", f"threads={THREADS}",
               "logger=none", "trainer.enable_progress_bar=false", f"paths.log_dir={tmp}/logs",
               f"paths.cache_dir={tmp}/cache", f"hydra.run.dir={tmp}/run"]
        t0 = time.perf_counter()
        done = subprocess.run(cmd, cwd=REPO_ROOT, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if done.returncode:
            raise RuntimeError(f"the measured job failed: {done.stderr.strip().splitlines()[-1]}")
        metrics = json.loads((Path(tmp) / "run" / "metrics.json").read_text())
    log = done.stderr + done.stdout
    fit = re.search(r"fitting .* on (\d+) measured rows", log)
    acc = ", ".join(f"{k.removeprefix('test/acc_')} {v:.2f}" for k, v in sorted(metrics.items()) if k.startswith("test/"))
    out.append(Result("measured job, K = 8, four variants, cold", wall, "s",
                      f"fit on {fit.group(1) if fit else '?'} unlabelled rows + 1,600 synthetic rows + 4 classifiers "
                      f"(compact CNN, small_data), {THREADS} threads; {acc}"))
    return out


if __name__ == "__main__":
    for r in run():
        print(r.row())
