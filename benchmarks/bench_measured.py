"""Synthesis for a measured dataset: the wall time of one dataset's synthetic rows, cold, for each processing set-up.

The classes and grid of Xia et al.'s manifest (conf/manifests/xia2021.yaml: 8 classes, 64 Doppler bins x 64
frames, frame-based Doppler), ``HANDRADAR_BENCH_MEASURED_PER_CLASS`` rows per class (default 125: 1000 rows),
motions drawn as the measured job draws them, the paper's model with no RadarWeightNet, cold: skeleton generation,
the reflection points' signals summed window by window (nothing cached), the chain, and the finishing steps
(handradar.synthesis.measured.finish_rows). Unknowns at the values the measured runs use (docs/findings.md): v_max
2.0 m/s, 35 ms a column, 64 chirps a frame (4096 chirps a row); the motions with their arm. Processing set-ups (docs/datasets.md#processing):
Xia et al.'s manifest as it is; an MTI canceller, the central 64 of a 128-bin Doppler FFT and the strongest range
bin; linear magnitude scaled per frame with a CA-CFAR. Needs no measured data. Each set-up runs three times and
reports the fastest (runs of one build on the 2-core machine spread by up to 1.5x with other load). Target (issues
54, 62, 63): >= 50 rows/s on 2 cores for each.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.common import Result
from handradar.data.datasets import load_arrays
from handradar.data.measured import dataset_chain, read_manifest
from handradar.provenance import REPO_ROOT
from handradar.synthesis.measured import finish_rows, motion_source, simulation_chain, synthesis_radar, with_steps
from handradar.synthesis.providers import synthesize_source

REPEAT = 3  # runs of each set-up; the fastest is reported (the least disturbed by other load on a shared machine)
SETUPS = {
    "as the manifest says": {},
    "MTI, 64 of 128 Doppler bins, strongest range bin": {"clutter_removal": "mti", "doppler_fft": 128,
                                                          "range": "strongest"},
    "linear magnitude per frame, CA-CFAR": {"quantity": "magnitude", "scale": "linear", "normalise": "frame",
                                            "cfar": {"guard": 4, "training": 8, "threshold_db": 6.0}},
}


def run() -> list[Result]:
    torch.set_num_threads(int(os.environ.get("HANDRADAR_BENCH_THREADS", "2")))
    per_class = int(os.environ.get("HANDRADAR_BENCH_MEASURED_PER_CLASS", "125"))
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        xia = read_manifest(REPO_ROOT / "conf" / "manifests" / "xia2021.yaml", root=tmp)  # the classes, not the data
        shape = (64, 64)
        values = {"v_max_m_s": 2.0, "frame_period_s": 0.035, "chirps_per_frame": 64, "dynamic_range_db": 60.0}
        for name, steps in SETUPS.items():
            m = with_steps(xia, steps)
            radar = synthesis_radar(m, shape, values)
            chain = dataset_chain(m, shape, radar.n_loops, values)
            source = motion_source(m, per_class, 0, shape[1] * radar.frame_period_s)
            n = per_class * len(m.classes)
            wall = float("inf")
            for k in range(REPEAT):
                f = Path(tmp) / f"synth-{len(out)}-{k}.h5"
                t0 = time.perf_counter()
                synthesize_source(source, f, radar=radar, chain=simulation_chain(chain), progress=False,
                                  cache_dir=Path(tmp) / "cache")
                x = finish_rows(load_arrays(f).x, {"approaching": "low"}, 0, chain)
                wall = min(wall, time.perf_counter() - t0)
                assert x.shape == (n, *shape) and np.isfinite(x).all()
            note = (f"{name}: {n} rows, 8 classes, 64 x 64, {radar.chirps_per_frame * shape[1]} chirps a row, cold, "
                    f"best of {REPEAT}")
            out += [Result(f"measured synthesis ({name}): wall time", wall, "s", note),
                    Result(f"measured synthesis ({name})", n / wall, "rows/s", note)]
    return out
