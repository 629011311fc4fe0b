"""antenna_pattern: the patch antennas' gain falls off away from boresight (z).

One-way power pattern G(theta) = cos(theta)^q for theta < 90 deg from boresight and 0 behind the
board; a point's amplitude is multiplied by sqrt(G(theta_tx) G(theta_rx)) of the directions of
its outbound and inbound legs (equal for a direct path). q = 0 is the paper's isotropic model;
q ~ 4.8 gives a +-30 deg half-power beam. Differentiable in q.
"""

from __future__ import annotations

import torch

from handradar.sim.effects.base import Effect, Param, register


def pattern_amplitude(p: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """sqrt(cos(theta)^q) of directions p (..., 3) seen from the origin; 0 at or behind the board."""
    cos = p[..., 2] / p.norm(dim=-1).clamp_min(1e-9)
    return torch.where(cos > 0, cos.clamp_min(1e-12) ** (0.5 * q), torch.zeros_like(cos))


@register
class AntennaPattern(Effect):
    name = "antenna_pattern"
    stage = "scatterers"
    order = 70
    params = {"q": Param(4.0, 0.0, 12.0, (0.5, 1.0, 2.0, 4.0, 8.0), "exponent of the cos^q one-way power pattern")}

    def apply_scatterers(self, scat, ctx):
        q = self.value("q").to(scat.tx.dtype)
        return scat.scaled(pattern_amplitude(scat.tx, q) * pattern_amplitude(scat.rx, q))
