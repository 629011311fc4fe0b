"""forearm: the wrist and forearm that move with the hand, as a cylinder behind the wrist.

Axis: from the wrist away from the fingers, along wrist - middle MCP. The cylinder of length_m
and radius_m is cut into ``n_segments`` pieces, each one scattering centre at its midpoint with
the finite-cylinder RCS of its own length (handradar.sim.rcs.cylinder_rcs_m2), so a long forearm
spans range bins. Unweighted points (slot -1). Differentiable in both parameters.
"""

from __future__ import annotations

import torch

from handradar.sim.effects.base import Effect, Param, register
from handradar.sim.rcs import cos_angle, cylinder_rcs_m2
from handradar.sim.scatterers import Scatterers


@register
class Forearm(Effect):
    name = "forearm"
    stage = "scatterers"
    order = 40
    params = {"length_m": Param(0.15, 0.02, 0.3, (0.05, 0.1, 0.2), "forearm length seen by the radar"),
              "radius_m": Param(0.03, 0.015, 0.05, (0.025, 0.04), "forearm radius")}

    def __init__(self, n_segments: int = 4, **values: float) -> None:
        super().__init__(**values)
        self.n_segments = int(n_segments)

    def apply_scatterers(self, scat, ctx):
        wrist = ctx.joints[..., 0, :]
        axis = wrist - ctx.joints[..., 9, :]
        unit = axis / axis.norm(dim=-1, keepdim=True).clamp_min(1e-9)  # (B, T, 2, 3)
        length = self.value("length_m").to(wrist.dtype)
        seg = length / self.n_segments
        k = (torch.arange(self.n_segments, device=wrist.device, dtype=wrist.dtype) + 0.5) * seg
        pos = wrist[..., None, :] + k[:, None] * unit[..., None, :]  # (B, T, 2, S, 3)
        rcs = cylinder_rcs_m2(cos_angle(pos, unit[..., None, :].expand_as(pos)), self.value("radius_m").to(wrist.dtype),
                              seg, ctx.radar.wavelength_m)
        b, t = wrist.shape[:2]
        n = 2 * self.n_segments
        gain = ctx.mask.to(wrist.dtype)[..., None].expand(b, t, 2, self.n_segments).reshape(b, t, n)
        pos = pos.reshape(b, t, n, 3)
        owner = torch.full((n,), -1, dtype=torch.long, device=wrist.device)
        return scat.cat(Scatterers(pos, pos, rcs.reshape(b, t, n), gain, owner))
