"""The guarded RadarWeightNet's decision for one train.py job, without training its classifiers
(``python -m benchmarks.rwn_guard_decision +experiment=data_efficiency split.per_class=8 seed=1 ...``).

Takes a finished job's train.py overrides (the same ones, so that its job hash and hence its state
folder, with its split and fitted simulator, are found; a job never run is split and fitted here) and
runs only the synthesis of its RadarWeightNet variant: the fold fits, the guard's rule and the final
fit. Prints the guard's report (JSON) and the seconds it took. The synthetic file lands in ``synth.cache_dir`` as the job would write it, so a
later ``train.py ... resume=false`` only trains the classifier. A way to judge a new guard rule over
many jobs at the cost of their synthesis: where the rule keeps a job's shrink, its accuracy is the
old run's (CPU runs are deterministic); where it falls back to 0, model-based's.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir

from handradar.config import VERSION_BASE, config_dir
from handradar.data.hdf5 import read_attrs
from handradar.tasks.train import Job


def main(overrides: list[str]) -> dict:
    with initialize_config_dir(config_dir=str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("train", overrides=overrides)
    torch.set_num_threads(int(cfg.get("threads") or 1))
    t0 = time.time()
    with tempfile.TemporaryDirectory() as run_dir:  # the job writes nothing there before it trains
        job = Job(cfg, Path(run_dir))
        job.load_data()
        job.state.mkdir(parents=True, exist_ok=True)
        parts = job._make_extra("enhanced", job.split())
    report = json.loads(read_attrs(parts[0].path).get("rwn_guard", "{}"))
    return {"overrides": overrides, "seconds": round(time.time() - t0), **report}


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1:])), flush=True)
