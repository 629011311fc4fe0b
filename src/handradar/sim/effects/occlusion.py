"""occlusion: parts hidden behind other parts of the hand(s) reflect less.

The RCS of bone k is scaled by its un-occluded fraction f = visible / facing mesh vertices
(handradar.hand.visibility; 1 in full view, 0 hidden), i.e. its amplitude by
sqrt(t + (1 - t) f), where t is the power a hidden part still returns (diffraction, creeping
waves, a partly transparent shadow). t = 1 is the paper's model. Differentiable in t.

f comes from the simulation context (the feature cache's ``visible_fraction``) or, when absent,
is ray cast here from the simulator's own (retargeted) joints.
"""

from __future__ import annotations

import numpy as np
import torch

from handradar.hand.mesh import default_template
from handradar.hand.visibility import visibility as ray_cast_visibility
from handradar.sim.effects.base import Effect, Param, register
from handradar.sim.scatterers import N_SLOTS


def visible_fraction(joints: torch.Tensor, mask: torch.Tensor, hand) -> torch.Tensor:
    """(B, T, 2, 19) visible / facing fraction by ray casting each example (numpy, no gradient)."""
    j = joints.detach().cpu().numpy().astype(np.float64)
    m = mask.detach().cpu().numpy()
    out = np.stack([ray_cast_visibility(j[i], m[i], template=default_template(hand.sections, hand.rings),
                                        backend=hand.backend, stride=hand.visibility_stride).fraction()
                    for i in range(j.shape[0])])
    return torch.as_tensor(out, dtype=joints.dtype, device=joints.device)


@register
class Occlusion(Effect):
    name = "occlusion"
    stage = "scatterers"
    order = 50
    params = {"transmission": Param(0.0, 0.0, 1.0, (0.0, 0.1, 0.3, 0.6),
                                    "fraction of its power a fully hidden bone still returns")}

    def apply_scatterers(self, scat, ctx):
        frac = ctx.visibility if ctx.visibility is not None else visible_fraction(ctx.joints, ctx.mask, ctx.hand)
        b, t = frac.shape[:2]
        tr = self.value("transmission").to(frac.dtype)
        power = tr + (1.0 - tr) * frac.reshape(b, t, N_SLOTS)
        hidden = power <= 0
        amp = torch.where(hidden, torch.zeros_like(power), torch.sqrt(torch.where(hidden, torch.ones_like(power), power)))
        factor = torch.ones_like(scat.gain)
        bone = (scat.owner >= 0) & (scat.owner < N_SLOTS)
        # every point owned by bone k takes bone k's factor (multipath, later, bounces off the shadowed gains)
        factor[..., bone] = amp[..., scat.owner[bone]]
        return scat.scaled(factor)
