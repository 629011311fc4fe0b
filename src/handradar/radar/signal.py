"""Raw IF (beat) signal of point reflectors: the ADC-level model behind the chain's sign convention.

The mixer multiplies the transmitted chirp by the conjugate of its echo, ``S_TX(t) conj(S_RX(t))``
with ``S_RX(t) = S_TX(t - tau)``, tau = 2 R / c (Tang et al., Section III; TI's "Introduction to
mmWave sensing: FMCW radars"). Its phase ``2 pi (f0 tau + S tau t - S tau^2 / 2)`` puts the delay in
the fast-time tone and in the carrier phase with the same sign:

    s[n] = sum_k A_k exp(+j 2 pi f_b,k n / fs) exp(+j 4 pi R_k / lambda_0),   f_b,k = 2 S R_k / c

lambda_0 = c / (f0 + S t_adc) the wavelength at the first ADC sample (n counts from there), R_k at
each chirp's sampling centre (motion within one chirp is neglected: at 2 m/s a hand moves 50 um in a
25.6 us sampling window), S tau^2 / 2 dropped (1e-3 cycles at 1 m). A reflector moving away advances
the phase; docs/architecture.md, "Sign convention", says how the chain orders the Doppler rows.
Used to write raw captures (tests, the reference world); the simulator uses the closed-form range
response of the chain with the same :func:`carrier_phase_rad`.
"""

from __future__ import annotations

import math

import numpy as np

from handradar.radar.config import SPEED_OF_LIGHT_M_S, RadarConfig


def carrier_phase_rad(radar: RadarConfig, range_m):
    """Carrier phase (rad) of a reflector at ``range_m`` (m; numpy array or torch tensor) at the
    first ADC sample: +4 pi R (f0 + S t_adc) / c, the one sign convention of every signal path."""
    return (4.0 * math.pi * (radar.start_freq_hz + radar.slope_hz_per_s * radar.adc_start_time_s)
            / SPEED_OF_LIGHT_M_S) * range_m


def doppler_mirror(adc: np.ndarray) -> np.ndarray:
    """conj(x[-n mod N]) along fast time: each range bin's windowed spectrum conjugated bin by bin (a
    DFT-even window is symmetric under n -> -n), so the range bins stay and the Doppler mirrors."""
    return np.conj(np.roll(adc[..., ::-1], 1, axis=-1))


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
    for f0 in range(0, frames, max(1, chunk // max(1, chirps // 128))):
        f1 = min(frames, f0 + max(1, chunk // max(1, chirps // 128)))
        r = ranges_m[f0:f1]
        fb = radar.beat_frequency_hz(r)  # (f, c, rx, K)
        carrier = amplitudes[f0:f1] * np.exp(1j * carrier_phase_rad(radar, r))
        tone = np.exp(2j * np.pi * fb[..., None, :] * n[:, None])  # (f, c, rx, N, K)
        out[f0:f1] = np.einsum("fcrnk,fcrk->fcrn", tone, carrier).astype(np.complex64)
    return out
