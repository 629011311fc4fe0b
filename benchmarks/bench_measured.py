"""Synthesis for a measured dataset: the wall time of one dataset's synthetic rows, cold.

The classes and grid of Xia et al.'s manifest (conf/manifests/xia2021.yaml: 8 classes, 64 Doppler bins x 64
frames, frame-based Doppler), ``HANDRADAR_BENCH_MEASURED_PER_CLASS`` rows per class (default 125: 1000 rows),
motions drawn as the measured job draws them, the paper's model with no RadarWeightNet, cold: skeleton generation,
the reflection points' signals summed window by window (nothing cached), and the chain. Unknowns at the values the
measured runs use (docs/findings.md): v_max 1.5 m/s, 50 ms a column, 32 chirps a frame (2048 chirps a row).
Needs no measured data. Target (issue 54): >= 50 rows/s on 2 cores.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import torch

from benchmarks.common import Result
from handradar.data.measured import dataset_chain, read_manifest, synthesis_radar
from handradar.provenance import REPO_ROOT
from handradar.synthesis.providers import synthesize_source


def run() -> list[Result]:
    torch.set_num_threads(int(os.environ.get("HANDRADAR_BENCH_THREADS", "2")))
    per_class = int(os.environ.get("HANDRADAR_BENCH_MEASURED_PER_CLASS", "125"))
    with tempfile.TemporaryDirectory() as tmp:
        m = read_manifest(REPO_ROOT / "conf" / "manifests" / "xia2021.yaml", root=tmp)  # the classes, not the data
        shape = (64, 64)
        radar = synthesis_radar(m, shape, {"v_max_m_s": 1.5, "frame_period_s": 0.05, "chirps_per_frame": 32})
        source = {"name": "motions", "classes": m.classes, "per_class": per_class, "seed": 0,
                  "duration_s": shape[1] * radar.frame_period_s,
                  "ranges": {k: list(v) for k, v in m.motion_ranges.items()}}
        t0 = time.perf_counter()
        synthesize_source(source, Path(tmp) / "synth.h5", radar=radar, chain=dataset_chain(m, shape, radar.n_loops),
                          cache_dir=Path(tmp) / "cache", progress=False)
        wall = time.perf_counter() - t0
    n = per_class * len(m.classes)
    note = f"{n} rows, 8 classes, 64 x 64, {radar.chirps_per_frame * shape[1]} chirps a row, cold"
    return [Result("measured synthesis: wall time", wall, "s", note), Result("measured synthesis", n / wall, "rows/s", note)]
