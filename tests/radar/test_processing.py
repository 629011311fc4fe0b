"""The chain's processing steps (the ways published datasets were made) against a direct numpy implementation run on
the same slow-time data: clutter filters, the Doppler window of FFT bins, range handling, magnitude or power,
linear or dB, the normalisations, a cell-averaging CFAR and a fixed threshold; each alone and in combinations."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from handradar.radar.chain import (
    ChainConfig,
    ClutterRemoval,
    cfar_detections,
    doppler_axis_hz,
    profile_power,
    spectrogram_from_profiles,
    stft_power,
    white_noise_power,
)

FRAMES, LOOPS, CHANNELS, BINS = 6, 32, 2, 5


def if_data(seed: int = 0) -> np.ndarray:
    """(frames, loops, channels, bins) slow-time data: a reflector still within each frame, two movers in different bins (one at a
    fractional Doppler bin) and complex noise."""
    rng = np.random.default_rng(seed)
    m = np.arange(FRAMES * LOOPS).reshape(FRAMES, LOOPS, 1, 1)
    x = np.zeros((FRAMES, LOOPS, CHANNELS, BINS), complex)
    x[..., 1] += 30.0 * np.exp(1j * 0.4) * np.linspace(0.3, 1.0, FRAMES)[:, None, None]  # held, then nearer
    x[..., 2] += (4.0 * np.exp(2j * np.pi * 0.157 * m) * np.linspace(0.2, 1.5, FRAMES)[:, None, None, None])[..., 0]
    x[..., 3] += (2.0 * np.exp(-2j * np.pi * 0.31 * m) * np.linspace(1.5, 0.2, FRAMES)[:, None, None, None])[..., 0]
    return x + 0.05 * (rng.normal(size=x.shape) + 1j * rng.normal(size=x.shape))


def reference(x: np.ndarray, c: ChainConfig) -> np.ndarray:
    """The chain's spectrogram (doppler, frames) by plain loops: frame-based Doppler (one window of all loops)."""
    frames, loops, channels, bins = x.shape
    x = x.copy()
    if c.clutter_removal == ClutterRemoval.WINDOW:
        x -= x.mean(axis=(0, 1), keepdims=True)
    elif c.clutter_removal == ClutterRemoval.FRAME:
        x -= x.mean(axis=1, keepdims=True)
    elif c.clutter_removal == ClutterRemoval.MTI:
        lag = c.mti_lag or 1
        y = np.zeros_like(x)
        for m in range(lag, loops):
            y[:, m] = x[:, m] - x[:, m - lag]
        x = y
    n_fft = c.doppler_bins or loops
    w = 0.54 - 0.46 * np.cos(2 * np.pi * np.arange(loops) / loops)  # periodic Hamming
    rows = np.arange(n_fft) - n_fft // 2  # the echo's Doppler shift, the exp(+j) kernel
    if c.doppler_keep:
        rows = rows[n_fft // 2 - c.doppler_keep // 2: n_fft // 2 - c.doppler_keep // 2 + c.doppler_keep]
    kernel = np.exp(2j * np.pi * np.outer(rows, np.arange(loops)) / n_fft)  # (doppler, loops)
    power = np.zeros((len(rows), frames))
    for f in range(frames):
        cells = np.zeros((len(rows), bins))
        for b in range(bins):
            for ch in range(channels):
                cells[:, b] += np.abs(kernel @ (w * x[f, :, ch, b])) ** 2
        power[:, f] = cells[:, cells.sum(axis=0).argmax()] if c.range_mode == "strongest" else cells.sum(axis=1)
    level = np.sqrt(power) if c.quantity == "magnitude" else power
    if c.normalise == "frame":
        ref = level.max(axis=0, keepdims=True)
    elif c.normalise == "none":
        ref = 10.0 ** ((c.reference_db or 0.0) / (20.0 if c.quantity == "magnitude" else 10.0))
    else:
        ref = level.max()
    if c.scale == "linear":
        out = np.clip(level / ref, 0, 1)
    else:
        db = (20.0 if c.quantity == "magnitude" else 10.0) * np.log10(level / ref)
        out = np.clip((db + c.dynamic_range_db) / c.dynamic_range_db, 0, 1)
    if c.cfar is not None:
        guard, train, t_db = c.cfar
        n = power.shape[0]
        for f in range(frames):
            keep = []
            for i in range(n):
                near = [(i + s * k) % n for k in range(guard + 1, guard + train + 1) for s in (1, -1)]
                keep.append(power[i, f] > 10 ** (t_db / 10) * np.mean(power[near, f]))
            out[:, f] = np.where(keep, out[:, f], 0.0)
    if c.threshold is not None:
        out = np.where(out >= c.threshold, out, 0.0)
    return out


BASE = dict(stft_len=LOOPS, stft_hop=LOOPS, n_columns=FRAMES, dynamic_range_db=40.0, clutter_removal="none")
STEPS = {
    "dB power per image (the default)": {},
    "window mean": {"clutter_removal": "window"},
    "frame mean": {"clutter_removal": "frame"},
    "MTI lag 1": {"clutter_removal": "mti"},
    "MTI lag 3": {"clutter_removal": "mti", "mti_lag": 3},
    "central 40 of 64 bins": {"doppler_bins": 64, "doppler_keep": 40},
    "strongest bin": {"range_mode": "strongest"},
    "linear magnitude": {"quantity": "magnitude", "scale": "linear"},
    "linear power": {"scale": "linear"},
    "dB magnitude": {"quantity": "magnitude", "scale": "db"},
    "per frame": {"normalise": "frame"},
    "no normalisation": {"normalise": "none", "reference_db": 50.0},
    "CA-CFAR": {"cfar": (1, 4, 8.0)},
    "fixed threshold": {"threshold": 0.3},
    "frame mean, per frame, linear magnitude, CFAR": {"clutter_removal": "frame", "normalise": "frame",
                                                     "quantity": "magnitude", "scale": "linear", "cfar": (2, 3, 6.0)},
    "MTI, 24 of 32 bins, strongest bin, threshold": {"clutter_removal": "mti", "doppler_keep": 24,
                                                      "range_mode": "strongest", "threshold": 0.5},
}


@pytest.mark.parametrize("step", list(STEPS))
def test_each_step_matches_a_direct_numpy_implementation(step):
    chain = ChainConfig(**{**BASE, **STEPS[step]})
    x = if_data()
    ours = spectrogram_from_profiles(torch.as_tensor(x), chain).numpy()
    ref = reference(x, chain)
    assert ours.shape == ref.shape == (chain.n_doppler, FRAMES)
    np.testing.assert_allclose(ours, ref, atol=1e-7)
    assert 0.0 < float((ours > 0).mean())  # something shows


def test_the_steps_change_the_image():
    """No step is silently ignored: each gives an image other than the default's (a test of the test's reach), but
    the dB of a magnitude, 20 log10 |x|, which is the dB of its power."""
    x = torch.as_tensor(if_data())
    default = spectrogram_from_profiles(x, ChainConfig(**BASE)).numpy()
    for step, change in list(STEPS.items())[1:]:
        image = spectrogram_from_profiles(x, ChainConfig(**{**BASE, **change})).numpy()
        differs = image.shape != default.shape or np.abs(image - default).max() > 1e-3
        assert differs != (step == "dB magnitude"), step


def test_mti_response_is_four_sin_squared():
    """A tone at a whole Doppler bin f through the lag-L canceller: its row's power is 4 sin^2(pi f L) times the
    tone's without it, but for the first L loops (zeroed), i.e. a window of loops L.. instead of 0.."""
    loops, k = 64, 5
    tone = torch.as_tensor(np.exp(2j * np.pi * k / loops * np.arange(loops)).reshape(1, loops, 1, 1))
    w = 0.54 - 0.46 * np.cos(2 * np.pi * np.arange(loops) / loops)
    for lag in (1, 2, 7):
        chain = ChainConfig(stft_len=loops, stft_hop=loops, n_columns=1, clutter_removal="mti", mti_lag=lag)
        row = float(stft_power(tone, chain)[loops // 2 - k, 0])  # exp(+j 2 pi k m / L): a receding echo, below
        kept = abs(w[lag:].sum()) ** 2  # the windowed tone's own bin over the loops the canceller keeps
        assert row == pytest.approx(4 * math.sin(math.pi * k / loops * lag) ** 2 * kept, rel=1e-9)


def test_cfar_keeps_a_peak_in_flat_noise_at_the_rate_the_threshold_sets():
    """Exponential noise power (one complex cell): a cell-averaging CFAR with 2N training cells at factor a passes
    noise with probability (1 + a / (2N))^(-2N) (Richards, Fundamentals of Radar Signal Processing, eq. 6.27);
    a peak 20 dB above the noise always passes."""
    rng = np.random.default_rng(0)
    power = torch.as_tensor(rng.exponential(size=(64, 4000)))
    guard, train, t_db = 2, 8, 10.0
    a = 10 ** (t_db / 10)
    rate = float(cfar_detections(power, guard, train, t_db).double().mean())
    expected = (1 + a / (2 * train)) ** (-2 * train)
    assert rate == pytest.approx(expected, rel=0.1)
    power[10] = 100.0
    assert bool(cfar_detections(power, guard, train, t_db)[10].all())


@pytest.mark.parametrize("setting", [{"clutter_removal": "mti"}, {"clutter_removal": "mti", "mti_lag": 2},
                                     {"doppler_bins": 64, "doppler_keep": 48, "clutter_removal": "frame"}])
def test_white_noise_power_is_the_monte_carlo_mean_for_the_new_steps(setting):
    """The closed form of the expected noise power per row against the mean of 3000 draws (5 standard errors)."""
    chain = ChainConfig(stft_len=32, stft_hop=32, n_columns=2, **setting)
    gen = torch.Generator().manual_seed(1)
    shape = (3000, 2, 32, 1, 2)
    z = torch.complex(torch.randn(shape, generator=gen, dtype=torch.float64),
                      torch.randn(shape, generator=gen, dtype=torch.float64)) / 2**0.5
    power = profile_power(z, chain)  # (draws, doppler, columns)
    closed = white_noise_power(torch.tensor(1.0, dtype=torch.float64), chain, 2, 32, 1, 2)
    rows, se = power.mean(dim=(0, 2)), power.mean(dim=2).std(dim=0) / 3000**0.5
    assert closed.shape == (chain.n_doppler,)
    assert ((rows - closed).abs() < 5 * se).all()


def test_a_doppler_window_keeps_the_fft_bin_spacing(radar):
    """The central 40 of 64 bins: 40 rows, zero at row 20, spaced 1 / (64 T_loop) as the full FFT's."""
    full = ChainConfig(stft_len=64, stft_hop=64, n_columns=32, doppler_bins=64)
    kept = ChainConfig(stft_len=64, stft_hop=64, n_columns=32, doppler_bins=64, doppler_keep=40)
    np.testing.assert_allclose(doppler_axis_hz(radar, kept), doppler_axis_hz(radar, full)[12:52])
    assert doppler_axis_hz(radar, kept)[20] == 0.0


@pytest.mark.parametrize("bad, match", [
    ({"clutter_removal": "sometimes"}, "clutter_removal must be one of"),
    ({"clutter_removal": 1}, "clutter_removal must be one of"),
    ({"doppler_keep": 80}, "doppler_keep 80 must lie in 2..64"),
    ({"mti_lag": 64}, "mti_lag 64 must lie in 1..63"),
    ({"scale": "log"}, "scale must be one of"),
    ({"normalise": "column"}, "normalise must be one of"),
    ({"range_mode": "max"}, "range_mode must be one of"),
    ({"cfar": (30, 4, 10.0)}, "cfar"),
    ({"threshold": 1.5}, "threshold must lie in"),
])
def test_bad_processing_settings_are_refused(bad, match):
    with pytest.raises(ValueError, match=match):
        ChainConfig(**bad)


def test_clutter_removal_is_a_named_choice():
    """Names; the bools of earlier configs read as window / none."""
    assert ChainConfig(clutter_removal=True).clutter_removal is ClutterRemoval.WINDOW
    assert ChainConfig(clutter_removal=False).clutter_removal is ClutterRemoval.NONE
    assert ChainConfig(clutter_removal="frame").clutter_removal == "frame"
