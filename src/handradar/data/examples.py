"""One recording -> one dataset row: the measured spectrogram and the skeleton of its window."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from handradar.data.recording import Recording
from handradar.hand.skeleton import HandSequence
from handradar.radar.chain import ChainConfig, measured_spectrogram


@dataclass
class Example:
    spectrogram: np.ndarray  # (64, 32) float32 in [0, 1]
    skeleton: HandSequence  # resampled over the window; times relative to the window start
    window_start_s: float  # start of the window's first frame on the radar clock


def window_times(n_frames: int, frame_period_s: float, rate_hz: float) -> np.ndarray:
    """Skeleton sample times (s, relative to the window start) over a window of ``n_frames`` frames."""
    n = int(round(n_frames * frame_period_s * rate_hz))
    return np.arange(n) / rate_hz


def skeleton_steps(chain: ChainConfig, radar, rate_hz: float) -> int:
    return len(window_times(chain.frames_per_window(radar), radar.frame_period_s, rate_hz))


def recording_example(rec: Recording, chain: ChainConfig, skeleton_rate_hz: float) -> Example:
    spec, start_frame = measured_spectrogram(rec.adc, rec.radar, chain)
    t0 = start_frame * rec.radar.frame_period_s
    rel = window_times(chain.frames_per_window(rec.radar), rec.radar.frame_period_s, skeleton_rate_hz)
    window = rec.skeleton.resample(t0 + rel)
    window.times = rel
    return Example(spec.numpy().astype(np.float32), window, t0)
