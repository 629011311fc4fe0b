"""Linear interpolation in time (not by sample index): skeleton steps -> chirp times.

Radar frames have idle gaps, so chirp times are not evenly spaced; everything that moves from
the skeleton rate to the chirp rate goes through these functions, with the true times.

Public API (torch; differentiable in the values and in the times, e.g. for a clock offset):

    interp_weights(times (T,) | (B, T), new_times (M,) | (B, M)) -> (lo, frac): (…, M) long / float
        times outside [times[0], times[-1]] are clamped (the end values are held)
    lerp(x (B, T, ...), lo, frac) -> (B, M, ...)   (reuse one interp_weights for many tensors)
    lerp_norm(x (B, T, K, D), lo, frac) -> (B, M, K)   |lerp(x)| over the last axis, without forming lerp(x)
    interpolate_time(x (B, T, ...), times, new_times) -> (B, M, ...)
    upsample_to_chirps(values (B, T, K), times (T,) | (B, T), chirp_times (F, L, C)) -> (B, K, F, L, C)
"""

from __future__ import annotations

import torch


def interp_weights(times: torch.Tensor, new_times: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Left index and fraction of each new time between its two neighbouring samples."""
    times = torch.as_tensor(times)
    new_times = torch.as_tensor(new_times, dtype=times.dtype, device=times.device)
    if times.shape[-1] < 2:
        raise ValueError(f"interpolation needs at least two time steps, found {times.shape[-1]}")
    if times.dim() == 2 and new_times.dim() == 1:
        new_times = new_times.expand(times.shape[0], -1)
    lo_t, hi_t = times[..., :1], times[..., -1:]
    t = torch.maximum(torch.minimum(new_times, hi_t), lo_t)
    hi = torch.searchsorted(times.detach().contiguous(), t.detach().contiguous(), right=True)
    hi = hi.clamp(1, times.shape[-1] - 1)
    lo = hi - 1
    t_lo = torch.gather(times, -1, lo) if times.dim() == 2 else times[lo]
    t_hi = torch.gather(times, -1, hi) if times.dim() == 2 else times[hi]
    return lo, (t - t_lo) / (t_hi - t_lo)


def lerp(x: torch.Tensor, lo: torch.Tensor, frac: torch.Tensor) -> torch.Tensor:
    """x (B, T, ...) at interpolation indices/fractions (M,) or (B, M) -> (B, M, ...)."""
    b = x.shape[0]
    tail = [1] * (x.dim() - 2)
    if lo.dim() == 1 and not frac.requires_grad and x.dim() >= 2 and not x.is_complex():
        # times shared by the batch and fixed: a sparse (M, T) interpolation matrix, two entries a row;
        # its backward is a sparse product too (3x faster than index_select's index_add backward)
        m, t = lo.shape[0], x.shape[1]
        f = frac.to(x.dtype)
        rows = torch.arange(m, device=lo.device).repeat_interleave(2)
        cols = torch.stack([lo, lo + 1], 1).flatten()  # row-major and increasing: already coalesced
        w = torch.sparse_coo_tensor(torch.stack([rows, cols]), torch.stack([1 - f, f], 1).flatten(), (m, t),
                                    check_invariants=False, is_coalesced=True)
        flat = x.transpose(0, 1).reshape(t, -1)  # (T, B * rest)
        return torch.sparse.mm(w, flat).reshape(m, b, *x.shape[2:]).transpose(0, 1)
    if lo.dim() == 1:  # shared times, differentiable fractions: plain index_select
        x_lo, x_hi = x.index_select(1, lo), x.index_select(1, lo + 1)
        return x_lo + (x_hi - x_lo) * frac.to(x.dtype).reshape(1, -1, *tail)
    idx = lo.reshape(b, -1, *tail).expand(b, lo.shape[-1], *x.shape[2:])
    x_lo, x_hi = torch.gather(x, 1, idx), torch.gather(x, 1, idx + 1)
    return x_lo + (x_hi - x_lo) * frac.to(x.dtype).reshape(b, -1, *tail)


def lerp_norm(x: torch.Tensor, lo: torch.Tensor, frac: torch.Tensor) -> torch.Tensor:
    """|lerp(x, lo, frac)| over x's last axis (a point's distance from the origin at each new time), (B, M, K).

    |p + f d|^2 = |p|^2 + f (2 p.d + f |d|^2) with p = x[lo], d = x[lo + 1] - x[lo]: three scalars per step
    interpolated instead of D coordinates, and no (B, M, K, D) temporary (3x faster than the norm of lerp's result
    for 3-vectors). The same value up to rounding; differentiable in x and frac like lerp.
    """
    p, d = x[:, :-1], x[:, 1:] - x[:, :-1]  # lo <= T - 2 (interp_weights): every step has its successor
    terms = (p.square().sum(-1), 2 * (p * d).sum(-1), d.square().sum(-1))  # (B, T - 1, K) each
    if lo.dim() == 1:
        a, b, c = (t.index_select(1, lo) for t in terms)
        f = frac.to(x.dtype)[None, :, None]
    else:
        idx = lo[..., None].expand(-1, -1, x.shape[2])
        a, b, c = (torch.gather(t, 1, idx) for t in terms)
        f = frac.to(x.dtype)[..., None]
    return (a + f * (b + f * c)).clamp_min(0).sqrt()


def interpolate_time(x: torch.Tensor, times: torch.Tensor, new_times: torch.Tensor) -> torch.Tensor:
    """Values x (B, T, ...) sampled at ``times`` -> (B, M, ...) at ``new_times`` (seconds)."""
    lo, frac = interp_weights(times, new_times)
    return lerp(x, lo, frac)


def upsample_to_chirps(values: torch.Tensor, times: torch.Tensor, chirp_times: torch.Tensor) -> torch.Tensor:
    """Per-step values (B, T, K) -> (B, K, F, L, C) at the chirp times (F, L, C), linear in time."""
    chirp_times = torch.as_tensor(chirp_times)
    up = interpolate_time(values, times, chirp_times.reshape(-1))  # (B, M, K)
    return up.transpose(1, 2).reshape(values.shape[0], values.shape[2], *chirp_times.shape)
