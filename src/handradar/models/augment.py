"""Label-keeping augmentations of Doppler-time images (B, 1, doppler, time) in [0, 1], 0 the floor.

Small pure functions that take their parameters, one value per image, and :class:`SpectrogramAugment`, the configured
chain of them that a training recipe applies to every training batch (conf/recipe/): it draws the parameters from
torch's global generator, which handradar.training.StepSeed reseeds before every training step, so a fit stays a
function of its seed.

None mirrors the Doppler axis: that turns approaching into receding, which changes the class of a push or a swipe.
What each one stands for is in docs/configuration.md#training-recipes.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F


def shift_time(x: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """Image i moved by ``shift[i]`` whole columns (positive: later); the columns that enter are floor (0)."""
    t = x.shape[-1]
    src = torch.arange(t, device=x.device)[None, :] - shift[:, None]  # (B, T): the column each one takes
    inside = (src >= 0) & (src < t)
    out = torch.gather(x, -1, src.clamp(0, t - 1)[:, None, None, :].expand_as(x))
    return out * inside[:, None, None, :].to(x.dtype)


def stretch_time(x: torch.Tensor, factor: torch.Tensor) -> torch.Tensor:
    """Image i resampled in time by ``factor[i]`` about its centre (> 1: slower, longer): output column u is the
    linear interpolation of the input at column ``c + (u - c) / factor`` (c the centre), the floor (0) beyond the
    image; each Doppler row on its own."""
    t = x.shape[-1]
    c = (t - 1) / 2.0
    src = c + (torch.arange(t, device=x.device, dtype=x.dtype)[None, :] - c) / factor[:, None].to(x.dtype)  # (B, T)
    left = torch.floor(src)
    w = (src - left)[:, None, None, :]
    padded = F.pad(x, (1, 1))  # column j of x is column j + 1 here, a floor column either side

    def at(col: torch.Tensor) -> torch.Tensor:
        idx = (col.long() + 1).clamp(0, t + 1)[:, None, None, :].expand(*x.shape[:-1], t)
        return torch.gather(padded, -1, idx)

    return (1.0 - w) * at(left) + w * at(left + 1)


def scale_level(x: torch.Tensor, gain: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """``clip(gain[i] x + offset[i], 0, 1)``: on a dB image scaled to its peak, another dynamic range and floor."""
    return (gain[:, None, None, None] * x + offset[:, None, None, None]).clamp(0.0, 1.0)


def mask_band(x: torch.Tensor, start: torch.Tensor, width: torch.Tensor, axis: int) -> torch.Tensor:
    """Rows (``axis`` -2, Doppler) or columns (-1, time) ``start[i]`` to ``start[i] + width[i] - 1`` of image i set to
    the floor (SpecAugment's masks)."""
    size = x.shape[axis]
    idx = torch.arange(size, device=x.device)[None, :]
    keep = ~((idx >= start[:, None]) & (idx < (start + width)[:, None]))  # (B, size)
    shape = [x.shape[0], 1, 1, 1]
    shape[axis] = size
    return x * keep.view(shape).to(x.dtype)


class SpectrogramAugment(nn.Module):
    """The recipe's augmentations of a training batch, in order, each drawn per image: a time shift of up to
    ``shift`` columns either way, a time stretch by 1 -/+ ``stretch``, a level gain of 1 -/+ ``gain`` and offset of
    -/+ ``floor`` (units of the image's [0, 1] range), a band of up to ``time_mask`` columns and one of up to
    ``doppler_mask`` rows set to the floor. Each step applies to a batch with probability ``p``; 0 turns one off."""

    def __init__(self, *, shift: int = 0, stretch: float = 0.0, gain: float = 0.0, floor: float = 0.0,
                 time_mask: int = 0, doppler_mask: int = 0, p: float = 1.0) -> None:
        super().__init__()
        self.shift, self.stretch, self.gain, self.floor = int(shift), float(stretch), float(gain), float(floor)
        self.time_mask, self.doppler_mask, self.p = int(time_mask), int(doppler_mask), float(p)

    def _band(self, x: torch.Tensor, max_width: int, axis: int) -> torch.Tensor:
        n, size = x.shape[0], x.shape[axis]
        width = torch.randint(0, max_width + 1, (n,), device=x.device)
        start = (torch.rand(n, device=x.device) * (size - width + 1).to(torch.float32)).long()
        return mask_band(x, start, width, axis)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, dev = x.shape[0], x.device

        def uniform(lo: float, hi: float) -> torch.Tensor:
            return lo + (hi - lo) * torch.rand(n, device=dev)

        steps = [
            (self.shift > 0, lambda v: shift_time(v, torch.randint(-self.shift, self.shift + 1, (n,), device=dev))),
            (self.stretch > 0, lambda v: stretch_time(v, uniform(1.0 - self.stretch, 1.0 + self.stretch))),
            (self.gain > 0 or self.floor > 0,
             lambda v: scale_level(v, uniform(1.0 - self.gain, 1.0 + self.gain), uniform(-self.floor, self.floor))),
            (self.time_mask > 0, lambda v: self._band(v, self.time_mask, -1)),
            (self.doppler_mask > 0, lambda v: self._band(v, self.doppler_mask, -2)),
        ]
        for on, step in steps:
            if on and (self.p >= 1.0 or float(torch.rand(())) < self.p):
                x = step(x)
        return x
