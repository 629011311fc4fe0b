"""The processing chain against closed forms: point targets, bin responses, frame gaps."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from handradar.radar.chain import (
    ChainConfig,
    capture_spectrogram,
    column_times_s,
    gate_bins,
    measured_spectrogram,
    profile_power,
    range_profiles_from_adc,
    range_response,
    spectrogram_from_profiles,
    stft_power,
    velocity_axis_m_s,
)
from handradar.radar.signal import beat_signal, carrier_phase_rad


def point_target_adc(radar, n_frames: int, r0: float, v_away: float, amplitude: float = 2000.0) -> np.ndarray:
    """ADC of one point target moving with constant radial velocity (positive = receding),
    its range taken at the true chirp times (idle gaps between frames included)."""
    t = radar.chirp_times_s(n_frames)[..., 0]  # (frames, loops)
    ranges = (r0 + v_away * t).reshape(n_frames, radar.chirps_per_frame, 1, 1)
    return beat_signal(radar, ranges, np.full(ranges.shape, amplitude))


def expected_doppler_row(radar, chain, v_away: float) -> int:
    f_d = -2.0 * v_away / radar.wavelength_m  # the echo's Doppler shift: approaching (v_away < 0) positive, above
    return int(round(f_d * chain.stft_len * radar.loop_period_s)) + chain.stft_len // 2


@pytest.mark.parametrize("v_away", [-0.6, -0.25, 0.3, 0.9])
def test_point_target_lands_in_expected_doppler_row_every_column(radar, chain, v_away):
    n_frames = 16
    chain = dataclasses.replace(chain, gate_m=(0.05, 2.5))
    r0 = 1.2 - v_away * 0.8  # stays inside the gate for the whole capture
    adc = point_target_adc(radar, n_frames, r0, v_away)
    spec, start = measured_spectrogram(adc, radar, chain)
    assert spec.shape == (chain.stft_len, chain.n_columns) and start == 0
    rows = spec.argmax(dim=0)
    expected = expected_doppler_row(radar, chain, v_away)
    # every column, including the pairs on both sides of each inter-frame gap (columns 1|2, 3|4, ...)
    assert rows.tolist() == [expected] * chain.n_columns
    # and the measured velocity agrees with the set one within half a bin
    v_bin = velocity_axis_m_s(radar, chain)
    assert abs(v_bin[expected] - (-v_away)) <= 0.5 * (v_bin[1] - v_bin[0]) + 1e-9


def test_approaching_and_receding_are_on_opposite_sides(radar, chain):
    centre = chain.stft_len // 2
    toward, _ = measured_spectrogram(point_target_adc(radar, 16, 0.6, -0.25), radar, chain)
    away, _ = measured_spectrogram(point_target_adc(radar, 16, 0.2, +0.25), radar, chain)
    assert (toward.argmax(0) > centre).all()  # approaching: positive Doppler, rows above the centre
    assert (away.argmax(0) < centre).all()


def test_point_target_lands_in_expected_range_bin(radar, chain):
    b0, b1 = gate_bins(radar, chain)
    for r in (0.15, 0.31, 0.52):
        profiles = range_profiles_from_adc(torch.as_tensor(point_target_adc(radar, 1, r, 0.0)), radar, chain)
        peak = int(profiles.abs().mean(dim=(0, 1, 2)).argmax()) + b0
        assert peak == round(r / radar.range_resolution_m)


def test_gap_phase_continuity_matters(radar, chain):
    """Interpolating motion by chirp index (ignoring the idle gap) gives a different signal: the
    chain must be fed true chirp times. A target whose phase jumps at the gaps still lands in its
    bin because windows never straddle frames."""
    t = radar.chirp_times_s(2)[..., 0]
    gapless = np.arange(t.size).reshape(t.shape) * radar.chirp_period_s
    assert t[1, 0] - t[0, -1] > 100 * radar.chirp_period_s
    assert not np.allclose(t, gapless + t[0, 0])


def test_closed_form_range_response_matches_explicit_fft(radar, chain):
    rng = np.random.default_rng(0)
    ranges = rng.uniform(0.1, 0.6, size=(2, radar.chirps_per_frame, 1, 3))
    amps = rng.uniform(100, 1000, size=ranges.shape)
    adc = beat_signal(radar, ranges, amps)
    fft = range_profiles_from_adc(torch.as_tensor(adc), radar, chain)  # (2, loops, 1, bins)
    b0, b1 = gate_bins(radar, chain)
    nu = torch.as_tensor(radar.beat_frequency_hz(ranges) / radar.sample_rate_hz)
    carrier = torch.as_tensor(amps * np.exp(1j * carrier_phase_rad(radar, ranges)))
    closed = (range_response(nu, torch.arange(b0, b1), radar.n_samples, chain.range_window)
              * carrier[..., None]).sum(dim=-2)  # sum the 3 reflectors
    err = (closed.to(torch.complex64) - fft).abs().max() / fft.abs().max()
    assert err < 1e-5


@pytest.mark.parametrize("window_name", ["rect", "hann", "hamming", "blackman"])
def test_range_response_equals_dtft_of_window(window_name):
    from handradar.radar.chain import window

    n = 64
    w = window(window_name, n, dtype=torch.float64)
    nu = torch.tensor([0.0, 0.013, 0.25, 3.0 / n, -0.4], dtype=torch.float64)
    bins = torch.arange(0, 10)
    k = torch.arange(n, dtype=torch.float64)
    explicit = (w * torch.exp(2j * np.pi * (nu[:, None, None] - bins[None, :, None] / n) * k)).sum(-1)
    closed = range_response(nu, bins, n, window_name)
    torch.testing.assert_close(closed, explicit, atol=1e-9, rtol=1e-9)


def test_range_response_is_differentiable():
    nu = torch.tensor([0.0101, 0.3], dtype=torch.float64, requires_grad=True)
    bins = torch.arange(0, 6)
    torch.autograd.gradcheck(lambda x: torch.view_as_real(range_response(x, bins, 32, "hann")), (nu,))


def _range_response_reference(nu, bins, n, window_name):
    """The term-by-term form range_response had before the factorisation (one Dirichlet kernel per
    window term and bin), kept as the reference of the fast form."""
    from handradar.radar.chain import COSINE_WINDOWS, dirichlet

    nu = nu.unsqueeze(-1) - bins.to(nu.dtype) / n
    out = 0
    for m, a in enumerate(COSINE_WINDOWS[window_name]):
        if m == 0:
            out = out + a * dirichlet(nu, n)
        else:
            out = out + ((-1) ** m) * a / 2 * (dirichlet(nu + m / n, n) + dirichlet(nu - m / n, n))
    return out


@pytest.mark.parametrize("window_name", ["rect", "hann", "hamming", "blackman"])
def test_factored_range_response_equals_the_term_by_term_form(window_name):
    n = 256
    gen = torch.Generator().manual_seed(0)
    nu = torch.rand(4000, generator=gen, dtype=torch.float64) * 1.6 - 0.3  # aliased and negative beats too
    poles = torch.arange(-3, 14, dtype=torch.float64) / n  # the bins' and side lobes' poles (and aliases)
    nu[:17], nu[17:34] = poles, poles + 1.0  # exactly on a pole
    nu[34:51] = poles + 1e-8 * torch.randn(17, generator=gen, dtype=torch.float64)  # the pole limit
    nu[51:68] = poles + 4e-7 * torch.randn(17, generator=gen, dtype=torch.float64)  # just outside it
    nu = nu.reshape(2, 50, 40)
    bins = torch.arange(2, 10)
    ref = _range_response_reference(nu, bins, n, window_name)
    fast = range_response(nu, bins, n, window_name)
    assert fast.shape == ref.shape == (2, 50, 40, 8) and fast.dtype == torch.complex128
    scale = ref.abs().max()
    assert float((fast - ref).abs().max() / scale) < 1e-10
    # float32 beats: complex64 out, float32 round-off of the old float32 evaluation
    ref32 = _range_response_reference(nu.float(), bins, n, window_name)
    fast32 = range_response(nu.float(), bins, n, window_name)
    assert fast32.dtype == torch.complex64
    assert float((fast32 - ref32).abs().max() / scale) < 2e-6
    # a carrier multiplies each tone (poles included)
    carrier = torch.polar(torch.rand(nu.shape, generator=gen, dtype=torch.float64),
                          torch.rand(nu.shape, generator=gen, dtype=torch.float64) * 100.0)
    torch.testing.assert_close(range_response(nu, bins, n, window_name, carrier), ref * carrier[..., None],
                               atol=1e-10 * float(scale), rtol=0)
    # bins that are not integers go through the term-by-term form
    frac_bins = torch.tensor([2.5, 3.0])
    torch.testing.assert_close(range_response(nu, frac_bins, n, window_name),
                               _range_response_reference(nu, frac_bins, n, window_name), atol=0, rtol=0)


@pytest.mark.parametrize("window_name", ["hann", "blackman"])
@pytest.mark.parametrize("sum_dim", [0, 1, -1])
def test_summed_range_response_is_the_sum_of_the_term_by_term_responses(window_name, sum_dim):
    """sum_dim: the tones' responses summed over that axis, poles among them, against the term-by-term reference
    of each tone summed afterwards (float64, float32, a carrier, autograd)."""
    n = 128
    gen = torch.Generator().manual_seed(2)
    nu = torch.rand(3, 7, 50, generator=gen, dtype=torch.float64) * 0.4
    nu[0, 2, :6] = torch.arange(6, dtype=torch.float64) / n  # on the poles of bins and side lobes
    nu[1, :, 3] = 4.0 / n + 1e-8 * torch.randn(7, generator=gen, dtype=torch.float64)  # within the pole limit
    carrier = torch.polar(torch.rand(nu.shape, generator=gen, dtype=torch.float64),
                          torch.rand(nu.shape, generator=gen, dtype=torch.float64) * 100.0)
    bins = torch.arange(1, 6)
    ref = (_range_response_reference(nu, bins, n, window_name) * carrier[..., None]).sum(sum_dim % 3)
    summed = range_response(nu, bins, n, window_name, carrier, sum_dim=sum_dim)
    assert summed.shape == ref.shape and summed.dtype == torch.complex128
    scale = float(ref.abs().max())
    torch.testing.assert_close(summed, ref, atol=1e-10 * scale, rtol=0)
    summed32 = range_response(nu.float(), bins, n, window_name, carrier.to(torch.complex64), sum_dim=sum_dim)
    assert summed32.dtype == torch.complex64
    assert float((summed32 - ref).abs().max()) < 2e-5 * scale
    none = range_response(nu[:, :0], bins, n, window_name, carrier[:, :0], sum_dim=1)  # no tones: zeros
    assert none.shape == (3, 50, 5) and float(none.abs().max()) == 0.0
    x = nu[2, :3, 10:14].clone().requires_grad_(True)  # away from the poles, where the form takes the limit
    torch.autograd.gradcheck(
        lambda v: torch.view_as_real(range_response(v, bins, n, window_name, sum_dim=sum_dim % 2)), (x,))


def test_range_response_chunks_change_nothing(monkeypatch):
    import handradar.radar.chain as chain_module

    gen = torch.Generator().manual_seed(1)
    nu = torch.rand(3, 1000, generator=gen, dtype=torch.float64)
    nu[0, :5] = torch.arange(5) / 64.0  # poles in the first chunk
    carrier = torch.polar(torch.ones_like(nu), nu * 50.0)
    bins = torch.arange(1, 7)
    whole = range_response(nu, bins, 64, "hann", carrier)
    monkeypatch.setattr(chain_module, "_RESPONSE_CHUNK", 333)
    # the same sums (BLAS may block a shorter matmul differently: round-off only)
    torch.testing.assert_close(range_response(nu, bins, 64, "hann", carrier), whole,
                               atol=1e-13 * float(whole.abs().max()), rtol=0)
    x = nu[:, 10:50].clone().requires_grad_(True)  # the differentiable path concatenates its chunks
    monkeypatch.setattr(chain_module, "_RESPONSE_CHUNK", 7)
    torch.autograd.gradcheck(lambda v: torch.view_as_real(range_response(v, bins, 64, "hann")), (x,))


def test_range_response_gradient_near_a_pole():
    nu = torch.tensor([3.0 / 32 + 1e-4, 0.2, 5.0 / 32 - 2e-3], dtype=torch.float64, requires_grad=True)
    bins = torch.arange(0, 8)
    torch.autograd.gradcheck(lambda x: torch.view_as_real(range_response(x, bins, 32, "blackman")), (nu,))


def test_static_clutter_is_removed(radar, chain):
    static = point_target_adc(radar, 16, 0.30, 0.0, amplitude=20000.0)
    moving = point_target_adc(radar, 16, 0.50, -0.3, amplitude=200.0)
    spec, _ = measured_spectrogram(static + moving, radar, chain)
    assert (spec.argmax(0) == expected_doppler_row(radar, chain, -0.3)).all()


def test_frame_clutter_removal_takes_each_frames_own_mean():
    """clutter_removal "frame" (the TI mmWave SDK's static clutter removal): a reflector still within each frame but
    stepped between frames (a hand that moved, then held) leaves nothing, where the window's mean leaves it; a tone
    at a whole Doppler bin (zero mean over the frame's loops) is untouched; a slow drift (0.3 bin) is the windowed
    DTFT of each frame less its mean (a direct sum), notched at zero Doppler, its peak without clutter removal."""
    loops, frames = 32, 4
    chain = ChainConfig(stft_len=loops, stft_hop=loops, n_columns=frames, clutter_removal="frame")
    kept, window_mean = (dataclasses.replace(chain, clutter_removal=c) for c in ("none", "window"))
    rng = np.random.default_rng(0)
    steps = rng.normal(size=(frames, 1, 1, 1)) + 1j * rng.normal(size=(frames, 1, 1, 1))
    held = torch.as_tensor(np.broadcast_to(steps, (frames, loops, 1, 1)).copy())
    assert float(profile_power(held, chain).max()) < 1e-20 < 1e-3 < float(profile_power(held, window_mean).max())
    n = np.arange(frames * loops).reshape(frames, loops, 1, 1)
    tone = torch.as_tensor(np.exp(2j * np.pi * 3 * n / loops))
    np.testing.assert_allclose(profile_power(tone, chain).numpy(), profile_power(tone, kept).numpy(), rtol=1e-9,
                               atol=1e-9 * float(profile_power(tone, kept).max()))
    drift = np.exp(2j * np.pi * 0.3 * n / loops)
    removed, whole = (profile_power(torch.as_tensor(drift), c)[:, 0].numpy() for c in (chain, kept))
    x = drift[0, :, 0, 0] - drift[0, :, 0, 0].mean()  # the first frame, by a direct sum of its windowed DTFT
    w = 0.54 - 0.46 * np.cos(2 * np.pi * np.arange(loops) / loops)
    k = np.arange(loops) - loops // 2
    np.testing.assert_allclose(removed, np.abs((w * x * np.exp(2j * np.pi * np.outer(k, np.arange(loops)) / loops))
                                               .sum(axis=1)) ** 2, rtol=1e-9)
    zero = loops // 2
    assert whole.argmax() == zero and removed[zero] < 0.1 * removed.max()  # zero notched, its neighbour kept
    with pytest.raises(ValueError, match="clutter_removal"):
        ChainConfig(clutter_removal="sometimes")


def test_spectrogram_range_and_floor(radar, chain):
    spec, _ = measured_spectrogram(point_target_adc(radar, 16, 0.4, -0.2), radar, chain)
    assert float(spec.min()) == 0.0 and float(spec.max()) == 1.0
    narrow = dataclasses.replace(chain, dynamic_range_db=10.0)
    spec10, _ = measured_spectrogram(point_target_adc(radar, 16, 0.4, -0.2), radar, narrow)
    assert (spec10 == 0).float().mean() > (spec == 0).float().mean()


def test_window_selection_finds_the_motion(radar, chain):
    """A target that moves only during frames 10..25 of a 30-frame capture is windowed there."""
    n_frames = 30
    t = radar.chirp_times_s(n_frames)[..., 0]
    tt = np.clip(t, 1.0, 2.6)
    ranges = (0.5 - 0.4 * (tt - 1.0) / 1.6).reshape(n_frames, -1, 1, 1)
    adc = beat_signal(radar, ranges, np.full(ranges.shape, 1000.0))
    spec, start = measured_spectrogram(adc, radar, chain)
    assert start == 10
    # a window given instead of chosen: the same one gives the same spectrogram, another its own frames
    profiles = range_profiles_from_adc(torch.as_tensor(adc), radar, chain)
    same, _ = capture_spectrogram(profiles, radar, chain, start=10)
    torch.testing.assert_close(same, spec)
    fpw = chain.frames_per_window(radar)
    early, start = capture_spectrogram(profiles, radar, chain, start=0)
    assert start == 0
    torch.testing.assert_close(early, spectrogram_from_profiles(profiles[..., :fpw, :, :, :], chain))
    with pytest.raises(ValueError, match="window start frame 29 outside"):
        capture_spectrogram(profiles, radar, chain, start=29)


def test_column_times_follow_frames(radar, chain):
    times = column_times_s(radar, chain, n_frames=3)
    assert times.shape == (6,)
    # two columns per frame, 64 loops apart; the next frame starts one period later
    np.testing.assert_allclose(times[1] - times[0], 64 * radar.loop_period_s)
    np.testing.assert_allclose(times[2] - times[0], radar.frame_period_s)


def test_sim_and_measured_enter_the_same_chain(radar, chain):
    """Closed-form profiles through spectrogram_from_profiles equal the ADC path's spectrogram."""
    adc = point_target_adc(radar, 16, 0.45, -0.35)
    measured, _ = measured_spectrogram(adc, radar, chain)
    t = radar.chirp_times_s(16)[..., 0]
    r = torch.as_tensor(0.45 - 0.35 * t)
    b0, b1 = gate_bins(radar, chain)
    nu = torch.as_tensor(radar.beat_frequency_hz(r.numpy()) / radar.sample_rate_hz)
    prof = range_response(nu, torch.arange(b0, b1), radar.n_samples, chain.range_window)
    prof = (prof * 2000.0 * torch.exp(1j * carrier_phase_rad(radar, r))[..., None])[:, :, None, :]
    simulated = spectrogram_from_profiles(prof.to(torch.complex64), chain)
    assert (simulated - measured).abs().max() < 1e-3


def test_chain_config_rejects_bad_settings():
    with pytest.raises(ValueError, match="unknown window"):
        ChainConfig(range_window="kaiser-ish")
    with pytest.raises(ValueError, match="gate_m"):
        ChainConfig(gate_m=(0.5, 0.2))


@pytest.mark.parametrize("n_chirps", [16, 32, 64])
def test_zero_padded_doppler_is_the_windowed_dtft_at_the_bins(n_chirps):
    """doppler_bins > stft_len: each row is the windowed slow-time signal's DTFT at (k - D/2) / D cycles a loop,
    summed directly here (no FFT), for a tone between bins and a random signal; the rows are D whatever N is."""
    d = 64
    chain = ChainConfig(stft_len=n_chirps, stft_hop=n_chirps, doppler_bins=d, n_columns=1, stft_window="hamming")
    n = np.arange(n_chirps)
    rng = np.random.default_rng(0)
    tone = np.exp(2j * np.pi * 0.1371 * n)
    noise = rng.normal(size=n_chirps) + 1j * rng.normal(size=n_chirps)
    w = 0.54 - 0.46 * np.cos(2 * np.pi * n / n_chirps)  # periodic Hamming
    for x in (tone, noise):
        profiles = torch.as_tensor(x.reshape(1, n_chirps, 1, 1), dtype=torch.complex128)
        power = stft_power(profiles, chain)[:, 0].numpy()
        k = np.arange(d) - d // 2
        dtft = (w * x * np.exp(2j * np.pi * np.outer(k, n) / d)).sum(axis=1)
        assert power.shape == (d,)
        np.testing.assert_allclose(power, np.abs(dtft) ** 2, rtol=1e-9, atol=1e-9 * np.abs(dtft).max() ** 2)
    with pytest.raises(ValueError, match="fewer than the STFT length"):
        ChainConfig(stft_len=64, doppler_bins=32)


def test_fewer_chirps_widen_the_zero_doppler_line_as_the_window_says():
    """A still target with 32 Hamming-windowed chirps zero-padded to 64 bins: neighbours at -1.8 and -7.4 dB
    (|0.54 + 0.23 (e^{j pi k/2} ...)|^2 of the window's DTFT at half-bin steps), against -7.4 dB and nothing with 64."""
    def line(n_chirps):
        chain = ChainConfig(stft_len=n_chirps, stft_hop=n_chirps, doppler_bins=64, n_columns=1)
        p = stft_power(torch.ones(1, n_chirps, 1, 1, dtype=torch.complex128), chain)[:, 0].numpy()
        return 10 * np.log10(p[30:35] / p.max() + 1e-30)

    w32 = 0.54 - 0.46 * np.cos(2 * np.pi * np.arange(32) / 32)
    half_bin = 10 * np.log10(abs((w32 * np.exp(1j * np.pi * np.arange(32) / 32)).sum()) ** 2 / w32.sum() ** 2)
    np.testing.assert_allclose(line(32)[[1, 3]], half_bin, atol=1e-6)
    assert half_bin == pytest.approx(-1.8, abs=0.1)
    assert line(32)[0] == pytest.approx(10 * np.log10((0.23 / 0.54) ** 2), abs=1e-6)  # a whole bin: -7.4 dB
    assert line(64)[1] == pytest.approx(10 * np.log10((0.23 / 0.54) ** 2), abs=1e-6) and line(64)[0] < -200


def test_unset_later_fields_keep_earlier_cache_keys():
    """doppler_bins and the processing steps came after caches keyed by the chain: unset, the chain hashes as before
    they existed; set, it does not."""
    from handradar.provenance import config_hash

    later = {k for k, f in ChainConfig.__dataclass_fields__.items() if f.metadata.get("hash_if_set")}
    assert {"doppler_bins", "doppler_keep", "mti_lag", "range_mode", "scale", "normalise", "cfar"} <= later
    before = {k: getattr(ChainConfig(), k) for k in ChainConfig.__dataclass_fields__ if k not in later}
    assert config_hash(ChainConfig()) == config_hash(before)
    for change in ({"doppler_bins": 128}, {"scale": "linear"}, {"cfar": (2, 4, 10.0)}):
        assert config_hash(ChainConfig(**change)) != config_hash(ChainConfig())
