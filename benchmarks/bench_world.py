"""Reference world throughput: recordings/s on the ADC path (written to disk) and the build time of
the default HDF5 dataset on the fast path, both with the world's 2 worker processes."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from benchmarks.common import Result
from handradar.config import VERSION_BASE, config_dir
from handradar.world import (
    build_world_dataset,
    fast_example,
    recording_specs,
    world_config,
    write_world_recordings,
)


def _configs():
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("world", overrides=["out=unused"])
    return world_config(cfg.world), instantiate(cfg.radar), instantiate(cfg.chain)


def cpu_seconds_per_row(world, radar, chain, n: int = 20) -> float:
    """Mean CPU time of one fast-path row in this process (1 torch thread), over rows spread across
    the world's list: a figure that other load on the machine does not inflate."""
    specs = recording_specs(world)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        t0 = time.process_time()
        for spec in specs[:: max(1, len(specs) // n)][:n]:
            fast_example(world, radar, chain, spec)
        return (time.process_time() - t0) / n
    finally:
        torch.set_num_threads(threads)


def run(n_recordings: int = 12) -> list[Result]:
    world, radar, chain = _configs()
    n_rows = len(recording_specs(world))
    cpu_row = cpu_seconds_per_row(world, radar, chain)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        write_world_recordings(world, radar, Path(tmp) / "rec", limit=n_recordings, progress=False)
        t_rec = time.perf_counter() - t0
        t0 = time.perf_counter()
        build_world_dataset(world, radar, chain, Path(tmp) / "cache", progress=False)
        t_ds = time.perf_counter() - t0
    note = f"{world.workers} workers, {world.capture_frames}-frame captures"
    return [
        Result("world_recordings_per_s", n_recordings / t_rec, "rec/s", f"ADC path to disk, {note}"),
        Result("world_default_dataset_build", t_ds, "s", f"fast path, {n_rows} rows, {note}; target <= 600 s"),
        Result("world_dataset_rows_per_s", n_rows / t_ds, "rows/s", f"fast path, {note}"),
        Result("world_row_cpu_s", cpu_row, "CPU s/row", "fast path, 1 thread, mean of 20 rows across the list"),
        Result("world_default_dataset_cpu_bound", cpu_row * n_rows / world.workers, "s",
               f"{n_rows} rows x CPU s/row / {world.workers} cores: the build time on 2 idle cores"),
    ]
