"""Raw IF (beat) signal of point reflectors: the ADC-level model behind the chain's sign convention.

s[n] = sum_k A_k exp(j 2 pi f_b,k n / fs) exp(-j 4 pi R_k / lambda),   f_b,k = 2 S R_k / c

with R_k taken at each chirp's sampling centre (motion within one chirp is neglected: at 2 m/s a
hand moves 50 um during a 25.6 us sampling window). Used to write raw captures (tests, the reference
world); the simulator instead uses the closed-form range response of the chain.
"""

from __future__ import annotations

import numpy as np

from handradar.radar.config import RadarConfig


def beat_signal(radar: RadarConfig, ranges_m: np.ndarray, amplitudes: np.ndarray,
                *, chunk: int = 64) -> np.ndarray:
    """Complex ADC samples of K reflectors.

    ranges_m, amplitudes: (frames, chirps_per_frame, rx | 1, K) at each chirp (broadcast over rx).
    Returns (frames, chirps_per_frame, n_rx, samples) complex64 (ADC counts if A is in counts).
    """
    ranges_m = np.asarray(ranges_m, dtype=np.float64)
    amplitudes = np.asarray(amplitudes)
    frames, chirps = ranges_m.shape[:2]
    ranges_m = np.broadcast_to(ranges_m, (frames, chirps, radar.n_rx, ranges_m.shape[-1]))
    amplitudes = np.broadcast_to(amplitudes, ranges_m.shape)
    n = np.arange(radar.n_samples) / radar.sample_rate_hz
    out = np.empty((frames, chirps, radar.n_rx, radar.n_samples), dtype=np.complex64)
    k_phase = -4.0 * np.pi / radar.wavelength_m
    for f0 in range(0, frames, max(1, chunk // max(1, chirps // 128))):
        f1 = min(frames, f0 + max(1, chunk // max(1, chirps // 128)))
        r = ranges_m[f0:f1]
        fb = radar.beat_frequency_hz(r)  # (f, c, rx, K)
        carrier = amplitudes[f0:f1] * np.exp(1j * k_phase * r)
        tone = np.exp(2j * np.pi * fb[..., None, :] * n[:, None])  # (f, c, rx, N, K)
        out[f0:f1] = np.einsum("fcrnk,fcrk->fcrn", tone, carrier).astype(np.complex64)
    return out
