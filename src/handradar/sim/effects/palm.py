"""palm: the palm / back of the hand, a large flat reflector, as one disc per hand.

Centre: halfway between the wrist and the mean of the four finger MCP joints. Normal: the palm
plane's, (index MCP - wrist) x (pinky MCP - wrist); the disc is two-sided. RCS: the physical-optics
disc of handradar.sim.rcs.disc_rcs_m2 with an effective flat radius radius_m (a real palm is
curved: its specular patch is smaller than the palm). The points are unweighted (slot -1).
Differentiable in radius_m.
"""

from __future__ import annotations

import torch

from handradar.sim.effects.base import Effect, Param, register
from handradar.sim.rcs import cos_angle, disc_rcs_m2
from handradar.sim.scatterers import Scatterers

MCP = (5, 9, 13, 17)


def palm_frame(joints: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Palm centre and (unnormalised) normal, (..., 3) each, from joints (..., 21, 3)."""
    wrist = joints[..., 0, :]
    centre = 0.5 * (wrist + joints[..., list(MCP), :].mean(-2))
    normal = torch.cross(joints[..., 5, :] - wrist, joints[..., 17, :] - wrist, dim=-1)
    return centre, normal


@register
class Palm(Effect):
    name = "palm"
    stage = "scatterers"
    order = 30
    params = {"radius_m": Param(0.02, 0.003, 0.06, (0.005, 0.0075, 0.01, 0.02, 0.04), "effective flat radius of the palm disc")}

    def apply_scatterers(self, scat, ctx):
        centre, normal = palm_frame(ctx.joints)  # (B, T, 2, 3)
        rcs = disc_rcs_m2(cos_angle(centre, normal), self.value("radius_m").to(centre.dtype), ctx.radar.wavelength_m)
        gain = ctx.mask.to(centre.dtype)
        owner = torch.full((2,), -1, dtype=torch.long, device=centre.device)
        return scat.cat(Scatterers(centre, centre, rcs, gain, owner))
