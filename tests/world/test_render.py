"""Signal paths: the matrix-product beat synthesis, receiver noise at the set SNR, I/Q imbalance,
and the fast path against the ADC path."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from handradar.radar.chain import capture_spectrogram, range_profiles_from_adc
from handradar.radar.dca1000 import quantise
from handradar.radar.signal import beat_signal
from handradar.world.config import Effects, IQImbalance
from handradar.world.generate import RecordingSpec, simulate, simulate_adc
from handradar.world.render import (
    adc_cube,
    fast_profiles,
    iq_coefficients,
    synthesize_beat,
)
from handradar.world.tracks import DIRECT, ScatterTracks
from tests.world.conftest import range_doppler, with_effects


def test_beat_synthesis_matches_the_reference_model(radar):
    rng = np.random.default_rng(3)
    ranges = rng.uniform(0.1, 0.7, size=(5, 40))
    amps = rng.normal(0, 100, size=(5, 40))
    ours = synthesize_beat(radar, ranges, amps)
    ref = beat_signal(radar, ranges[None, :, None, :], amps[None, :, None, :])[0, :, 0]
    assert np.abs(ours - ref).max() < 1e-4 * np.abs(ref).max()


def moving_point(radar, n_frames: int, r0: float, v_away: float, amp: float = 300.0) -> ScatterTracks:
    t = np.arange(-0.02, n_frames * radar.frame_period_s + 0.02, 0.01)
    return ScatterTracks(t, (r0 + v_away * t)[:, None], np.full((len(t), 1), amp), np.array([DIRECT]),
                         np.array(["0:point"]))


@pytest.mark.parametrize("stage", ["slow_time", "adc"])
def test_iq_imbalance_creates_the_image_at_the_mirrored_doppler(radar, chain, stage):
    """A target approaching at 0.6 m/s; the image has the image-rejection ratio |nu/mu|^2 of the
    set gain/phase imbalance, at the mirrored Doppler (slow_time: same range bin; adc: mirrored range)."""
    n_frames = 2
    iq = IQImbalance(enabled=True, gain_db=2.0, phase_deg=12.0, stage=stage)
    fx = Effects().only().with_("iq_imbalance", **dataclasses.asdict(iq))
    cap = dataclasses.replace(radar, n_frames=n_frames)
    adc = adc_cube(moving_point(radar, n_frames, 0.35, -0.6), cap, n_frames, fx, np.random.default_rng(0), 0.0)
    wide = dataclasses.replace(chain, gate_m=(0.0, radar.max_range_m * 0.999))  # every range bin
    power = range_doppler(range_profiles_from_adc(torch.as_tensor(adc), cap, wide), wide, False).sum(-1)
    b, d = np.unravel_index(power.argmax(), power.shape)
    half = chain.stft_len // 2
    assert d > half  # approaching: positive Doppler
    image_bin = b if stage == "slow_time" else radar.n_samples - b
    image = power[image_bin, 2 * half - d]
    # image rejection of gain g and phase error phi in closed form: |1 - g e^{j phi}|^2 / |1 + g e^{j phi}|^2
    g, phi = 10 ** (2.0 / 20), np.radians(12.0)
    irr_db = 10 * np.log10((1 + g**2 - 2 * g * np.cos(phi)) / (1 + g**2 + 2 * g * np.cos(phi)))  # -16.2 dB
    assert 10 * np.log10(image / power[b, d]) == pytest.approx(irr_db, abs=0.3)
    mu, nu = iq_coefficients(iq)  # the coefficients the world applies give the same ratio
    assert 20 * np.log10(abs(nu / mu)) == pytest.approx(irr_db, abs=1e-9)
    if stage == "adc":  # nothing at the mirrored Doppler of the target's own bin
        assert power[b, 2 * half - d] < 1e-4 * power[b, d]


def test_noise_sets_the_floor_at_the_set_snr(world, radar):
    """Receiver noise: mean power of the hand's signal per ADC sample over the noise power (after
    int16 rounding of both captures) equals the configured SNR within 1 dB."""
    spec = RecordingSpec("finger_wave", 0, 0.0, 0)
    world = dataclasses.replace(world, capture_frames=4)
    for snr in (-5.0, 10.0):
        w_on = with_effects(world, "palm", "occlusion", "noise", noise={"snr_db": snr})
        w_off = with_effects(world, "palm", "occlusion")
        on = quantise(simulate_adc(simulate(w_on, radar, spec), w_on))[0].astype(float)
        off = quantise(simulate_adc(simulate(w_off, radar, spec), w_off))[0].astype(float)
        signal = (off ** 2).sum(0).mean()
        noise = ((on - off) ** 2).sum(0).mean()
        assert 10 * np.log10(signal / noise) == pytest.approx(snr, abs=1.0)


def test_fast_path_is_the_adc_path_in_the_range_bin_domain(world, radar, chain):
    """Same tracks, same noise draw: the fast path's per-range-bin signal equals the windowed FFT
    of the (unrounded) ADC cube up to the tabulation error; rounding adds its 1/12 count^2."""
    spec = RecordingSpec("double_hand_clap", 1, 0.0, 0)
    w = dataclasses.replace(world, capture_frames=16, effects=world.effects.with_("noise", quantisation=False))
    sim = simulate(w, radar, spec)
    adc = simulate_adc(sim, w)
    sim2 = simulate(w, radar, spec)
    fast = fast_profiles(sim2.tracks, sim2.radar, chain, sim2.radar.n_frames, w.effects, sim2.rng_noise,
                         sim2.rng_quant, sim2.noise_sigma)
    ref = range_profiles_from_adc(torch.as_tensor(adc), sim.radar, chain)
    err = (fast - ref).abs().pow(2).mean() / ref.abs().pow(2).mean()
    assert float(err) < 1e-5
    s_fast, start_fast = capture_spectrogram(fast, sim.radar, chain)
    s_ref, start_ref = capture_spectrogram(ref, sim.radar, chain)
    assert start_fast == start_ref
    assert float((s_fast - s_ref).abs().max()) < 0.01


@pytest.mark.parametrize("stage", ["slow_time", "adc"])
def test_fast_path_models_iq_imbalance_like_the_adc_path(world, radar, chain, stage):
    w = dataclasses.replace(world, capture_frames=3)
    w = dataclasses.replace(w, effects=w.effects.with_("iq_imbalance", enabled=True, stage=stage)
                            .with_("noise", quantisation=False))
    spec = RecordingSpec("grasp", 0, 0.0, 0)
    sim = simulate(w, radar, spec)
    ref = range_profiles_from_adc(torch.as_tensor(simulate_adc(sim, w)), sim.radar, chain)
    sim = simulate(w, radar, spec)
    fast = fast_profiles(sim.tracks, sim.radar, chain, 3, w.effects, sim.rng_noise, sim.rng_quant, sim.noise_sigma)
    assert float((fast - ref).abs().pow(2).mean() / ref.abs().pow(2).mean()) < 1e-5
