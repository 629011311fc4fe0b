"""forearm: the arm that moves with the hand, as a cylinder from the wrist to the elbow (and on to the shoulder).

Where the source gives the arm (``SimContext.arm``: the motion library's elbow and shoulder at every
step), the forearm runs from the wrist to that elbow and the upper arm, a second cylinder of the same
radius, from the elbow to the shoulder: a swing about the elbow gives forearm Doppler from zero at the
pivot to the wrist's, and a moving elbow gives the upper arm's. ``length_m`` is then unused.

Otherwise the elbow is not tracked; it is taken as fixed over the window (during a hand gesture the forearm
pivots about the elbow, which moves far less than the hand): at the mean over the tracked steps
of wrist + length_m * u, u the unit vector from the middle MCP to the wrist (away from the
fingers). The cylinder from the moving wrist to that elbow, of radius_m, is cut into
``n_segments`` pieces, each one scattering centre at its midpoint with the finite-cylinder RCS of
its own length (handradar.sim.rcs.cylinder_rcs_m2), so a long forearm spans range bins and its
Doppler runs from the wrist's velocity down to zero at the elbow. Unweighted points (slot -1).
Differentiable in both parameters.

(Earlier versions held the forearm rigidly along the hand's axis, so it swung with every wrist
flexion and its points moved like the palm; the gap benchmark could not tell it from other
reflectors near the hand, see docs/gap_report.md.)
"""

from __future__ import annotations

import torch

from handradar.sim.effects.base import Effect, Param, register
from handradar.sim.rcs import cos_angle, cylinder_rcs_m2
from handradar.sim.scatterers import Scatterers


def fixed_elbow(joints: torch.Tensor, mask: torch.Tensor, length_m: torch.Tensor) -> torch.Tensor:
    """Elbow (B, T, 2, 3) fixed over the window: mean over tracked steps of wrist + length * u."""
    wrist = joints[..., 0, :]
    axis = wrist - joints[..., 9, :]
    unit = axis / axis.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    m = mask.to(wrist.dtype)[..., None]  # (B, T, 2, 1)
    elbow = ((wrist + length_m * unit) * m).sum(1) / m.sum(1).clamp_min(1.0)  # (B, 2, 3)
    return elbow[:, None].expand_as(wrist)


@register
class Forearm(Effect):
    name = "forearm"
    stage = "scatterers"
    order = 40
    params = {"length_m": Param(0.15, 0.02, 0.3, (0.05, 0.1, 0.2, 0.3), "forearm length seen by the radar"),
              "radius_m": Param(0.03, 0.015, 0.05, (0.02, 0.03, 0.04), "forearm radius")}

    def __init__(self, n_segments: int = 4, **values: float) -> None:
        super().__init__(**values)
        self.n_segments = int(n_segments)

    def settings(self) -> dict[str, int]:
        return {"n_segments": self.n_segments}

    def apply_scatterers(self, scat, ctx):
        wrist = ctx.joints[..., 0, :]
        if ctx.arm is None:
            elbow = fixed_elbow(ctx.joints, ctx.mask, self.value("length_m").to(wrist.dtype))
            return scat.cat(self._cylinder(wrist, elbow, ctx))
        elbow, shoulder = ctx.arm[..., 0, :], ctx.arm[..., 1, :]
        return scat.cat(self._cylinder(wrist, elbow, ctx)).cat(self._cylinder(elbow, shoulder, ctx))

    def _cylinder(self, start: torch.Tensor, end: torch.Tensor, ctx) -> Scatterers:
        """``n_segments`` points per hand on a cylinder from ``start`` to ``end`` (B, T, 2, 3), unweighted."""
        axis = end - start
        k = (torch.arange(self.n_segments, device=start.device, dtype=start.dtype) + 0.5) / self.n_segments
        pos = start[..., None, :] + k[:, None] * axis[..., None, :]  # (B, T, 2, S, 3)
        seg = (axis.norm(dim=-1) / self.n_segments)[..., None]
        rcs = cylinder_rcs_m2(cos_angle(pos, axis[..., None, :].expand_as(pos)), self.value("radius_m").to(start.dtype),
                              seg, ctx.radar.wavelength_m, ctx.rcs_exponent)
        b, t = start.shape[:2]
        n = 2 * self.n_segments
        gain = ctx.mask.to(start.dtype)[..., None].expand(b, t, 2, self.n_segments).reshape(b, t, n)
        pos = pos.reshape(b, t, n, 3)
        owner = torch.full((n,), -1, dtype=torch.long, device=start.device)
        return Scatterers(pos, pos, rcs.reshape(b, t, n), gain, owner)
