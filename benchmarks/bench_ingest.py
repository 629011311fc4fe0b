"""Ingest throughput: synthetic recordings of the default radar -> HDF5, against a bare range FFT.

Writes ~20 recordings (24 frames each: 3.1 MB of ADC) with handradar's own writers, then times
``handradar.data.ingest.ingest`` over them (recordings/s, MB/s of ADC) and a bare
``numpy.fft.fft`` over the same cubes already in memory (the floor any ingest must pay: reading,
the slow-time STFT, resampling and writing come on top). The ratio says how many bare FFTs one
ingest costs.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pydantic_core

from benchmarks.common import Result, best_time
from handradar.data.examples import recording_example
from handradar.data.ingest import ingest
from handradar.data.recording import (
    RecordingMeta,
    load_recording,
    read_meta,
    write_meta,
)
from handradar.hand.leap import (
    leap_frames_from_sequence,
    read_leap_jsonl,
    write_leap_jsonl,
)
from handradar.hand.skeleton import HandSequence
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig
from handradar.radar.dca1000 import read_adc, write_adc
from handradar.radar.signal import beat_signal
from handradar.vocab import GESTURES

N_RECORDINGS = 20
N_FRAMES = 24
DEFAULT_CFG = """\
channelCfg 1 1 0
adcCfg 2 1
profileCfg 0 77 338.8 6 51.2 0 0 76.22 1 256 10000 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
frameCfg 0 0 128 {frames} 100 1 0
"""
# Leap mm -> radar m: Leap y (up) is boresight
LEAP_TO_RADAR = np.array([[1e-3, 0, 0, 0], [0, 0, -1e-3, 0], [0, 1e-3, 0, 0], [0, 0, 0, 1]])


def write_recordings(root: Path, n: int = N_RECORDINGS, n_frames: int = N_FRAMES, seed: int = 0) -> RadarConfig:
    """``n`` recordings: a few point reflectors on a hand moving along boresight, plus noise."""
    radar = RadarConfig.from_cfg_text(DEFAULT_CFG.format(frames=n_frames))
    rng = np.random.default_rng(seed)
    t = radar.chirp_times_s(n_frames)[..., 0]  # (frames, loops)
    for i in range(n):
        folder = root / f"rec{i:03d}"
        folder.mkdir(parents=True)
        (folder / "radar.cfg").write_text(radar.to_cfg())
        v = rng.uniform(-0.3, 0.3)
        r0 = rng.uniform(0.3, 0.45, size=3)
        ranges = (r0 + v * np.clip(t, 0.4, 2.0)[..., None]).reshape(n_frames, radar.chirps_per_frame, 1, 3)
        adc = beat_signal(radar, ranges, np.full(ranges.shape, 800.0))
        adc += rng.normal(0, 20, adc.shape) + 1j * rng.normal(0, 20, adc.shape)
        write_adc(folder / "adc_data.bin", adc, radar)
        lt = np.arange(-0.1, n_frames * radar.frame_period_s + 0.1, 0.01)
        pos = np.zeros((len(lt), 2, 21, 3), np.float32)
        pos[:, 0] = rng.uniform(-0.05, 0.05, (21, 3)) + [0, 0, 0.35]
        pos[:, 0, :, 2] += v * (np.clip(lt, 0.4, 2.0) - 0.4)[:, None]
        seq = HandSequence(pos, lt, np.tile([True, False], (len(lt), 1)))
        write_leap_jsonl(folder / "leap.jsonl", leap_frames_from_sequence(seq, np.linalg.inv(LEAP_TO_RADAR), 5e6))
        meta = RecordingMeta(gesture=GESTURES[i % 10], subject=f"s{i % 4}", angle_deg=0.0, hands=1,
                             occlusion=False, repetition=i, radar_start_us=5e6,
                             leap_to_radar=tuple(map(tuple, LEAP_TO_RADAR.tolist())))
        write_meta(folder, meta)
    return radar


def _parse_each(parse: Callable[[bytes], object], lines: list[bytes]) -> None:
    """Parse every line and drop the result at once, as read_leap_jsonl does: keeping thousands of
    parsed frames alive makes the garbage collector's passes, not the parser, the cost."""
    for line in lines:
        parse(line)


def run() -> list[Result]:
    chain = ChainConfig()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "recs"
        radar = write_recordings(root)
        folders = sorted(root.iterdir())
        out = Path(tmp) / "d.h5"
        t_ingest = best_time(lambda: ingest(root, out, chain, progress=False), repeat=5)
        cubes = [read_adc(p / "adc_data.bin", radar) for p in folders]
        t_fft = best_time(lambda: [np.fft.fft(c, axis=-1) for c in cubes], repeat=5)
        # where the time goes, stage by stage (best of 3 over all recordings)
        meta = [read_meta(p) for p in folders]
        t_leap = best_time(lambda: [read_leap_jsonl(p / "leap.jsonl", np.asarray(m.leap_to_radar), m.radar_start_us)
                                    for p, m in zip(folders, meta)], repeat=5)
        leap_lines = [line for p in folders for line in (p / "leap.jsonl").read_bytes().splitlines()]
        t_parse = best_time(lambda: _parse_each(pydantic_core.from_json, leap_lines), repeat=5)
        t_json = best_time(lambda: _parse_each(json.loads, leap_lines), repeat=5)
        t_read = best_time(lambda: [read_adc(p / "adc_data.bin", radar) for p in folders], repeat=5)
        recs = [load_recording(p) for p in folders]
        t_chain = best_time(lambda: [recording_example(r, chain, 100.0) for r in recs], repeat=5)
    n = len(cubes)
    mb = sum(c.shape[0] for c in cubes) * radar.frame_bytes() / 1e6
    per = 1e3 / n
    return [
        Result("ingest throughput", n / t_ingest, "recordings/s", f"{n} recordings x {N_FRAMES} frames, default radar"),
        Result("ingest ADC throughput", mb / t_ingest, "MB/s", f"{mb:.1f} MB of int16 ADC"),
        Result("bare numpy range FFT", mb / t_fft, "MB/s", "np.fft.fft over the same complex64 cubes in memory"),
        Result("ingest / bare FFT time", t_ingest / t_fft, "x", "1 = ingest as cheap as one range FFT"),
        Result("ingest per recording", t_ingest * per, "ms", "everything: read, validate, chain, resample, write"),
        Result("  leap.jsonl read", t_leap * per, "ms", f"of which the JSON parse alone {t_parse * per:.1f} ms "
                                                         f"(pydantic-core, as read_leap_jsonl; json.loads {t_json * per:.1f})"),
        Result("ingest / bare FFT time, JSON parse excluded", (t_ingest - t_parse) / t_fft, "x",
               "the JSON format's floor: the ratio if parsing leap.jsonl cost nothing"),
        Result("  adc_data.bin read", t_read * per, "ms", f"{mb / t_read:.0f} MB/s to complex64"),
        Result("  chain + skeleton window", t_chain * per, "ms", "measured_spectrogram + resample"),
    ]


if __name__ == "__main__":
    for r in run():
        print(r.row())
