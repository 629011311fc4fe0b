"""noise: receiver noise, white complex Gaussian at the ADC, at a signal-to-noise ratio.

Noise n[s] ~ CN(0, sigma^2) per ADC sample goes through the same windowed range FFT as the data
(handradar.radar.chain.range_profiles_from_adc), so its correlation across range bins is the
measured one. sigma is set per example from snr_db = 10 log10(P_signal / P_noise), both per
range bin and chirp after the FFT: P_signal the mean power of the example's dynamic signal (slow-
time mean removed), P_noise = sigma^2 sum_n w[n]^2. ADC quantisation is not separate: at 16 bits
it sits far below receiver noise. Draws come from the module's own generator (``seed``);
``reset_rng()`` replays them. Fitted by grid (the draws make gradients noisy).

``draws`` > 1 makes the simulator average the power of that many independent draws before dB
(Simulator.spectrogram); ``draws = 0`` is the limit of many draws in closed form
(:meth:`Noise.expected_power`: the signal's power plus the chain's expected noise power): the
expected spectrogram, a noise floor at the right level without one particular speckle pattern. The
gap diagnosis compares with it (a measured speckle pattern is never reproduced pixel by pixel, so a
single draw costs SSIM even at the right level); synthetic training data keep one draw
(draws = 1), like a measurement.

Unit noise is drawn once per generator state: simulators whose generators stand at the same state
(the variants of one gap-diagnosis pass, all seeded alike for common random numbers) reuse the same
range-binned draw instead of drawing every ADC sample again (:func:`unit_noise`). The draw is then
bit-identical and the generator moves on exactly as if it had drawn.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import torch

from handradar.radar.chain import (
    ChainConfig,
    range_profiles_from_adc,
    white_noise_power,
    window,
)
from handradar.radar.config import RadarConfig
from handradar.sim.effects.base import Effect, Param, register

_DRAW_CACHE: OrderedDict[tuple, tuple[torch.Tensor, torch.Tensor]] = OrderedDict()
_DRAW_CACHE_SIZE = 8  # draws kept: a diagnosis pass needs one batch's draws (`draws` of them, 4 by default) at a time


def unit_noise(generator: torch.Generator, shape: tuple[int, ...], dtype: torch.dtype, radar: RadarConfig,
               chain: ChainConfig) -> torch.Tensor:
    """Range profiles (B, F, L, Ch, gated bins) of white complex ADC noise of unit variance per
    sample, drawn from ``generator`` for ADC cubes of ``shape``; cached by the generator's state,
    which the call leaves where a draw would have (so later draws are unchanged)."""
    state = generator.get_state()
    key = (hashlib.blake2b(state.numpy().tobytes(), digest_size=16).digest(), tuple(shape), dtype, radar, chain)
    hit = _DRAW_CACHE.get(key)
    if hit is not None:
        _DRAW_CACHE.move_to_end(key)
        generator.set_state(hit[1])
        return hit[0]
    z = torch.complex(torch.randn(shape, generator=generator, dtype=dtype),
                      torch.randn(shape, generator=generator, dtype=dtype)) / 2**0.5
    noise = range_profiles_from_adc(z, radar, chain)
    _DRAW_CACHE[key] = (noise, generator.get_state())
    if len(_DRAW_CACHE) > _DRAW_CACHE_SIZE:
        _DRAW_CACHE.popitem(last=False)
    return noise


@register
class Noise(Effect):
    name = "noise"
    stage = "signal"
    order = 80
    fit = "grid"
    params = {"snr_db": Param(20.0, -20.0, 60.0, (0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0), "signal-to-noise ratio per range bin, dB")}

    def __init__(self, seed: int = 0, draws: int = 1, **values: float) -> None:
        super().__init__(**values)
        self.seed = int(seed)
        if int(draws) < 0:
            raise ValueError(f"noise: draws must be >= 0 (0: the expectation in closed form), found {draws}")
        self.draws = int(draws)
        self.reset_rng()

    def settings(self) -> dict[str, int]:
        return {"seed": self.seed, "draws": self.draws}

    def reset_rng(self) -> None:
        self.generator = torch.Generator().manual_seed(self.seed)

    def noise_power(self, signal: torch.Tensor, power_scale: torch.Tensor | None = None) -> torch.Tensor:
        """(B, 1, 1, 1, 1): the noise power per range bin and chirp, P_signal / 10^(snr / 10), snr =
        snr_db. P_signal is the summed signal's mean power
        after clutter removal, times ``power_scale`` (B,) if given: the SNR is relative to the power the
        chain shows (Simulator coherence)."""
        dyn = signal - signal.mean(dim=(-4, -3), keepdim=True)
        p_sig = (dyn.real**2 + dyn.imag**2).mean(dim=(-4, -3, -2, -1), keepdim=True).detach()
        if power_scale is not None:
            p_sig = p_sig * power_scale.detach().to(p_sig.dtype).reshape(-1, 1, 1, 1, 1)
        snr = self.value("snr_db").to(p_sig.dtype)
        return p_sig / 10.0 ** (snr / 10.0)

    def expected_power(self, signal: torch.Tensor, radar, chain, power_scale: torch.Tensor | None = None
                       ) -> torch.Tensor:
        """E[profile_power(noise)] (B, doppler, 1), the same in every column; added to the signal's
        own power it is the expected power of signal + noise exactly (the cross terms have zero mean)."""
        f, l, ch, bins = signal.shape[-4:]
        level = self.noise_power(signal, power_scale).reshape(-1)
        return white_noise_power(level, chain, f, l, ch, bins)[..., None]

    def apply_signal(self, signal, radar, chain, power_scale=None):
        real = signal.real.dtype
        w2 = float((window(chain.range_window, radar.n_samples, dtype=torch.float64) ** 2).sum())
        sigma = torch.sqrt(self.noise_power(signal, power_scale) / w2)
        shape = (signal.shape[0], signal.shape[1], radar.chirps_per_frame, radar.n_rx, radar.n_samples)
        noise = unit_noise(self.generator, shape, real, radar, chain).to(signal.device)  # (B, F, L, Ch, bins)
        return signal + sigma.to(real) * noise
