"""Recordings and datasets of the reference world.

Every recording is fixed by (world.seed, subject, gesture, angle, repetition): its random streams
are spawned from ``SeedSequence(world.seed)`` with that key, so a recording does not depend on
which others are generated with it, nor on the worker that generates it.

- :func:`write_recording` / :func:`write_world_recordings`: ``handradar.recording/1`` folders (ADC path).
- :func:`build_world_dataset`: the HDF5 dataset straight from the fast path (same physics, same
  noise draw), cached under a hash of the configuration and written atomically. Each row's window
  is chosen from its radar data, as ingest does; ``window_starts_s`` imposes another dataset's
  windows instead, so that two worlds can be compared row by row over the same stretch of motion
  (an effect that changes the radar data can move the chosen window by tenths of a second).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from handradar.data.examples import skeleton_steps, window_times
from handradar.data.hdf5 import open_writer
from handradar.data.recording import RecordingMeta, write_meta
from handradar.hand.leap import write_leap_jsonl
from handradar.provenance import config_hash
from handradar.radar.chain import ChainConfig, capture_spectrogram
from handradar.radar.config import RadarConfig
from handradar.radar.dca1000 import write_adc
from handradar.vocab import GESTURES
from handradar.world.config import WORLD_VERSION, WorldConfig, world_config
from handradar.world.kinematics import GESTURE_TABLE, Motion, Subject
from handradar.world.render import adc_cube, fast_profiles, noise_sigma
from handradar.world.scene import scene_tracks
from handradar.world.sensor import LeapObservation, nominal_leap_to_radar, observe
from handradar.world.tracks import ScatterTracks


@dataclass(frozen=True)
class RecordingSpec:
    gesture: str
    subject: int  # 0-based
    angle_deg: float
    repetition: int  # 0-based

    @property
    def name(self) -> str:
        return f"{self.gesture}_s{self.subject + 1:02d}_a{int(round(self.angle_deg)):+03d}_r{self.repetition}"

    def key(self) -> tuple[int, ...]:
        return (GESTURES.index(self.gesture), self.subject, int(round(self.angle_deg * 10)) + 100_000, self.repetition)


def recording_specs(world: WorldConfig) -> list[RecordingSpec]:
    """Every recording of the world: subjects x gestures x angles x repetitions."""
    return [RecordingSpec(g, s, float(a), r) for s in range(world.subjects) for g in world.gestures
            for a in world.angles_deg for r in range(world.repetitions)]


def capture_radar(radar: RadarConfig, world: WorldConfig) -> RadarConfig:
    """The radar set-up with the world's capture length (frameCfg numFrames)."""
    return dataclasses.replace(radar, n_frames=world.capture_frames)


def subject(world: WorldConfig, index: int) -> Subject:
    rng = np.random.default_rng(np.random.SeedSequence(world.seed, spawn_key=(1, index)))
    return Subject.sample(index, rng, world.kinematics, world.scene.finger_radius_m)


@dataclass
class Simulated:
    """Everything of one recording except its radar signal."""

    spec: RecordingSpec
    radar: RadarConfig  # with the capture's frame count
    motion: Motion
    tracks: ScatterTracks
    noise_sigma: float
    leap: LeapObservation
    meta: RecordingMeta
    truth: dict
    rng_noise: np.random.Generator
    rng_quant: np.random.Generator


def simulate(world: WorldConfig, radar: RadarConfig, spec: RecordingSpec) -> Simulated:
    """Kinematics, scene tracks, noise level and the Leap stream of one recording."""
    world = world_config(world)
    cap = capture_radar(radar, world)
    capture_s = cap.n_frames * cap.frame_period_s
    subj = subject(world, spec.subject)
    kin_ss, scene_ss, leap_ss, noise_ss, quant_ss = np.random.SeedSequence(world.seed, spawn_key=(2, *spec.key())).spawn(5)
    motion = Motion(spec.gesture, subj, spec.angle_deg, capture_s, world.kinematics, np.random.default_rng(kin_ss),
                    forearm_m=world.effects.forearm.length_m)
    dt = 1.0 / world.scene.rate_hz
    times = np.arange(-2 * dt, capture_s + 2.5 * dt, dt)
    tracks = scene_tracks(motion.pose(times), world.effects, world.scene, np.random.default_rng(scene_ss), cap)
    fx = world.effects
    sigma = noise_sigma(tracks, cap, fx.noise.snr_db) if fx.noise.enabled else 0.0
    leap = observe(motion, capture_s, world.leap, fx, np.random.default_rng(leap_ss))
    hands, occlusion = GESTURE_TABLE[spec.gesture]
    meta = RecordingMeta(gesture=spec.gesture, subject=f"s{spec.subject + 1:02d}", angle_deg=spec.angle_deg,
                         hands=hands, occlusion=occlusion, repetition=spec.repetition,
                         radar_start_us=float(leap.radar_start_us),
                         leap_to_radar=tuple(tuple(float(v) for v in row) for row in nominal_leap_to_radar()))
    truth = {
        "generator": WORLD_VERSION,
        "seed": world.seed,
        "effects": {name: dataclasses.asdict(getattr(fx, name)) for name in fx.__dataclass_fields__},
        "enabled": fx.enabled(),
        "sync_offset_s": leap.sync_offset_s,
        "leap_to_radar_true": leap.leap_to_radar_true.tolist(),
        "leap_dropped_frames": leap.dropped,
        "noise_sigma_counts": sigma,
        "subject": subj.summary(),
        "gesture_start_s": motion.start_s,
        "gesture_duration_s": motion.duration_s,
        "amplitude": motion.amplitude,
        "centre_m": motion.centre.tolist(),
        "hand_slots": motion.slots,
        "n_scatterers": int(tracks.kind.size),  # tracks: facets, bounce paths, static reflectors
        "n_surface_elements": 0 if tracks.surface is None else int(tracks.surface.n_elements),
        "n_texture_points": 0 if tracks.surface is None else int(tracks.surface.n_points),
    }
    rngs = [np.random.default_rng(s) for s in (noise_ss, quant_ss)]
    return Simulated(spec, cap, motion, tracks, sigma, leap, meta, truth, *rngs)


def simulate_adc(sim: Simulated, world: WorldConfig) -> np.ndarray:
    """The recording's complex ADC cube (counts, before int16 rounding)."""
    return adc_cube(sim.tracks, sim.radar, sim.radar.n_frames, world.effects, sim.rng_noise, sim.noise_sigma)


def write_recording(world: Any, radar: RadarConfig, spec: RecordingSpec, folder: str | Path) -> Path:
    """Write one ``handradar.recording/1`` folder; it appears complete or not at all."""
    world = world_config(world)
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    sim = simulate(world, radar, spec)
    adc = simulate_adc(sim, world)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".part", dir=folder.parent))
    try:
        (tmp / "radar.cfg").write_text(sim.radar.to_cfg(), encoding="utf-8")
        write_adc(tmp / "adc_data.bin", adc, sim.radar)
        write_leap_jsonl(tmp / "leap.jsonl", sim.leap.frames())
        write_meta(tmp, sim.meta, truth=sim.truth)
        if folder.exists():
            shutil.rmtree(folder)
        os.replace(tmp, folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return folder


def fast_example(world: Any, radar: RadarConfig, chain: ChainConfig, spec: RecordingSpec,
                 window_start_frame: int | None = None) -> dict:
    """One dataset row from the fast path: spectrogram, label, skeleton window (as ingest would give).

    window_start_frame: the window's first radar frame; None chooses it from the radar data as ingest does.
    """
    world = world_config(world)
    sim = simulate(world, radar, spec)
    profiles = fast_profiles(sim.tracks, sim.radar, chain, sim.radar.n_frames, world.effects, sim.rng_noise,
                             sim.rng_quant, sim.noise_sigma)
    spec_map, start = capture_spectrogram(profiles, sim.radar, chain, window_start_frame)
    seq = sim.leap.as_read()  # exactly what ingest would read from the recording's leap.jsonl
    t0 = start * sim.radar.frame_period_s
    rel = window_times(chain.frames_per_window(sim.radar), sim.radar.frame_period_s, world.skeleton_rate_hz)
    window = seq.resample(t0 + rel)
    labels = sim.meta.labels()
    labels["recording"] = spec.name
    return {"spectrogram": spec_map.numpy().astype(np.float32), "label": sim.meta.label,
            "skeleton": window.positions, "hand_mask": window.mask, "window_start_s": t0, "meta": labels}


# ---- parallel drivers ----------------------------------------------------------------------------
def _init_worker() -> None:
    torch.set_num_threads(1)  # one core per worker process


def _run_parallel(fn: Callable, jobs: list, workers: int, progress: bool, desc: str) -> Iterator:
    """fn(*job) for every job, results in job order, in ``workers`` processes (1: in this process)."""
    bar = tqdm(total=len(jobs), desc=desc, unit="rec", disable=not progress)
    try:
        if workers <= 1:
            threads = torch.get_num_threads()
            torch.set_num_threads(1)
            try:
                for job in jobs:
                    yield fn(*job)
                    bar.update()
            finally:
                torch.set_num_threads(threads)
            return
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"), initializer=_init_worker)
        try:
            for result in pool.map(fn, *zip(*jobs), chunksize=1):
                yield result
                bar.update()
        finally:  # on Ctrl-C or an error, drop the queued work instead of finishing it
            pool.shutdown(wait=True, cancel_futures=True)
    finally:
        bar.close()


# Settings added after worlds were cached, and when they leave the data as it was before they existed:
# there they stay out of the key, so every world cached before keeps its key (tests/world/test_points_world.py).
ADDED_LATER: tuple[tuple[str, Callable[[WorldConfig], bool]], ...] = (
    ("scene.facet_turn", lambda w: w.scene.facet_turn == 0.0),
    ("scene.scattering", lambda w: w.scene.scattering == "surfaces"),
    ("scene.points", lambda w: w.scene.scattering == "surfaces"),  # read by bone_points scattering only
    ("leap.jitter_floor_m", lambda w: w.leap.jitter_floor_m == 0.0),
)


def dataset_path(world: Any, radar: RadarConfig, chain: ChainConfig, cache_dir: str | Path,
                 window_starts: Sequence[int] | None = None) -> tuple[Path, str]:
    """Cache file of the world's dataset and its config hash (radar, chain, world physics, generator
    version, and the imposed window start frames if any)."""
    world = world_config(world)
    physics = {k: v for k, v in world.to_dict().items() if k != "workers"}  # workers do not change the data
    for key, unchanged in ADDED_LATER:
        if unchanged(world):
            section, name = key.split(".")
            del physics[section][name]
    parts = (physics, capture_radar(radar, world), chain, WORLD_VERSION, "fast-path")
    h = config_hash(*parts, [int(s) for s in window_starts]) if window_starts is not None else config_hash(*parts)
    return Path(cache_dir) / f"world_{h}.h5", h


def _window_start_frames(window_starts_s: Sequence[float], radar: RadarConfig, n_rows: int) -> list[int]:
    """Window start times (s, a dataset's ``window_start_s``, row by row) -> radar frame indices."""
    if len(window_starts_s) != n_rows:
        raise ValueError(f"{len(window_starts_s)} window starts given for a world of {n_rows} recordings")
    frames = [int(round(float(t) / radar.frame_period_s)) for t in window_starts_s]
    off = [f"{t:g} s" for t, f in zip(window_starts_s, frames) if abs(f * radar.frame_period_s - float(t)) > 1e-6]
    if off:
        raise ValueError(f"window starts must fall on radar frames ({radar.frame_period_s * 1e3:g} ms apart): {off[:3]}")
    return frames


def build_world_dataset(world_cfg: Any, radar: RadarConfig, chain: ChainConfig, cache_dir: str | Path, *,
                        progress: bool = True, window_starts_s: Sequence[float] | None = None) -> Path:
    """The world's HDF5 dataset (handradar.dataset/1) via the fast path; cached by config hash.

    world_cfg: the ``world`` config node (DictConfig / dict) or a WorldConfig. Returns the cached
    file when it exists; otherwise builds it with ``world.workers`` processes (spawned: a calling
    script needs the usual ``if __name__ == "__main__":`` guard). An interrupted build leaves
    nothing behind. window_starts_s: each row's window start (s; another world's ``window_start_s``,
    in the same row order) instead of the window its own radar data would choose.
    """
    world = world_config(world_cfg)
    cap = capture_radar(radar, world)
    specs = recording_specs(world)
    starts = None if window_starts_s is None else _window_start_frames(window_starts_s, cap, len(specs))
    path, h = dataset_path(world, radar, chain, cache_dir, starts)
    if path.is_file():
        return path
    jobs = [(world, radar, chain, s, None if starts is None else starts[i]) for i, s in enumerate(specs)]
    with open_writer(path, classes=GESTURES, radar=cap, chain=chain, skeleton_rate_hz=world.skeleton_rate_hz,
                     n_steps=skeleton_steps(chain, cap, world.skeleton_rate_hz), config_hash=h,
                     extra_attrs={"world_config": json.dumps(world.to_dict()), "source": "handradar.world"}) as w:
        for row in _run_parallel(fast_example, jobs, world.workers, progress, "world dataset"):
            w.append(row["spectrogram"], row["label"], row["skeleton"], row["hand_mask"], row["window_start_s"],
                     row["meta"])
    return path


def write_world_recordings(world_cfg: Any, radar: RadarConfig, out: str | Path, *, limit: int | None = None,
                           progress: bool = True, overwrite: bool = False) -> list[Path]:
    """Write the world's recordings under ``out`` (ADC path); finished ones are kept (resumable)."""
    world = world_config(world_cfg)
    out = Path(out)
    specs = recording_specs(world)[:limit] if limit else recording_specs(world)
    todo = [s for s in specs if overwrite or not (out / s.name / "meta.json").is_file()]
    jobs = [(world, radar, s, out / s.name) for s in todo]
    for _ in _run_parallel(write_recording, jobs, world.workers, progress, "world recordings"):
        pass
    return [out / s.name for s in specs]

