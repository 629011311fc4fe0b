"""The IF sign convention from first principles: the transmitted chirp mixed literally with its echo.

Sources of the convention:
- Tang et al., "Advancing Radar Hand Gesture Recognition: A Hybrid Spectrum Synthetic Framework
  Merging Simulation with Neural Networks", Section III: S_TX(t) = exp(j 2 pi (f0 t + S t^2 / 2)) and
  S_RX(t) = S_TX(t - tau); the mixer's IF is S_TX conj(S_RX), phase 2 pi (f0 tau + S tau t - S tau^2 / 2).
- TI, C. Iovescu and S. Rao, "The fundamentals of millimeter wave radar sensors" (SPYY005): the IF of
  an object at distance d has frequency S 2d / c and initial phase 4 pi d / lambda, the same sign.
- RadarSimPy's "Sign Conventions" page: a negative Doppler frequency is a target moving towards the
  radar (f_d = 2 v_r / lambda, v_r negative when closing).

The IF below is numpy alone: both chirps' phases evaluated at every ADC sample time, the delay of a
target that moves during the chirp too; no handradar signal code builds it. The project's ADC
writer, the reference world's writer, the simulator's range profiles and the ingest path are then
held against it, with the raw numbers of the .cfg (f0, slope, adcStart, sample rate, idle, rampEnd).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from handradar.data.convention import range_mirror_db
from handradar.radar.chain import gate_bins, measured_spectrogram, range_profiles_from_adc
from handradar.radar.dca1000 import encode_adc, read_adc
from handradar.radar.signal import beat_signal, doppler_mirror
from handradar.sim.profiles import scatterer_profiles, window_chirp_times
from handradar.sim.scatterers import Scatterers
from handradar.world.render import synthesize_beat

C = 299_792_458.0


def ramp_starts(radar, n_frames: int) -> np.ndarray:
    """(frames, chirps_per_frame) start time of every ramp, from the .cfg's numbers alone."""
    chirp = radar.idle_time_s + radar.ramp_end_time_s
    k = np.arange(radar.n_loops * radar.chirps_per_loop)
    return np.arange(n_frames)[:, None] * radar.frame_period_s + k[None, :] * chirp


def literal_if(radar, n_frames: int, r0: float, v_away: float, amplitude: float = 2000.0,
               swap_iq: bool = False, mirror_doppler: bool = False) -> np.ndarray:
    """(frames, chirps, 1, samples) IF of a point target at r0 + v_away t (t from the capture start),
    S_TX(t') conj(S_TX(t' - tau)) at t' = adcStart + n / fs after each ramp start. ``mirror_doppler``:
    the carrier phase 2 pi tau (f0 + S adcStart) of the wrong sign, the fast-time tone kept."""
    def tx_cycles(t):
        return radar.start_freq_hz * t + 0.5 * radar.slope_hz_per_s * t ** 2

    tp = radar.adc_start_time_s + np.arange(radar.n_samples) / radar.sample_rate_hz
    t_abs = ramp_starts(radar, n_frames)[..., None] + tp
    tau = 2 * (r0 + v_away * t_abs) / C
    sig = amplitude * np.exp(2j * np.pi * (tx_cycles(tp) - tx_cycles(tp - tau)))
    if mirror_doppler:
        sig = sig * np.exp(-4j * np.pi * tau * (radar.start_freq_hz + radar.slope_hz_per_s * radar.adc_start_time_s))
    if swap_iq:
        sig = sig.imag + 1j * sig.real
    return sig[:, :, None, :].astype(np.complex64)


def centre_wavelength(radar) -> float:
    """Wavelength at the centre of the sampled sweep: the slow-time phase slope after the range FFT."""
    f = radar.start_freq_hz + radar.slope_hz_per_s * (radar.adc_start_time_s + radar.n_samples / radar.sample_rate_hz / 2)
    return C / f


def sampling_centres(radar, n_frames: int) -> np.ndarray:
    return ramp_starts(radar, n_frames) + radar.adc_start_time_s + radar.n_samples / radar.sample_rate_hz / 2


def profiles_of(adc: np.ndarray, radar, chain) -> torch.Tensor:
    return range_profiles_from_adc(torch.as_tensor(adc), radar, chain)


def rel_err(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().max() / b.abs().max())


@pytest.mark.parametrize("v_away", [-0.3, 0.25])
def test_project_adc_writer_is_the_literal_mix(radar, chain, v_away):
    """handradar.radar.signal.beat_signal: the same range profiles as the literal IF, phase included
    (the writer holds each chirp's range at its sampling centre: 1 % at 0.3 m/s). The carrier phase
    with the opposite sign would differ by the whole signal (relative error ~2)."""
    lit = literal_if(radar, 2, 0.4, v_away)
    r = (0.4 + v_away * sampling_centres(radar, 2))[..., None, None]
    ours = beat_signal(radar, r, np.full(r.shape, 2000.0))
    assert rel_err(profiles_of(ours, radar, chain), profiles_of(lit, radar, chain)) < 0.02
    assert rel_err(profiles_of(ours.conj(), radar, chain).conj(), profiles_of(lit, radar, chain)) > 1.0


def test_world_writer_is_the_literal_mix(radar, chain):
    """handradar.world.render.synthesize_beat (the reference world's ADC path) against the literal IF."""
    lit = literal_if(radar, 1, 0.35, -0.3)
    r = (0.35 - 0.3 * sampling_centres(radar, 1))[0][:, None]  # (chirps, 1 reflector)
    ours = synthesize_beat(radar, r, np.full(r.shape, 2000.0))[None, :, None, :]
    assert rel_err(profiles_of(ours, radar, chain), profiles_of(lit, radar, chain)) < 0.02


def test_simulator_profiles_are_the_literal_mix(radar, chain):
    """The simulator's closed-form per-range-bin signal of one point: the literal IF's range FFT up to
    a real amplitude (the radar equation sets the simulator's scale, not the sign or the phase)."""
    short = dataclasses.replace(chain, n_columns=2)  # one frame
    times = np.linspace(-0.01, 0.11, 121)
    z = 0.35 - 0.3 * times
    pos = torch.as_tensor(np.stack([0 * times, 0 * times, z], -1)[None, :, None])
    gain = torch.as_tensor(z ** 2)[None, :, None]  # cancels the radar equation's 1 / R^2: a constant amplitude
    scat = Scatterers(pos, pos, torch.full((1, len(times), 1), 1e-3, dtype=torch.float64), gain, torch.tensor([0]))
    prof = scatterer_profiles(scat, torch.as_tensor(times), window_chirp_times(radar, short), radar, short,
                              tx_power_w=1.0, gain_tx_dbi=0.0, gain_rx_dbi=0.0)[0, 0]  # (F, L, C*rx, bins)
    lit = profiles_of(literal_if(radar, 1, 0.35, -0.3), radar, short).to(torch.complex128)
    scale = float((prof.conj() * lit).sum().real / (prof.abs() ** 2).sum())
    assert scale > 0 and rel_err(prof * scale, lit) < 0.02


@pytest.mark.parametrize("v_away", [-0.6, -0.25, 0.3, 0.9])
def test_ingest_puts_the_target_where_physics_says(radar, chain, v_away, tmp_path):
    """Through adc_data.bin and the ingest path: the range bin of 2 S R / c, and the Doppler row of
    the echo's shift 2 v / lambda, approaching above the centre row (the display order), receding below."""
    n_frames = 16
    chain = dataclasses.replace(chain, gate_m=(0.05, 2.5))
    r0 = 1.2 - v_away * 0.8
    (tmp_path / "adc.bin").write_bytes(encode_adc(literal_if(radar, n_frames, r0, v_away), radar))
    adc = read_adc(tmp_path / "adc.bin", dataclasses.replace(radar, n_frames=n_frames))
    spec, _ = measured_spectrogram(adc, radar, chain)
    shift_hz = 2 * (-v_away) / centre_wavelength(radar)
    row = chain.stft_len // 2 + round(shift_hz * chain.stft_len * (radar.idle_time_s + radar.ramp_end_time_s))
    assert spec.argmax(0).tolist() == [row] * chain.n_columns
    assert (row > chain.stft_len // 2) == (v_away < 0)
    b0, _ = gate_bins(radar, chain)
    prof = profiles_of(adc[:1], radar, chain).abs().mean(dim=(0, 1, 2))
    r_mid = r0 + v_away * radar.n_loops * (radar.idle_time_s + radar.ramp_end_time_s) / 2  # frame 0's middle
    beat_bins = 2 * radar.slope_hz_per_s * r_mid / C / radar.sample_rate_hz * radar.n_samples
    assert abs(int(prof.argmax()) + b0 - beat_bins) < 0.6


def test_swapped_iq_puts_the_target_at_negative_range_bins_and_ingest_reads_it_back(radar, chain, tmp_path):
    """I and Q exchanged (x -> j conj(x)): the target moves to bin N - b and its Doppler mirrors; the
    range check names it, and reading with iq_swap restores the unswapped capture."""
    good, swapped = literal_if(radar, 4, 0.4, -0.3), literal_if(radar, 4, 0.4, -0.3, swap_iq=True)
    cfg = dataclasses.replace(radar, n_frames=4)
    (tmp_path / "a.bin").write_bytes(encode_adc(swapped, radar))
    as_written = read_adc(tmp_path / "a.bin", cfg)
    power = (np.abs(np.fft.fft(as_written[0], axis=-1)) ** 2).sum(axis=(0, 1))
    b = round(2 * radar.slope_hz_per_s * 0.4 / C / radar.sample_rate_hz * radar.n_samples)
    assert abs(int(power.argmax()) - (radar.n_samples - b)) <= 1
    assert range_mirror_db(as_written, radar, np.array([0.4])) > 20
    assert range_mirror_db(read_adc(tmp_path / "a.bin", cfg, iq_swap=True), radar, np.array([0.4])) < -20
    np.testing.assert_allclose(read_adc(tmp_path / "a.bin", cfg, iq_swap=True), np.rint(good.real) + 1j * np.rint(good.imag))


def test_doppler_flip_rights_a_mirrored_carrier_but_leaves_a_swapped_target_at_mirrored_bins(radar, chain):
    """doppler_flip (handradar.radar.signal.doppler_mirror, each bin's windowed spectrum conjugated): on a
    capture whose carrier phase has the wrong sign it gives back the literal IF's range profiles in
    magnitude and in their chirp-to-chirp phase steps (the Doppler; the window's slowly moving linear
    phase at a fractional beat bin is conjugated too). On an I/Q-swapped capture (j conj(x)) it rights
    the slow-time phase but the target stays at bin N - b (there, -j times the right profile): the
    Doppler of the leakage at bin b passes the check while the range figure still names the swap; only
    iq_swap puts the target back at bin b."""
    good = literal_if(radar, 2, 0.4, -0.3)
    righted = profiles_of(doppler_mirror(literal_if(radar, 2, 0.4, -0.3, mirror_doppler=True)), radar, chain)
    want = profiles_of(good, radar, chain)
    assert rel_err(righted.abs(), want.abs()) < 0.02
    steps = [p[:, 1:] * p[:, :-1].conj() for p in (righted, want)]  # chirp to chirp, per range bin
    assert rel_err(*steps) < 0.02
    assert rel_err(steps[0], steps[1].conj()) > 0.5  # the wrong sign would show: the Doppler is the step's phase
    flipped = doppler_mirror(literal_if(radar, 2, 0.4, -0.3, swap_iq=True))
    hann = torch.hann_window(radar.n_samples, periodic=True, dtype=torch.float64).numpy()
    spec_good, spec_flipped = (np.fft.fft(x * hann, axis=-1) for x in (good, flipped))
    b = round(2 * radar.slope_hz_per_s * 0.4 / C / radar.sample_rate_hz * radar.n_samples)
    bins = np.arange(b - 2, b + 3)
    mirrored = spec_flipped[..., radar.n_samples - bins]
    assert rel_err(torch.as_tensor(mirrored), torch.as_tensor(-1j * spec_good[..., bins])) < 0.02
    assert range_mirror_db(flipped, radar, np.array([0.4])) > 20 and range_mirror_db(good, radar, np.array([0.4])) < -20
