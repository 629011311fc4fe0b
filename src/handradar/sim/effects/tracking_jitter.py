"""tracking_jitter: temporal Gaussian smoothing of the skeleton, undoing the tracker's jitter.

A tracked joint x(t) is replaced by sum_s g(t - s) m(s) x(s) / sum_s g(t - s) m(s) with
g(dt) = exp(-dt^2 / (2 sigma^2)) over +-3 sigma and m the hand mask (untracked steps take no part;
the edges use the available steps only). sigma -> 0 returns the input. Differentiable in sigma_s.
"""

from __future__ import annotations

import torch

from handradar.sim.effects.base import Effect, Param, register


@register
class TrackingJitter(Effect):
    name = "tracking_jitter"
    stage = "skeleton"
    order = 10
    params = {"sigma_s": Param(0.01, 0.0, 0.1, (0.005, 0.01, 0.02, 0.04),
                               "std of the Gaussian smoothing kernel, seconds")}

    def apply_skeleton(self, positions, mask, times):
        sigma = self.value("sigma_s")
        t = times if times.dim() == 1 else times[0]
        dt = float((t[-1] - t[0]) / (t.shape[0] - 1))
        sigma_f = float(sigma.detach())
        half = min(int(3.0 * sigma_f / dt) + 1, positions.shape[1] - 1)
        if sigma_f < 1e-4 or half < 1:
            return positions, mask, times
        offs = torch.arange(-half, half + 1, device=positions.device, dtype=positions.dtype) * dt
        kernel = torch.exp(-0.5 * (offs / sigma.to(positions.dtype)) ** 2)  # (W,)
        b, n = positions.shape[:2]
        m = mask.to(positions.dtype)  # (B, T, 2)
        x = (positions * m[..., None, None]).permute(0, 2, 3, 4, 1).reshape(-1, 1, n)  # (B*2*21*3, 1, T)
        w = m.permute(0, 2, 1).reshape(-1, 1, n)  # (B*2, 1, T)
        k = kernel.flip(0).reshape(1, 1, -1)
        num = torch.nn.functional.conv1d(x, k, padding=half).reshape(b, 2, 21, 3, n)
        den = torch.nn.functional.conv1d(w, k, padding=half).reshape(b, 2, 1, 1, n)
        smooth = (num / den.clamp_min(1e-12)).permute(0, 4, 1, 2, 3)
        return torch.where(mask[..., None, None], smooth, positions), mask, times
