"""Scatterer tracks -> radar signals, at the true chirp times.

Two routes with the same physics (docs/architecture.md, "Processing chain and simulator" sign convention, see handradar.radar.signal):

- ADC path: the complex beat signal of every scatterer sampled at each chirp, receiver noise,
  receiver I/Q imbalance, then int16 rounding when the capture is written (dca1000.write_adc).
- fast path: the per-range-bin slow-time signal of the gated bins directly, each scatterer through
  the closed-form windowed range response of the chain (handradar.radar.chain.range_response,
  tabulated finely in beat frequency); the noise is the windowed FFT of the very same noise draw,
  and int16 rounding is replaced by its equivalent, white noise of 1/12 count^2 per I and Q.

Motion: scatterer ranges are interpolated from the physics rate to each chirp's sampling time
(RadarConfig.chirp_times_s, idle gaps between frames included) with a cubic spline, point
amplitudes (which carry the shadowing) linearly; a facet track's complex amplitude is evaluated at
each chirp from its physical-optics elements and texture points (tracks.SurfaceTracks), whose
relative phases change much faster than the physics rate.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from handradar.radar.chain import (
    ChainConfig,
    gate_bins,
    range_response,
    window,
)
from handradar.radar.config import RadarConfig
from handradar.radar.signal import carrier_phase_rad, doppler_mirror
from handradar.world.config import Effects, IQImbalance
from handradar.world.tracks import STATIC, ScatterTracks

_BLOCK = 16  # fast-time samples per block of the matrix-product synthesis
_TABLE_STEPS_PER_BIN = 64


def interpolate_tracks(tracks: ScatterTracks, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ranges (cubic spline) and complex amplitudes at ``times`` (any shape) -> (*times.shape, K):
    facet tracks evaluated from their surface elements, point scatterers interpolated linearly."""
    return tracks.at(times)


def carrier(radar: RadarConfig, ranges_m: np.ndarray, amps: np.ndarray) -> np.ndarray:
    """Slow-time phasor A exp(+j 4 pi R / lambda_0) of each scatterer (complex128, signal.carrier_phase_rad)."""
    return amps * np.exp(1j * carrier_phase_rad(radar, ranges_m))


def _powers(step: torch.Tensor, n: int) -> torch.Tensor:
    """step^0 .. step^(n-1) along a new last axis (complex64), by a running product (n is small:
    the rounding error grows like n eps)."""
    out = step.unsqueeze(-1).expand(*step.shape, n).clone()
    out[..., 0] = 1.0
    return torch.cumprod(out, dim=-1)


def synthesize_beat(radar: RadarConfig, ranges_m: np.ndarray, amps: np.ndarray) -> np.ndarray:
    """Beat signal sum_k A_k exp(j 2 pi f_b,k n / fs) exp(+j 4 pi R_k / lambda_0) (signal.beat_signal's model).

    ranges_m, amps: (C, K) at C chirps -> (C, n_samples) complex64. Written as a batched matrix
    product: with n = B m + r, exp(j 2 pi nu n) = exp(j 2 pi nu r) exp(j 2 pi nu B m), each factor
    a power series of one phasor.
    """
    n = radar.n_samples
    block = _BLOCK if n % _BLOCK == 0 else 1
    nu = torch.as_tensor(radar.beat_frequency_hz(ranges_m) / radar.sample_rate_hz, dtype=torch.float64)
    car = torch.as_tensor(carrier(radar, ranges_m, amps)).to(torch.complex64)
    ones = torch.ones_like(nu)
    step_r = torch.polar(ones, 2 * math.pi * nu).to(torch.complex64)
    step_m = torch.polar(ones, 2 * math.pi * nu * block).to(torch.complex64)
    a = car[..., None] * _powers(step_r, block)  # (C, K, B)
    b = _powers(step_m, n // block)  # (C, K, M)
    out = torch.bmm(b.transpose(-1, -2), a)  # (C, M, B): sample B m + r
    return out.reshape(*ranges_m.shape[:-1], n).numpy()


def noise_sigma(tracks: ScatterTracks, radar: RadarConfig, snr_db: float) -> float:
    """Complex noise rms (counts) giving ``snr_db`` against the mean power per ADC sample of the
    moving scene (static clutter excluded), evaluated at the physics-rate times."""
    moving = tracks.select(tracks.kind != STATIC)
    if not moving.kind.size:
        return 0.0
    every = max(1, len(moving.times) // 64)  # 64 instants estimate the mean power well
    x = synthesize_beat(radar, moving.ranges[::every], moving.amplitudes[::every])
    power = float(np.mean(np.abs(x) ** 2))
    return math.sqrt(power / 10 ** (snr_db / 10))


def iq_coefficients(iq: IQImbalance) -> tuple[complex, complex]:
    """(mu, nu) of y = mu x + nu conj(x) for gain imbalance g (dB) and phase error phi (deg)."""
    g = 10 ** (iq.gain_db / 20)
    phi = math.radians(iq.phase_deg)
    return (1 + g * np.exp(-1j * phi)) / 2, (1 - g * np.exp(1j * phi)) / 2


def receiver_noise(rng: np.random.Generator, shape: tuple[int, ...], sigma: float) -> np.ndarray:
    """Circular complex Gaussian noise of total power sigma^2 per sample (complex64)."""
    z = rng.standard_normal(shape + (2,), dtype=np.float32) * np.float32(sigma / math.sqrt(2))
    return z.view(np.complex64)[..., 0]


def chirp_times(radar: RadarConfig, n_frames: int) -> np.ndarray:
    """(frames, chirps_per_frame) chirp sampling times (s), chirps in time order (loop-major, then TX)."""
    return radar.chirp_times_s(n_frames).reshape(n_frames, radar.chirps_per_frame)


def adc_cube(tracks: ScatterTracks, radar: RadarConfig, n_frames: int, effects: Effects,
             rng_noise: np.random.Generator, sigma: float) -> np.ndarray:
    """ADC path: complex ADC counts (frames, chirps_per_frame, rx, samples), not yet rounded."""
    t = chirp_times(radar, n_frames)
    out = np.empty((n_frames, radar.chirps_per_frame, radar.n_rx, radar.n_samples), dtype=np.complex64)
    for f in range(n_frames):
        ranges, amps = interpolate_tracks(tracks, t[f])
        out[f] = synthesize_beat(radar, ranges, amps)[:, None, :]
    if effects.noise.enabled:
        out += receiver_noise(rng_noise, out.shape, sigma)
    iq = effects.iq_imbalance
    if iq.enabled:
        mu, nu = iq_coefficients(iq)
        if iq.stage == "adc":
            out = mu * out + nu * np.conj(out)
        else:  # slow_time: the image sits in the same range bin, Doppler mirrored
            out = mu * out + nu * doppler_mirror(out)
    return out.astype(np.complex64)


def response_table(radar: RadarConfig, chain: ChainConfig, bins: np.ndarray, nu_max: float) -> tuple[torch.Tensor, float]:
    """range_response tabulated on a fine beat-frequency grid: (steps, bins) complex128 and the step."""
    n = radar.n_samples
    step = 1.0 / (n * _TABLE_STEPS_PER_BIN)
    grid = torch.arange(0, int(nu_max / step) + 3, dtype=torch.float64) * step
    return range_response(grid, torch.as_tensor(bins), n, chain.range_window), step


def fast_profiles(tracks: ScatterTracks, radar: RadarConfig, chain: ChainConfig, n_frames: int, effects: Effects,
                  rng_noise: np.random.Generator, rng_quant: np.random.Generator, sigma: float) -> torch.Tensor:
    """Fast path: per-range-bin slow-time signal (frames, loops, channels, gated bins) complex64."""
    b0, b1 = gate_bins(radar, chain)
    gated = np.arange(b0, b1)
    iq = effects.iq_imbalance
    mirror = iq.enabled and iq.stage == "adc"
    n = radar.n_samples
    bins = np.concatenate([gated, (n - gated) % n]) if mirror else gated
    t = chirp_times(radar, n_frames)
    nu_max = float(radar.beat_frequency_hz(tracks.ranges.max()) / radar.sample_rate_hz) + 0.05
    table, step = response_table(radar, chain, bins, nu_max)
    table = table.to(torch.complex64)
    prof = torch.empty((n_frames, radar.chirps_per_frame, len(bins)), dtype=torch.complex64)
    for f in range(n_frames):
        ranges, amps = interpolate_tracks(tracks, t[f])
        nu = radar.beat_frequency_hz(ranges) / radar.sample_rate_hz
        x = torch.as_tensor(nu / step)
        i0 = x.floor().long()
        w = (x - i0).to(torch.float32)[..., None]
        h = table[i0] * (1 - w) + table[i0 + 1] * w  # (C, K, bins)
        car = torch.as_tensor(carrier(radar, ranges, amps)).to(torch.complex64)
        prof[f] = torch.einsum("ck,ckb->cb", car, h)
    prof = prof[:, :, None, :].expand(n_frames, radar.chirps_per_frame, radar.n_rx, len(bins)).clone()
    noise_shape = (n_frames, radar.chirps_per_frame, radar.n_rx, n)
    if effects.noise.enabled:  # the same draw as the ADC path, through the same windowed FFT
        prof += _bin_fft(torch.as_tensor(receiver_noise(rng_noise, noise_shape, sigma)), chain, bins)
    if iq.enabled:
        mu, nu_c = iq_coefficients(iq)
        g = len(gated)
        image = prof[..., g:] if mirror else prof
        prof = mu * prof[..., :g] + nu_c * image.conj()
    if effects.noise.enabled and effects.noise.quantisation:
        # int16 rounding of I and Q after the receiver: uniform error of 1/12 count^2 each
        prof += _bin_fft(torch.as_tensor(receiver_noise(rng_quant, noise_shape, math.sqrt(2 / 12))), chain, gated)
    # (frames, chirps, rx, bins) -> (frames, loops, channels, bins), as range_profiles_from_adc
    return prof.reshape(n_frames, radar.n_loops, radar.chirps_per_loop * radar.n_rx, len(gated)).to(torch.complex64)


def _bin_fft(x: torch.Tensor, chain: ChainConfig, bins: np.ndarray) -> torch.Tensor:
    """Windowed fast-time FFT of (..., samples) at the given bins (the chain's range FFT)."""

    w = window(chain.range_window, x.shape[-1], dtype=torch.float32)
    return torch.fft.fft(x * w, dim=-1)[..., torch.as_tensor(bins)]
