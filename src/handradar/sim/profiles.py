"""Per-reflection-point IF synthesis in the chain's domain (docs/architecture.md, "Processing chain and simulator"), plain torch.

For every reflection point k and chirp c (true chirp times, idle gaps included):

    R_k(c)   = (|tx_k(c)| + |rx_k(c)|) / 2            positions linearly interpolated in time
    A_k(c)   = radar_amplitude(sigma_k, |tx_k|, |rx_k|) * gain_k   at the skeleton steps, then
               interpolated linearly in time (amplitudes vary slowly)
    P_k(c,b) = A_k(c) exp(+j 4 pi R_k(c) / lambda_0) range_response(2 S R_k(c) / c0 / fs, b, N, window)

exactly the sign and window convention of handradar.radar.signal (carrier_phase_rad) and
handradar.radar.chain, so the
profiles equal range_profiles_from_adc(beat_signal(...)) for the same trajectory (tests check it).
Points are summed per owner slot: (B, 39, ...) = 38 weighted bone slots + 1 unweighted slot.

Virtual channels: chirp-of-loop c gets its own chirp times (TDM); the RX of a chirp get the same
signal. The chain sums power non-coherently over channels, so the RX phase offsets of the array,
which are not modelled, cannot change a spectrogram.

Public API:

    window_chirp_times(radar, chain) -> np.ndarray (F, L, C) seconds from the window start
    scatterer_profiles(scat, times (T,) | (B, T), chirp_times (F, L, C), radar, chain, *,
                       tx_power_w, gain_tx_dbi, gain_rx_dbi, summed=False) -> (B, 39, F, L, C * n_rx, bins) complex
                       (summed: (B, F, L, C * n_rx, bins), the slots' sum)
    combine_slots(slot_profiles (B, 39, F, L, Ch, bins) complex | (..., 2) real view, weights (B, 38, F, L, C)
        | None, n_rx, active (38,) bool | None) -> (B, F, L, Ch, bins) complex: sum_k w_k P_k + unweighted slot
"""

from __future__ import annotations

import numpy as np
import torch

from handradar.radar.chain import ChainConfig, gate_bins, range_response
from handradar.radar.config import SPEED_OF_LIGHT_M_S, RadarConfig
from handradar.radar.signal import carrier_phase_rad
from handradar.sim.interp import interp_weights, lerp, lerp_norm
from handradar.sim.scatterers import N_SLOTS, Scatterers, radar_amplitude

N_ALL_SLOTS = N_SLOTS + 1  # 38 weighted bone slots + 1 unweighted slot (index 38)


def window_chirp_times(radar: RadarConfig, chain: ChainConfig) -> np.ndarray:
    """Chirp times (F, L, C) seconds of one spectrogram window, relative to its first frame."""
    return radar.chirp_times_s(chain.frames_per_window(radar))


def scatterer_profiles(scat: Scatterers, times: torch.Tensor, chirp_times: torch.Tensor | np.ndarray,
                       radar: RadarConfig, chain: ChainConfig, *, tx_power_w: float, gain_tx_dbi: float,
                       gain_rx_dbi: float, summed: bool = False) -> torch.Tensor:
    """Per-slot range profiles (B, 39, F, L, C * n_rx, gated bins), complex (see module doc); ``summed``: their
    sum over the slots (B, F, L, C * n_rx, gated bins), every point at weight 1, built without the slots."""
    dtype = scat.tx.dtype
    cdtype = torch.complex128 if dtype == torch.float64 else torch.complex64
    dev = scat.tx.device
    ct = torch.as_tensor(chirp_times, dtype=torch.float64, device=dev)
    f, l, c = ct.shape
    times = torch.as_tensor(times, device=dev)
    lo, frac = interp_weights(times.to(torch.float64), ct.reshape(-1))
    frac = frac.to(dtype)

    tx, rx = scat.tx, scat.rx
    direct = rx is tx  # direct paths: one distance serves both legs
    r_tx = tx.norm(dim=-1)  # (B, T, K) at the skeleton steps
    amp = radar_amplitude(scat.rcs_m2, r_tx, r_tx if direct else rx.norm(dim=-1), radar.wavelength_m, tx_power_w,
                          gain_tx_dbi, gain_rx_dbi) * scat.gain
    # points silent at every step of the batch (a hand untracked all window) are silent at every chirp
    # and add exact zeros: they are left out before interpolating, unless autograd is recording (d/d
    # amplitude is nonzero at amplitude 0 too, and a caller may backpropagate through an all-silent batch)
    owner = torch.where(scat.owner < 0, torch.full_like(scat.owner, N_SLOTS), scat.owner)
    if not (torch.is_grad_enabled() and (amp.requires_grad or frac.requires_grad)):  # amp carries tx's and rx's
        live = torch.nonzero((amp != 0).flatten(0, 1).any(0)).flatten()
        if live.numel() < scat.n_points:
            amp, owner = amp[..., live], owner[live]
            tx = tx[:, :, live]
            rx = tx if direct else rx[:, :, live]
    # the chirps innermost, (B, K, M): the slots come out contiguous in the (B, 39, F, L, Ch, bins)
    # layout that combine_slots and the cache read without a copy
    amp_c = lerp(amp, lo, frac).transpose(1, 2).contiguous()
    rng = lerp_norm(tx, lo, frac)
    rng = rng if direct else 0.5 * (rng + lerp_norm(rx, lo, frac))
    rng = rng.transpose(1, 2).contiguous()  # (B, K, M)

    b0, b1 = gate_bins(radar, chain)
    bins = torch.arange(b0, b1, device=dev)
    beat = rng * (2.0 * radar.slope_hz_per_s / SPEED_OF_LIGHT_M_S / radar.sample_rate_hz)
    carrier = torch.polar(amp_c, carrier_phase_rad(radar, rng))  # A exp(+j 4 pi R / lambda_0)
    bsz = beat.shape[0]
    if summed:  # the points' sum, (B, M, nb): their responses are never formed one by one
        total = range_response(beat, bins, radar.n_samples, chain.range_window, carrier, sum_dim=1).to(cdtype)
        total = total.reshape(bsz, f, l, c, 1, -1).expand(-1, -1, -1, -1, radar.n_rx, -1)
        return total.reshape(bsz, f, l, c * radar.n_rx, -1)
    prof = range_response(beat, bins, radar.n_samples, chain.range_window, carrier).to(cdtype)  # (B, K, M, nb)
    m = prof.shape[2]
    if owner.shape[0] == N_SLOTS and bool((owner == torch.arange(N_SLOTS, device=dev)).all()):
        slots = torch.cat([prof, prof.new_zeros(bsz, 1, m, prof.shape[-1])], dim=1)
    elif owner.shape[0] <= N_SLOTS and bool((owner[1:] > owner[:-1]).all()):  # distinct slots: a copy
        slots = prof.new_zeros(bsz, N_ALL_SLOTS, m, prof.shape[-1]).index_copy(1, owner, prof)
    else:
        slots = prof.new_zeros(bsz, N_ALL_SLOTS, m, prof.shape[-1]).index_add(1, owner, prof)
    slots = slots.reshape(bsz, N_ALL_SLOTS, f, l, c, 1, -1).expand(-1, -1, -1, -1, -1, radar.n_rx, -1)
    return slots.reshape(bsz, N_ALL_SLOTS, f, l, c * radar.n_rx, -1)


def _weighted_sum(flat: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """(B, 39, M, 2 bins) real, (B, 38, M, 1) -> (B, M, 2 bins): the kernel torch.compile fuses."""
    return (flat[:, :N_SLOTS].to(weights.dtype) * weights).sum(1) + flat[:, N_SLOTS].to(weights.dtype)


_compiled_weighted_sum = None


def _compiled() -> object:
    global _compiled_weighted_sum
    if _compiled_weighted_sum is None:
        _compiled_weighted_sum = torch.compile(_weighted_sum, dynamic=None)
    return _compiled_weighted_sum


def combine_slots(slot_profiles: torch.Tensor, weights: torch.Tensor | None = None, n_rx: int = 1,
                  active: torch.Tensor | None = None, compiled: bool = False) -> torch.Tensor:
    """sum_k w_k(c) P_k(c, b) over the 38 bone slots, plus the unweighted slot -> (B, F, L, Ch, bins) complex.

    slot_profiles: (B, 39, F, L, Ch, bins) complex, or its real view (..., 2) in any float dtype
    (e.g. the float16 cache; converted one slot at a time). weights: (B, 38, F, L, C) real at the
    chirp times (each chirp's value repeated over its n_rx receivers) or None (all 1).
    active: optional (38,) bool, False for bone slots known to be zero in the whole batch (an
    untracked hand), which are skipped. Accumulating slot by slot in place avoids a (B, 38, ...)
    temporary: several times faster on a CPU. ``compiled=True`` runs the weighted sum through
    torch.compile instead (one fused pass over the profiles, ~3x faster again; needs a C++ compiler
    and ~30 s to compile once per process and shape; ``active`` is ignored there).
    """
    real = torch.view_as_real(slot_profiles) if slot_profiles.is_complex() else slot_profiles
    acc_dtype = torch.float64 if real.dtype == torch.float64 else torch.float32
    b, _, f, l, ch, nb, _ = real.shape
    # (B, slots, chirps, bins * 2): one broadcast dimension for the weights keeps the loop fast
    flat = real.reshape(b, real.shape[1], f * l * ch, nb * 2)
    if weights is not None:
        if n_rx > 1:
            weights = weights.repeat_interleave(n_rx, dim=-1)
        weights = weights.to(acc_dtype).reshape(b, N_SLOTS, f * l * ch, 1)
        if compiled:
            return torch.view_as_complex(_compiled()(flat, weights).reshape(b, f, l, ch, nb, 2))
    out = flat[:, N_SLOTS].to(acc_dtype).clone()
    ks = range(N_SLOTS) if active is None else torch.nonzero(torch.as_tensor(active)).flatten().tolist()
    slots = flat.unbind(1)  # unbind, not slicing: one gradient buffer in the backward pass, not 38
    ws = weights.unbind(1) if weights is not None else None
    for k in ks:
        p = slots[k].to(acc_dtype)
        if ws is None:
            out.add_(p)
        else:
            out.addcmul_(p, ws[k])
    return torch.view_as_complex(out.reshape(b, f, l, ch, nb, 2))
