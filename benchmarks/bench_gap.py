"""Gap diagnosis wall time: 240 recordings, the default settings of conf/diagnose.yaml, 2 threads.

The recordings are 240 reference-world recordings (handradar.world.write_world_recordings, the
default world with every effect on; written once into .cache/bench_gap/recordings and kept, not
timed) or the folder named by HANDRADAR_BENCH_GAP_RECORDINGS. Timed: what ``python diagnose.py
data.root=DIR`` does after composing its config: ingest into a dataset file, then the diagnosis
(visibility features, slot-profile cache, grid fit, evaluation, greedy selection, RadarWeightNet
readout), with nothing cached beforehand; then the same without the RadarWeightNet readout. The
phases come from the report's ``timings_s``. Target: the whole diagnosis within 5 minutes (issue 44).
``diagnose.folds=auto`` cross-fits 240 recordings in 2 folds; the largest folder it cross-fits in 3
(59 recordings) is timed too, with the readout.

``noise_grid``: the noise candidate's grid as a diagnosis pass evaluates it (9 SNR values, 4 draws
each, every simulator seeded alike) on one batch of 8 windows, with the unit-noise cache
(handradar.sim.effects.noise.unit_noise) and with it switched off (every variant draws again).

Run: ``PYTHONPATH=$PWD/src:$PWD python -m benchmarks bench_gap``.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import time
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf

from benchmarks.common import Result, best_time
from handradar.config import VERSION_BASE, config_dir
from handradar.data.ingest import ingest
from handradar.gap.data import load_dataset
from handradar.gap.diagnosis import diagnose
from handradar.gap.folds import AUTO_SMALL_BELOW_ROWS
from handradar.provenance import REPO_ROOT
from handradar.sim.factory import SimFactory

N_RECORDINGS = 240


def _conf(name: str):
    return OmegaConf.load(REPO_ROOT / "conf" / f"{name}.yaml")


def recordings() -> Path:
    env = os.environ.get("HANDRADAR_BENCH_GAP_RECORDINGS")
    if env:
        return Path(env)
    from handradar.world import (
        write_world_recordings,  # the reference world (docs/architecture.md, "Reference world")
    )

    out = REPO_ROOT / ".cache" / "bench_gap" / "recordings"
    write_world_recordings(None, instantiate(_conf("radar/awr1843")), out, limit=N_RECORDINGS, progress=False)
    return out


def noise_grid(threads: int) -> list[Result]:
    from handradar.sim.effects import noise
    from handradar.sim.simulator import Simulator

    radar, chain = instantiate(_conf("radar/awr1843")), instantiate(_conf("chain/default"))
    shape = (8, chain.frames_per_window(radar), radar.n_loops, radar.chirps_per_loop * radar.n_rx, 8)
    signal = torch.complex(torch.randn(shape), torch.randn(shape))
    sims = [Simulator(radar, chain, effects=["noise"], effect_params={"noise": {"snr_db": snr, "draws": 4}})
            for snr in noise.Noise.params["snr_db"].grid]

    def grid() -> None:
        noise._DRAW_CACHE.clear()  # a pass starts cold: its first variant draws
        for sim in sims:
            sim.effect("noise").reset_rng()
            sim.spectrogram(signal)

    size = noise._DRAW_CACHE_SIZE
    try:
        cached = best_time(grid)
        noise._DRAW_CACHE_SIZE = 0  # every draw evicted at once: each variant draws again
        redrawn = best_time(grid)
    finally:
        noise._DRAW_CACHE_SIZE = size
    note = f"{len(sims)} SNR values x 4 draws on 8 windows, {threads} threads"
    return [Result("noise_grid_cached_draws", cached, "s", note),
            Result("noise_grid_redrawn", redrawn, "s", f"{note}; the cache off"),
            Result("noise_grid_speedup", redrawn / cached, "x", "redrawn / cached")]


def crossfit_subset(root: Path, n: int, out: Path) -> Path:
    """A folder with copies of ``n`` of the recordings in ``root`` (not timed), taken gesture by gesture in turn (each
    recording folder is named ``<gesture>_s<subject>_...``), so every gesture keeps rows in every fold."""
    by_gesture: dict[str, list[Path]] = {}
    for rec in sorted(p for p in root.iterdir() if p.is_dir()):
        by_gesture.setdefault(re.sub(r"_s\d+_.*$", "", rec.name), []).append(rec)
    queues, picked = list(by_gesture.values()), []
    while len(picked) < n and any(queues):
        picked += [q.pop(0) for q in queues if q][: n - len(picked)]
    out.mkdir(parents=True)
    for rec in picked:
        shutil.copytree(rec, out / rec.name)  # copies: ingest does not follow linked folders
    return out


def run() -> list[Result]:
    threads = int(os.environ.get("HANDRADAR_BENCH_THREADS", "2"))
    torch.set_num_threads(threads)
    root = recordings()
    chain = instantiate(_conf("chain/default"))
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        sim_cfg = compose("diagnose", overrides=["data.root=/unused"]).sim  # the paper's simulator, as diagnose.py has it
    diag_cfg = OmegaConf.to_container(_conf("diagnose").diagnose, resolve=True)
    out: list[Result] = noise_grid(threads)
    with tempfile.TemporaryDirectory() as tmp:
        # the default diagnosis of N_RECORDINGS (2 folds), with and without the readout; then the largest
        # folder that diagnose.folds=auto cross-fits in 3 folds
        for n_rec, rwns in ((N_RECORDINGS, (True, False)), (AUTO_SMALL_BELOW_ROWS - 1, (True,))):
            folder = root if n_rec == N_RECORDINGS else crossfit_subset(root, n_rec, Path(tmp) / f"subset{n_rec}")
            t0 = time.perf_counter()
            ingest(folder, Path(tmp) / f"data{n_rec}.h5", chain, progress=False)
            t_ingest = time.perf_counter() - t0
            data = load_dataset(Path(tmp) / f"data{n_rec}.h5")
            n = len(data)
            for rwn in rwns:
                cfg = {**diag_cfg, "radarweightnet": rwn}
                t0 = time.perf_counter()
                factory = SimFactory.from_config(sim_cfg, data.radar, data.chain)
                d = diagnose(data, factory, factory.effects, cfg,
                             cache_dir=Path(tmp) / f"cache-{n_rec}-{rwn}", progress=False)
                wall = time.perf_counter() - t0
                tag = "with RadarWeightNet readout" if rwn else "without RadarWeightNet (diagnose.radarweightnet=false)"
                phases = ", ".join(f"{k} {v:.0f} s" for k, v in d.report["timings_s"].items())
                out.append(Result(f"gap_diagnosis_{'rwn' if rwn else 'no_rwn'}_{n}rec", wall + t_ingest, "s",
                                  f"{tag}; ingest {t_ingest:.0f} s, {phases}; cause {d.report['cause']}; "
                                  f"folds {d.report['settings']['folds']}; {threads} threads; target <= 300 s"))
    return out
