"""Candidate effects tried on the truth side and not landed (benchmarks/candidate_scan.py).

Registered on import, outside the vocabulary (handradar.vocab.EFFECTS): no diagnosis scores them
unless a probe asks for them by name. Each records why it stays here (README, "How visible each
effect is").

palm_lobe: the palm as one point at the palm centre (handradar.sim.effects.palm.palm_frame) whose
strength and lobe width are separate parameters, sigma = rcs0_m2 |cos theta|^m (theta from the palm
normal, two-sided: palm and back of the hand), instead of the disc's, which ties both to one radius
(a smooth disc of radius a is m ~ (k a)^2 / 2 + 2 at rcs0 = 4 pi (pi a^2)^2 / lambda^2; a rough
surface m ~ 1). ``bury`` removes that share of the four finger metacarpals' amplitude, as a slab
that buries them would. Not landed: it closes +0.064 of the tuning world's palm gap and hurts on
both held-out worlds.
"""

from __future__ import annotations

import torch

from handradar.sim.effects.base import Effect, Param, register
from handradar.sim.effects.palm import palm_frame
from handradar.sim.rcs import cos_angle
from handradar.sim.scatterers import METACARPAL_SLOTS, Scatterers


@register
class PalmLobe(Effect):
    name = "palm_lobe"
    stage = "scatterers"
    order = 30
    params = {"rcs0_m2": Param(0.03, 0.0, 10.0, (0.01, 0.03, 0.1, 0.3), "RCS at normal incidence, m^2"),
              "m": Param(1.0, 0.0, 64.0, (1.0, 2.0, 4.0), "lobe exponent (0: isotropic)"),
              "bury": Param(0.0, 0.0, 1.0, (0.0,), "share of the metacarpals' amplitude removed")}

    def apply_scatterers(self, scat, ctx):
        centre, normal = palm_frame(ctx.joints)  # (B, T, 2, 3)
        c = cos_angle(centre, normal).abs().clamp_min(1e-6)
        rcs = self.value("rcs0_m2").to(centre.dtype) * c ** self.value("m").to(centre.dtype)
        owner = torch.full((2,), -1, dtype=torch.long, device=centre.device)
        return (scat.slots_scaled(METACARPAL_SLOTS, 1.0 - self.value("bury"))
                .cat(Scatterers(centre, centre, rcs, ctx.mask.to(centre.dtype), owner)))
