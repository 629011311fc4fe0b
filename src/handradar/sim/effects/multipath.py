"""multipath: double bounces off a table plane below the radar plane, by the image method.

The table is the plane z = -height_m of the radar frame (the radar lies on it looking up). Every
reflection point p (bones, palm, forearm) has the mirror image p' = p - 2 (p_z + height) e_z, and
two extra paths with the same owner slot (so a RadarWeightNet weight scales a bone's echoes
together):

- one bounce, radar -> p -> table -> radar and its reverse: equal lengths, so one point with
  tx = p, rx = p' and amplitude factor 2 Gamma;
- two bounces, radar -> table -> p -> table -> radar: tx = rx = p', factor Gamma^2.

The RCS of an image path is taken as the monostatic one of p (bistatic RCS is not modelled);
the antenna_pattern effect, if selected after this one, suppresses paths arriving from below the
board. Hand-hand double bounces are not modelled. Differentiable in both parameters.

The fitting grid covers a radar lying on the table (the paper's set-up): the antenna 0.5-3 cm above
the plane. A raised radar needs its own grid (``diagnose.grids.multipath.height_m``). Heights of
5-15 cm put the one-bounce images one or more range bins behind the hand with a Doppler scaled
toward zero, a generic "slower copy" that closes part of any simulator-vs-measurement gap (the gap
benchmark found it winning in worlds with no multipath at all), so they are not tried by default.
"""

from __future__ import annotations

import torch

from handradar.sim.effects.base import Effect, Param, register
from handradar.sim.scatterers import Scatterers


@register
class Multipath(Effect):
    name = "multipath"
    stage = "scatterers"
    order = 60
    params = {"height_m": Param(0.02, 0.0, 0.5, (0.005, 0.01, 0.02, 0.03), "radar height above the table plane"),
              "reflection_coeff": Param(0.3, 0.0, 1.0, (0.2, 0.5), "table amplitude reflection coefficient")}

    def apply_scatterers(self, scat, ctx):
        h = self.value("height_m").to(scat.tx.dtype)
        gamma = self.value("reflection_coeff").to(scat.tx.dtype)

        def mirror(p: torch.Tensor) -> torch.Tensor:
            z = p[..., 2:]
            return torch.cat([p[..., :2], -z - 2.0 * h], dim=-1)

        one = Scatterers(scat.tx, mirror(scat.rx), scat.rcs_m2, scat.gain * (2.0 * gamma), scat.owner)
        two = Scatterers(mirror(scat.tx), mirror(scat.rx), scat.rcs_m2, scat.gain * gamma**2, scat.owner)
        return scat.cat(one).cat(two)
