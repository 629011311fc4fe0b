"""The one processing chain shared by measured and simulated data.

Measured ADC and simulated signals meet at the *per-range-bin slow-time signal*: a complex
tensor of shape ``(..., frames, loops, channels, bins)`` holding the windowed range-FFT value of
each gated range bin for every chirp loop (slow time), every virtual channel (chirp-of-loop x RX)
and every frame. From there every step is shared:

    static clutter removal -> STFT over slow time inside each frame (Hamming 64, hop 64,
    two-sided, zero Doppler centred) -> power summed over gated bins and channels ->
    dB with a floor -> [0, 1]

Measured data reach that signal through :func:`range_profiles_from_adc` (an explicit FFT);
the simulator through :func:`range_response` (the closed-form response of the same windowed
FFT to a beat tone), so both see the same window and the same bins.

Sign convention (docs/architecture.md, "Sign convention"): the IF is ``S_TX conj(S_RX)``, so a
reflector at range R contributes ``A exp(+j 2 pi f_b n / fs) exp(+j 4 pi R / lambda_0)`` with
``f_b = 2 S R / c`` (handradar.radar.signal): positive range bins, and a phase that *falls* while the
reflector approaches. The rows are ordered by the echo's Doppler shift ``f_D = 2 v / lambda`` (v > 0
approaching), the negative of the IF's slow-time frequency: the slow-time transform uses the
``exp(+j ...)`` kernel, so an approaching reflector lands *above* the centre row (rows > n/2) and a
receding one below it, for measured and simulated data alike.

All functions are plain torch and differentiable; none holds state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import scipy.signal
import torch

from handradar.radar.config import RadarConfig

# Generalised cosine windows w[n] = sum_m (-1)^m a_m cos(2 pi m n / N) (periodic form).
COSINE_WINDOWS: dict[str, tuple[float, ...]] = {
    "rect": (1.0,),
    "hann": (0.5, 0.5),
    "hamming": (0.54, 0.46),
    "blackman": (0.42, 0.5, 0.08),
}


class ClutterRemoval(StrEnum):
    """What the chain subtracts from each range bin's slow-time signal before the Doppler transform."""

    NONE = "none"      # nothing
    WINDOW = "window"  # the mean over the window (all its frames and loops)
    FRAME = "frame"    # each frame's own mean over its loops (the TI mmWave SDK's static clutter removal)
    MTI = "mti"        # a two-pulse canceller inside each STFT window (a frame, frame-based): loop m minus loop m - lag

    @classmethod
    def parse(cls, value: object) -> ClutterRemoval:
        """A name, or the bool of earlier configs (true: window, false: none); anything else is an error."""
        if isinstance(value, bool):
            return cls.WINDOW if value else cls.NONE
        if isinstance(value, str) and value in cls._value2member_map_:
            return cls(value)
        raise ValueError(f"clutter_removal must be one of {[c.value for c in cls]}, found {value!r}")

    def __canonical__(self) -> bool | str:
        """The value cache keys hash: the bools earlier caches were keyed by, so that they hold."""
        return {ClutterRemoval.WINDOW: True, ClutterRemoval.NONE: False}.get(self, self.value)


QUANTITIES = ("power", "magnitude")    # ChainConfig.quantity: what a pixel holds before scaling
SCALES = ("db", "linear")              # ChainConfig.scale
NORMALISATIONS = ("image", "frame", "none")  # ChainConfig.normalise: the reference a pixel is scaled to
RANGE_MODES = ("sum", "strongest")     # ChainConfig.range_mode: how the gated range bins become one Doppler image


def _set(**kw: object) -> object:  # a field added after caches keyed by the chain: unset (None), earlier cache keys hold
    return field(metadata={"hash_if_set": True}, **kw)


@dataclass(frozen=True)
class ChainConfig:
    """Settings of the processing chain (the same for measured and simulated data).

    gate_m: range interval (metres) of the bins kept; the hand is expected inside it (one fixed range bin of a
    dataset: a gate that holds one bin).
    stft_len / stft_hop: slow-time STFT window length and hop, in chirp loops; windows never
    straddle two frames (frames are separated by idle time).
    doppler_bins: the Doppler FFT's length, the window zero-padded to it (None: ``stft_len``, no padding).
    doppler_keep: rows kept, the central ``doppler_keep`` of the FFT's bins (None: all); the spectrogram has
    :attr:`n_doppler` rows, zero Doppler at row ``n_doppler // 2``.
    n_columns: spectrogram width; it must be a whole number of frames' worth of columns.
    clutter_removal: :class:`ClutterRemoval` (a name; true / false: window / none); ``mti_lag``: the canceller's
    lag in loops (None: 1).
    range_mode: ``sum`` (None): power summed over the gated bins; ``strongest``: each frame's strongest gated bin
    (power over its loops and channels, after clutter removal) alone.
    quantity / scale / normalise (None: power, db, image): a pixel is the power or the magnitude, scaled to the
    reference of its image (the peak), of its column (each frame's column to its own peak) or none (``reference_db``:
    the power, in dB, shown as 1); in dB with a floor ``dynamic_range_db`` below the reference, or linear.
    cfar: (guard, training, threshold dB) of a cell-averaging CFAR along each column's Doppler cells (cyclic): a cell
    whose power is below the threshold times its training cells' mean is set to 0. threshold: pixels below it
    (a [0, 1] value) set to 0. None: no such step.
    """

    range_window: str = "hann"
    gate_m: tuple[float, float] = (0.08, 0.70)
    stft_window: str = "hamming"
    stft_len: int = 64
    stft_hop: int = 64
    doppler_bins: int | None = _set(default=None)
    n_columns: int = 32
    dynamic_range_db: float = 30.0
    clutter_removal: ClutterRemoval | bool | str = ClutterRemoval.WINDOW
    mti_lag: int | None = _set(default=None)
    doppler_keep: int | None = _set(default=None)
    range_mode: str | None = _set(default=None)
    quantity: str | None = _set(default=None)
    scale: str | None = _set(default=None)
    normalise: str | None = _set(default=None)
    reference_db: float | None = _set(default=None)
    cfar: tuple[int, int, float] | None = _set(default=None)
    threshold: float | None = _set(default=None)

    def __post_init__(self) -> None:
        object.__setattr__(self, "clutter_removal", ClutterRemoval.parse(self.clutter_removal))
        object.__setattr__(self, "gate_m", (float(self.gate_m[0]), float(self.gate_m[1])))
        for name in (self.range_window, self.stft_window):
            if name not in COSINE_WINDOWS:
                raise ValueError(f"unknown window {name!r}; expected one of {sorted(COSINE_WINDOWS)}")
        if not 0 <= self.gate_m[0] < self.gate_m[1]:
            raise ValueError(f"gate_m must be an increasing pair of ranges >= 0, found {self.gate_m}")
        if self.stft_len <= 0 or self.stft_hop <= 0 or self.n_columns <= 0 or self.dynamic_range_db <= 0:
            raise ValueError("stft_len, stft_hop, n_columns and dynamic_range_db must be positive")
        if self.doppler_bins is not None and int(self.doppler_bins) < self.stft_len:
            raise ValueError(f"doppler_bins {self.doppler_bins} is fewer than the STFT length {self.stft_len}")
        if self.doppler_keep is not None and not 2 <= int(self.doppler_keep) <= self.n_fft:
            raise ValueError(f"doppler_keep {self.doppler_keep} must lie in 2..{self.n_fft} (the Doppler FFT's bins)")
        if self.mti_lag is not None and not 1 <= int(self.mti_lag) < self.stft_len:
            raise ValueError(f"mti_lag {self.mti_lag} must lie in 1..{self.stft_len - 1} loops")
        for key, choices in (("range_mode", RANGE_MODES), ("quantity", QUANTITIES), ("scale", SCALES),
                             ("normalise", NORMALISATIONS)):
            if getattr(self, key) is not None and getattr(self, key) not in choices:
                raise ValueError(f"{key} must be one of {list(choices)}, found {getattr(self, key)!r}")
        if self.cfar is not None:
            guard, train, db = self.cfar
            if not (int(guard) >= 0 and int(train) >= 1 and 2 * (int(guard) + int(train)) < self.n_doppler):
                raise ValueError(f"cfar (guard {guard}, training {train}) needs guard >= 0, training >= 1 and "
                                 f"2 (guard + training) < {self.n_doppler} Doppler rows")
            object.__setattr__(self, "cfar", (int(guard), int(train), float(db)))
        if self.threshold is not None and not 0.0 <= float(self.threshold) < 1.0:
            raise ValueError(f"threshold must lie in [0, 1), found {self.threshold}")

    @property
    def n_fft(self) -> int:
        """The Doppler FFT's length."""
        return self.stft_len if self.doppler_bins is None else int(self.doppler_bins)

    @property
    def n_doppler(self) -> int:
        """Rows of a spectrogram: the Doppler FFT's bins kept."""
        return self.n_fft if self.doppler_keep is None else int(self.doppler_keep)

    def columns_per_frame(self, radar: RadarConfig) -> int:
        if radar.n_loops < self.stft_len:
            raise ValueError(f"a frame has {radar.n_loops} loops, fewer than the STFT length {self.stft_len}")
        return (radar.n_loops - self.stft_len) // self.stft_hop + 1

    def frames_per_window(self, radar: RadarConfig) -> int:
        """Frames spanned by one ``n_columns`` spectrogram (16 for the default radar)."""
        cpf = self.columns_per_frame(radar)
        if self.n_columns % cpf:
            raise ValueError(f"n_columns {self.n_columns} is not a multiple of the {cpf} STFT columns per frame")
        return self.n_columns // cpf


def window(name: str, n: int, *, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None) -> torch.Tensor:
    """Periodic (DFT-even) window of length n, the form used before an FFT."""
    w = scipy.signal.get_window("boxcar" if name == "rect" else name, n, fftbins=True)
    return torch.as_tensor(w, dtype=dtype, device=device)


def gate_bins(radar: RadarConfig, chain: ChainConfig) -> tuple[int, int]:
    """Half-open range-bin interval [b0, b1) covering ``chain.gate_m``."""
    res = radar.range_resolution_m
    b0 = max(0, math.ceil(chain.gate_m[0] / res - 1e-9))
    b1 = min(radar.n_range_bins, math.floor(chain.gate_m[1] / res + 1e-9) + 1)
    if b1 <= b0:
        raise ValueError(f"range gate {chain.gate_m} m holds no bin of {res:.4f} m below {radar.max_range_m:.2f} m")
    return b0, b1


# ---- entering the chain ------------------------------------------------------------------------
def range_profiles_from_adc(adc: torch.Tensor, radar: RadarConfig, chain: ChainConfig) -> torch.Tensor:
    """Measured path: ADC cube (frames, chirps_per_frame, rx, samples) -> (frames, loops, channels, gated bins).

    Windowed FFT over fast time; chirps are split loop-major into (loops, chirps_per_loop) and each
    chirp-of-loop x RX pair becomes a virtual channel.
    """
    frames, chirps, n_rx, n = adc.shape[-4:]
    if (chirps, n_rx, n) != (radar.chirps_per_frame, radar.n_rx, radar.n_samples):
        raise ValueError(f"ADC cube shape {tuple(adc.shape)} does not match the radar config "
                         f"(frames, {radar.chirps_per_frame}, {radar.n_rx}, {radar.n_samples})")
    b0, b1 = gate_bins(radar, chain)
    w = window(chain.range_window, n, dtype=adc.real.dtype, device=adc.device)
    spectrum = torch.fft.fft(adc * w, dim=-1)[..., b0:b1]
    lead = adc.shape[:-4]
    spectrum = spectrum.reshape(*lead, frames, radar.n_loops, radar.chirps_per_loop * n_rx, b1 - b0)
    return spectrum


_RESPONSE_CHUNK = 32768  # beat values per pass of range_response
_CHUNKS_PER_BLOCK = 8  # passes per block of per-beat factors


def dirichlet(nu: torch.Tensor, n: int) -> torch.Tensor:
    """D(nu) = sum_{k<n} exp(j 2 pi nu k): the DTFT of a length-n rectangle, nu in cycles/sample."""
    nu = nu - torch.round(nu)  # D has period 1 in nu: keep |nu| <= 1/2 so only nu = 0 is singular
    small = nu.abs() < 1e-7
    s = torch.sin(math.pi * nu)
    ratio = torch.where(small, torch.full_like(nu, float(n)),
                        torch.sin(math.pi * n * nu) / torch.where(small, torch.ones_like(s), s))
    phase = math.pi * (n - 1) * nu
    return torch.complex(ratio * torch.cos(phase), ratio * torch.sin(phase))


def range_response(beat_cycles: torch.Tensor, bins: torch.Tensor, n: int, window_name: str,
                   carrier: torch.Tensor | None = None, sum_dim: int | None = None) -> torch.Tensor:
    """Closed-form windowed range FFT of a unit beat tone.

    beat_cycles: beat frequency in cycles per sample (f_b / fs), any shape S.
    bins: range-bin indices, shape (B,). Returns complex (*S, B): sum_k w[k] exp(j 2 pi (nu - b/n) k),
    exactly what :func:`range_profiles_from_adc` gives for ``exp(j 2 pi nu k)``; times ``carrier``
    (complex, shape S: each tone's amplitude and phase) when given. ``sum_dim``: the responses summed
    over that axis of S (the tones of one signal: S without it, then B), never formed one by one.

    Every term is a Dirichlet kernel D(x - q/n) at an integer shift q (the bin b and the window's
    side lobes b -+ m), and D(x - q/n) = (-1)^q sin(pi n x) exp(j pi (n-1) x) exp(-j pi (n-1) q/n)
    / sin(pi x - pi q/n): so the sines and the phase are evaluated once per beat value, not per
    bin and term (the simulator's hot spot); the summed tones are summed per shift q first (their sum
    commutes with the bins'), and the bins are one small real matmul over the shifts.
    The denominators are float64 (a difference of products), the rest in the input's precision;
    returned in the input's complex dtype. Beat values within ~3e-7 cycles of a pole (x - q/n an
    integer) go through the term-by-term form (:func:`dirichlet`), which takes the limit.
    """
    coefs = COSINE_WINDOWS[window_name]
    bins_i = torch.as_tensor(bins)
    if bins_i.numel() == 0 or (bins_i.is_floating_point() and not bool((bins_i == torch.round(bins_i)).all())):
        out = _range_response_terms(beat_cycles, bins_i, n, window_name)  # the factorisation needs integer bins
        out = out if carrier is None else out * carrier[..., None]
        return out if sum_dim is None else out.sum(sum_dim % beat_cycles.dim())
    bins_i = bins_i.round().long() if bins_i.is_floating_point() else bins_i
    # (G, R): each of the R outputs sums G tones (G = 1: nothing summed), the summed axis first
    if sum_dim is None:
        out_shape, beats = beat_cycles.shape, beat_cycles.reshape(1, -1)
    else:
        moved = beat_cycles.movedim(sum_dim, 0)
        out_shape, beats = moved.shape[1:], moved.reshape(moved.shape[0], math.prod(moved.shape[1:]))
        carrier = None if carrier is None else carrier.movedim(sum_dim, 0)
    carrier_2d = None if carrier is None else carrier.reshape(beats.shape)
    g, r = beats.shape
    # float32 beats: float32 reciprocals, sums and output (the old term-by-term form's precision);
    # the denominators themselves are always differences of float64 products (poles)
    work = torch.float64 if beat_cycles.dtype == torch.float64 else torch.float32
    dev = beat_cycles.device
    x = beats.to(torch.float64)
    # a pole: x - q/n an integer, i.e. n x one; values within 3.2e-7 cycles of any integer n x (a
    # superset of |sin(pi (x - q/n))| < 1e-6) are left to the term-by-term form, which takes the limit
    near = (n * x - torch.round(n * x)).abs() < 3.2e-7 * n
    has_pole = bool(near.any())
    xs = torch.where(near, x + 0.5 / n, x) if has_pole else x  # any value away from the poles
    spread = len(coefs) - 1
    q = torch.arange(int(bins_i.min()) - spread, int(bins_i.max()) + spread + 1, device=dev)  # (Q,) shifts
    # W[q, b] = (-1)^q exp(-j pi (n-1) q / n) * (window coefficient of D(x - q/n) in bin b)
    diff = (q[:, None] - bins_i.to(dev)[None, :]).abs()
    coef = torch.zeros(diff.shape, dtype=torch.float64, device=dev)
    for m, a in enumerate(coefs):
        coef = torch.where(diff == m, a if m == 0 else (-1) ** m * a / 2, coef)
    qf = q.to(torch.float64)
    sign = 1.0 - 2.0 * (q % 2).to(torch.float64)
    w = coef * (sign * torch.polar(torch.ones_like(qf), -math.pi * (n - 1) * qf / n))[:, None]  # (Q, B)
    shift = torch.stack([torch.cos(math.pi * qf / n), -torch.sin(math.pi * qf / n)], dim=1)  # (Q, 2)
    mix = torch.cat([torch.stack([w.real, w.imag], dim=-1), torch.stack([-w.imag, w.real], dim=-1)])  # (2Q, B, 2)
    nb = bins_i.shape[0]
    mix = mix.reshape(2 * len(q), 2 * nb).to(work)  # (2Q, 2B)
    grad = torch.is_grad_enabled() and (beat_cycles.requires_grad or (carrier is not None and carrier.requires_grad))
    out = None if grad else torch.empty(r, 2 * nb, dtype=work, device=dev)
    parts = []
    # in chunks of outputs for the (Q, G, Rc) terms: small temporaries are reused by the allocator, where large
    # ones are mapped and faulted in afresh on every call (measured: the chunks halve the time); the per-beat
    # factors once per block of chunks (a sixth less time than once per chunk: fewer small ops)
    chunk = max(1, _RESPONSE_CHUNK // max(g, 1))
    block = chunk * _CHUNKS_PER_BLOCK
    for b0 in range(0, max(r, 1), block):  # once at least: no beats still gives a (0, B) graph node
        xb = xs[:, b0:b0 + block]  # (G, Rb)
        # per beat value L = sin(pi n x) e^{j pi (n-1) x} = sin(pi n x) e^{j pi n x} e^{-j pi x} (times the
        # carrier, 0 at a pole: added below), as (Re, Im) in the working precision
        sin_x, cos_x = torch.sin(math.pi * xb), torch.cos(math.pi * xb)
        sin_n, cos_n = torch.sin(math.pi * n * xb), torch.cos(math.pi * n * xb)
        lead = torch.stack([sin_n * (cos_n * cos_x + sin_n * sin_x), sin_n * (sin_n * cos_x - cos_n * sin_x)]).to(work)
        if carrier_2d is not None:
            re, im = carrier_2d[:, b0:b0 + block].real.to(work), carrier_2d[:, b0:b0 + block].imag.to(work)
            lead = torch.stack([lead[0] * re - lead[1] * im, lead[0] * im + lead[1] * re])
        if has_pole:
            lead = torch.where(near[:, b0:b0 + block], 0, lead)
        sc = torch.stack([sin_x, cos_x])  # (2, G, Rb) float64
        for c0 in range(0, max(xb.shape[1], 1), chunk):
            rc = min(chunk, xb.shape[1] - c0)
            # 1 / sin(pi (x - q/n)), (Q, G Rc): sin(pi x) cos(pi q/n) - cos(pi x) sin(pi q/n) as one float64
            # matmul (the long axis innermost keeps every later broadcast fast)
            den = shift @ sc[:, :, c0:c0 + chunk].reshape(2, -1)
            if grad or work == torch.float64:  # out= records no graph
                inv = den.reciprocal().to(work)
            else:  # the same values, cast by the reciprocal itself: no float64 copy of the reciprocals
                inv = torch.reciprocal(den, out=torch.empty(den.shape, dtype=work, device=dev))
            # sum_g L_g inv_qg per shift q (the tones' sum first: it commutes with the bins' matmul), then
            # [Re, Im] (Rc, 2Q) times [[Re W, Im W], [-Im W, Re W]], its columns interleaved (re, im) per bin
            # so that the product is the complex result's real view
            terms = inv.reshape(1, len(q), g, rc) * lead[:, None, :, c0:c0 + chunk]
            scaled = terms.sum(2).reshape(2 * len(q), rc).T  # (Rc, 2Q)
            if out is None:
                parts.append(scaled @ mix)
            else:
                torch.matmul(scaled, mix, out=out[b0 + c0:b0 + c0 + rc])
    if out is None:
        out = torch.cat(parts) if len(parts) > 1 else parts[0]
    if has_pole:
        at = torch.nonzero(near.reshape(-1)).flatten()
        # in the caller's precision: exactly the term-by-term values
        poles = _range_response_terms(beats.reshape(-1)[at], bins_i.to(dev), n, window_name)
        if carrier_2d is not None:
            poles = poles * carrier_2d.reshape(-1)[at, None]
        poles = torch.view_as_real(poles.to(torch.complex128 if work == torch.float64 else torch.complex64))
        poles = poles.reshape(-1, 2 * nb)
        # in place where autograd is off: no copy of the whole response for a few values
        out = out.index_add(0, at % r, poles) if out.requires_grad else out.index_add_(0, at % r, poles)
    return torch.view_as_complex(out.reshape(*out_shape, nb, 2))


def _range_response_terms(beat_cycles: torch.Tensor, bins: torch.Tensor, n: int, window_name: str) -> torch.Tensor:
    """range_response term by term: one Dirichlet kernel per window term and bin (the plain form;
    handles any bins and the poles)."""
    nu = beat_cycles.unsqueeze(-1) - bins.to(beat_cycles.dtype) / n
    out = 0
    for m, a in enumerate(COSINE_WINDOWS[window_name]):
        if m == 0:
            out = out + a * dirichlet(nu, n)
        else:
            out = out + ((-1) ** m) * a / 2 * (dirichlet(nu + m / n, n) + dirichlet(nu - m / n, n))
    return out


# ---- shared steps --------------------------------------------------------------------------------
def remove_static_clutter(profiles: torch.Tensor, per_frame: bool = False) -> torch.Tensor:
    """Subtract the slow-time mean of each range bin and channel over all frames and loops (``per_frame``:
    over each frame's loops)."""
    return profiles - profiles.mean(dim=(-3,) if per_frame else (-4, -3), keepdim=True)


def mti_cancel(segments: torch.Tensor, lag: int = 1) -> torch.Tensor:
    """A two-pulse canceller along the loops (axis -3) of STFT windows (..., loops, channels, bins): loop m becomes
    loop m minus loop m - ``lag``; the first ``lag`` loops, which have no predecessor in the window, become 0 (the
    window keeps its length and its loops their times). Its power response is 4 sin^2(pi f lag), f in cycles a loop."""
    out = torch.zeros_like(segments)
    out[..., lag:, :, :] = segments[..., lag:, :, :] - segments[..., :-lag, :, :]
    return out


def clutter_removed(profiles: torch.Tensor, chain: ChainConfig) -> torch.Tensor:
    """``profiles`` (..., frames, loops, channels, bins) after the chain's mean removal (ClutterRemoval window or
    frame); the MTI canceller runs inside each STFT window instead (:func:`stft_power`)."""
    c = chain.clutter_removal
    if c in (ClutterRemoval.NONE, ClutterRemoval.MTI):
        return profiles
    return remove_static_clutter(profiles, per_frame=c == ClutterRemoval.FRAME)


def kept_rows(chain: ChainConfig) -> slice:
    """The rows of the fftshifted Doppler FFT the spectrogram keeps: the central ``n_doppler`` of ``n_fft``, zero
    Doppler (row ``n_fft // 2``) landing on row ``n_doppler // 2``."""
    first = chain.n_fft // 2 - chain.n_doppler // 2
    return slice(first, first + chain.n_doppler)


def stft_power(profiles: torch.Tensor, chain: ChainConfig) -> torch.Tensor:
    """STFT over slow time inside each frame (the MTI canceller, if set, inside each window), power summed over
    channels and collapsed over the gated bins (``range_mode``).

    profiles (..., frames, loops, channels, bins) -> power (..., doppler = n_doppler, columns),
    columns in time order (``columns_per_frame`` per frame), zero Doppler at row n_doppler // 2,
    approaching reflectors above it (module doc, sign convention). The window is zero-padded to
    ``n_fft`` (``doppler_bins``), of whose rows the central ``n_doppler`` are kept (``doppler_keep``).
    """
    frames, loops = profiles.shape[-4:-2]
    n_win = (loops - chain.stft_len) // chain.stft_hop + 1
    if n_win < 1:
        raise ValueError(f"{loops} loops per frame is fewer than the STFT length {chain.stft_len}")
    starts = torch.arange(n_win, device=profiles.device) * chain.stft_hop
    idx = starts[:, None] + torch.arange(chain.stft_len, device=profiles.device)[None, :]
    segs = profiles[..., idx, :, :]  # (..., frames, n_win, len, ch, bins)
    if chain.clutter_removal == ClutterRemoval.MTI:  # inside each window: every column sees the same canceller
        segs = mti_cancel(segs, chain.mti_lag or 1)
    w = window(chain.stft_window, chain.stft_len, dtype=profiles.real.dtype, device=profiles.device)
    # the exp(+j) kernel (unscaled inverse DFT): rows ordered by the echo's Doppler shift, approaching above
    spec = torch.fft.fftshift(torch.fft.ifft(segs * w[:, None, None], n=chain.n_fft, dim=-3, norm="forward"), dim=-3)
    if chain.doppler_keep is not None:
        spec = spec[..., kept_rows(chain), :, :]
    cells = (spec.real**2 + spec.imag**2).sum(dim=-2)  # (..., frames, n_win, doppler, bins)
    if chain.range_mode == "strongest":  # each frame's bin of most power (its windows, rows and channels)
        best = cells.sum(dim=(-3, -2)).argmax(dim=-1)  # (..., frames)
        index = best[..., None, None, None].expand(*cells.shape[:-1], 1)
        power = cells.gather(-1, index)[..., 0]
    else:
        power = cells.sum(dim=-1)  # (..., frames, n_win, doppler)
    power = power.flatten(-3, -2)  # (..., columns, doppler)
    return power.transpose(-1, -2)


def select_window_start(power: torch.Tensor, chain: ChainConfig, columns_per_frame: int) -> int:
    """First frame of the ``n_columns`` window (frame-aligned) holding the most energy.

    power: (doppler, columns) of one recording. Frame alignment keeps the window's chirp times
    identical for measured and simulated data.
    """
    per_col = power.detach().sum(dim=-2).reshape(-1)
    n_cols = per_col.shape[0]
    if n_cols < chain.n_columns:
        raise ValueError(f"capture gives {n_cols} STFT columns, fewer than the {chain.n_columns} of a spectrogram")
    frame_energy = per_col[: n_cols - n_cols % columns_per_frame].reshape(-1, columns_per_frame).sum(-1)
    fpw = chain.n_columns // columns_per_frame
    sums = frame_energy.unfold(0, fpw, 1).sum(-1)
    return int(torch.argmax(sums))


def power_to_unit(power: torch.Tensor, chain: ChainConfig) -> torch.Tensor:
    """Power (..., doppler, columns) -> the spectrogram in [0, 1] (ChainConfig's quantity, normalise, scale, cfar,
    threshold; by default: dB, clamped ``dynamic_range_db`` below each spectrogram's peak).

    The reference is the peak over the last two dims (``image``), over each column (``frame``), or the power
    10^(reference_db / 10) (``none``). The CFAR decides on the power; the fixed threshold on the [0, 1] value."""
    if (chain.quantity, chain.scale, chain.normalise) == (None, None, None):  # the default, as every cache holds it
        peak = power.detach().amax(dim=(-2, -1), keepdim=True)
        db = 10.0 * torch.log10(power + 1e-12 * peak + 1e-30)
        top = db.amax(dim=(-2, -1), keepdim=True)
        unit = ((db - top + chain.dynamic_range_db) / chain.dynamic_range_db).clamp(0.0, 1.0)
    else:
        unit = scaled_to_unit(power, chain)
    if chain.cfar is not None:
        unit = torch.where(cfar_detections(power, *chain.cfar), unit, torch.zeros_like(unit))
    if chain.threshold is not None:
        unit = torch.where(unit >= chain.threshold, unit, torch.zeros_like(unit))
    return unit


def scaled_to_unit(power: torch.Tensor, chain: ChainConfig) -> torch.Tensor:
    """Power -> [0, 1] by ``quantity``, ``normalise`` and ``scale`` (:func:`power_to_unit`)."""
    normalise = chain.normalise or "image"
    if normalise == "image":
        ref = power.detach().amax(dim=(-2, -1), keepdim=True)
    elif normalise == "frame":
        ref = power.detach().amax(dim=-2, keepdim=True)
    else:
        ref = torch.full_like(power[..., :1, :1], 10.0 ** ((chain.reference_db or 0.0) / 10.0))
    relative = power / ref.clamp_min(1e-30)  # power relative to the reference
    if (chain.scale or "db") == "db":  # a magnitude's dB, 20 log10 |x|, is its power's
        db = 10.0 * torch.log10(relative + 1e-30)
        return ((db + chain.dynamic_range_db) / chain.dynamic_range_db).clamp(0.0, 1.0)
    return (relative.sqrt() if chain.quantity == "magnitude" else relative).clamp(0.0, 1.0)


def cfar_detections(power: torch.Tensor, guard: int, train: int, threshold_db: float) -> torch.Tensor:
    """Cell-averaging CFAR along the Doppler axis (-2) of ``power`` (..., doppler, columns), cyclic (the axis is an
    FFT's): True where a cell's power exceeds 10^(threshold_db / 10) times the mean of its 2 ``train`` training
    cells, the ``guard`` cells on either side of it left out."""
    noise = torch.zeros_like(power)
    for k in range(guard + 1, guard + train + 1):
        noise = noise + torch.roll(power, k, dims=-2) + torch.roll(power, -k, dims=-2)
    return power > 10.0 ** (threshold_db / 10.0) * noise / (2 * train)


def profile_power(profiles: torch.Tensor, chain: ChainConfig) -> torch.Tensor:
    """Per-range-bin slow-time signal -> clutter removal (if set) -> STFT power (..., doppler, columns)."""
    return stft_power(clutter_removed(profiles, chain), chain)


def white_noise_power(variance: torch.Tensor, chain: ChainConfig, n_frames: int, n_loops: int, n_channels: int,
                      n_bins: int) -> torch.Tensor:
    """Expected :func:`profile_power` of white noise over ``n_frames`` frames of ``n_loops`` chirp loops,
    (..., doppler): the same in every column.

    ``variance`` (any shape ...): E|n|^2 of each per-range-bin value, independent across chirps
    and channels (receiver noise after the range FFT: correlation across bins does not change the
    summed power). A windowed DFT bin d of the clutter-removed loops holds variance ||a_d||^2, a_d the
    coefficients that bin gives each input loop: for a mean removal over N values (frames x loops; a frame's
    loops for ``frame``) that is sum w^2 - |W(d)|^2 / N, W the window's DFT, notching the rows near zero
    Doppler only; for the MTI canceller, the window's taps less their shifted copies. Summed over
    ``n_channels`` channels and ``n_bins`` bins (one bin for ``range_mode`` strongest: the chosen bin's
    expectation, the choice's bias left out)."""
    c = chain.clutter_removal
    w = window(chain.stft_window, chain.stft_len, dtype=torch.float64)
    if c == ClutterRemoval.MTI:  # y_m = x_m - x_{m-lag} for m >= lag, 0 below: a_d[k] = w_k e_k [k>=lag] - w_{k+lag} e_{k+lag}
        lag = chain.mti_lag or 1
        k = torch.arange(chain.stft_len, dtype=torch.float64)
        d = torch.arange(chain.n_fft, dtype=torch.float64) - chain.n_fft // 2
        e = torch.polar(torch.ones(len(d), len(k), dtype=torch.float64), 2 * math.pi * d[:, None] * k[None, :] / chain.n_fft)
        a = torch.where(k >= lag, w, torch.zeros_like(w)) * e
        a[:, :-lag] -= (w[lag:] * e[:, lag:])
        per_row = (a.abs() ** 2).sum(dim=1)
    else:
        n_mean = n_loops if c == ClutterRemoval.FRAME else n_frames * n_loops
        per_row = torch.full((chain.n_fft,), float((w**2).sum()), dtype=torch.float64)
        if c != ClutterRemoval.NONE:
            per_row = per_row - torch.fft.fftshift(torch.fft.fft(w, n=chain.n_fft).abs() ** 2) / n_mean
    per_row = per_row[kept_rows(chain)]
    if chain.range_mode == "strongest":
        n_bins = 1
    variance = torch.as_tensor(variance)
    if not variance.is_floating_point():
        variance = variance.to(torch.float64)
    return variance[..., None] * (n_channels * n_bins * per_row).to(variance.dtype)


def spectrogram_from_profiles(profiles: torch.Tensor, chain: ChainConfig) -> torch.Tensor:
    """Per-range-bin slow-time signal of one window -> spectrogram in [0, 1] (..., doppler, columns)."""
    return power_to_unit(profile_power(profiles, chain), chain)


def measured_spectrogram(adc: np.ndarray | torch.Tensor, radar: RadarConfig, chain: ChainConfig) -> tuple[torch.Tensor, int]:
    """Measured path end to end: ADC cube -> (spectrogram (doppler, n_columns), window start frame).

    The window is chosen on the whole capture; its spectrogram is then computed from the window's
    frames alone, exactly as the simulator computes it, so both see the same clutter mean.
    """
    return capture_spectrogram(range_profiles_from_adc(torch.as_tensor(adc), radar, chain), radar, chain)


def capture_spectrogram(profiles: torch.Tensor, radar: RadarConfig, chain: ChainConfig,
                        start: int | None = None) -> tuple[torch.Tensor, int]:
    """A whole capture's per-range-bin signal (frames, loops, channels, bins) -> (spectrogram, window start frame).

    The second half of :func:`measured_spectrogram`, shared with generators that reach the
    per-range-bin signal without an ADC cube (the reference world's fast path). ``start``: the
    window's first frame, given instead of chosen (e.g. to compare two worlds row by row at the
    same window); None selects the window holding the most energy, as for measured data.
    """
    fpw = chain.frames_per_window(radar)
    if profiles.shape[-4] < fpw:
        raise ValueError(f"capture has {profiles.shape[-4]} frames, fewer than the {fpw} of one spectrogram")
    if start is None:
        full = profile_power(profiles, chain)
        start = select_window_start(full, chain, chain.columns_per_frame(radar))
    elif not 0 <= start <= profiles.shape[-4] - fpw:
        raise ValueError(f"window start frame {start} outside the capture's 0..{profiles.shape[-4] - fpw}")
    return spectrogram_from_profiles(profiles[..., start:start + fpw, :, :, :], chain), start


# ---- axes ---------------------------------------------------------------------------------------
def doppler_axis_hz(radar: RadarConfig, chain: ChainConfig) -> np.ndarray:
    """Echo Doppler shift 2 v / lambda of each spectrogram row, positive approaching (row n_doppler // 2 is zero)."""
    k = np.arange(chain.n_doppler) - chain.n_doppler // 2
    return k / (chain.n_fft * radar.loop_period_s)


def velocity_axis_m_s(radar: RadarConfig, chain: ChainConfig) -> np.ndarray:
    """Radial velocity of each row; positive = approaching the radar."""
    return doppler_axis_hz(radar, chain) * radar.wavelength_m / 2.0


def column_times_s(radar: RadarConfig, chain: ChainConfig, n_frames: int, start_frame: int = 0) -> np.ndarray:
    """Centre time of each STFT column of frames [start_frame, start_frame + n_frames)."""
    t = radar.chirp_times_s(start_frame + n_frames)[start_frame:, :, 0]  # (frames, loops)
    cpf = chain.columns_per_frame(radar)
    cols = [t[:, s * chain.stft_hop: s * chain.stft_hop + chain.stft_len].mean(axis=1) for s in range(cpf)]
    return np.stack(cols, axis=1).reshape(-1)
