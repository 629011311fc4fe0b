"""Reflection points of the simulator: where they are, how strongly they reflect, whose weight they take.

A :class:`Scatterers` set lives at the skeleton steps (B, T, K). Each point k has an outbound and
an inbound position (``tx``, ``rx``; equal for a direct reflection, different for an image path
of the multipath effect), so that its range is the half path length ``(|tx| + |rx|) / 2``; an RCS
(m^2); a dimensionless amplitude ``gain`` (hand mask, visibility, antenna pattern, reflection
coefficients multiply in here); and an ``owner`` slot: 0..37 for the bone (hand * 19 + bone)
whose RadarWeightNet weight scales it, -1 for extra reflectors that no weight scales (palm,
forearm).

Amplitude (radar equation, bistatic form, sqrt of received power for unit transmit amplitude):

    A = lambda sqrt(Gt Gr P sigma) / ((4 pi)^1.5 R_tx R_rx)      (= ... / R^2 for a direct path)

Public API (torch, differentiable):

    bone_geometry(joints (..., 21, 3)) -> (midpoint (..., 19, 3), axis vector (..., 19, 3), length (..., 19))
    bone_scatterers(joints (B, T, 2, 21, 3), mask (B, T, 2), wavelength_m, radii (19,), rcs_exponent=1.0)
        -> Scatterers: one point per bone at its midpoint, cylinder RCS with the bone's own length
        (rcs_exponent: the aspect exponent of handradar.sim.rcs.cylinder_rcs_m2)
    radar_amplitude(rcs_m2, r_tx_m, r_rx_m, wavelength_m, tx_power_w, gain_tx_dbi, gain_rx_dbi) -> A
    Scatterers.cat(other) -> Scatterers (points appended)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from handradar.hand.skeleton import BONE_CHILD, BONE_NAMES, BONE_PARENT, N_BONES
from handradar.sim.rcs import cos_angle, cylinder_rcs_m2

N_SLOTS = 2 * N_BONES  # weighted reflection points: 19 bones x 2 hands
# the slots (hand * 19 + bone) of the four finger metacarpals of both hands: wrist-to-knuckle bones
# that a real hand buries in the palm's flesh
METACARPAL_SLOTS = tuple(h * N_BONES + b for h in (0, 1) for b, name in enumerate(BONE_NAMES) if name.endswith("metacarpal"))


@dataclass
class Scatterers:
    tx: torch.Tensor  # (B, T, K, 3) metres, radar frame
    rx: torch.Tensor  # (B, T, K, 3) metres
    rcs_m2: torch.Tensor  # (B, T, K)
    gain: torch.Tensor  # (B, T, K) dimensionless amplitude factor
    owner: torch.Tensor  # (K,) long: weight slot (0..37) or -1 (unweighted)

    @property
    def n_points(self) -> int:
        return self.owner.shape[0]

    def cat(self, other: Scatterers) -> Scatterers:
        return Scatterers(torch.cat([self.tx, other.tx], 2), torch.cat([self.rx, other.rx], 2),
                          torch.cat([self.rcs_m2, other.rcs_m2], 2), torch.cat([self.gain, other.gain], 2),
                          torch.cat([self.owner, other.owner]))

    def scaled(self, factor: torch.Tensor) -> Scatterers:
        """Amplitude gain multiplied by ``factor`` (broadcast to (B, T, K))."""
        return replace(self, gain=self.gain * factor)

    def slots_scaled(self, slots: tuple[int, ...], factor: torch.Tensor | float) -> Scatterers:
        """The points owned by ``slots`` with their amplitude gain multiplied by ``factor`` (a number
        or a 0-d tensor, differentiable), the others unchanged."""
        chosen = torch.isin(self.owner, torch.as_tensor(slots, device=self.owner.device))
        return self.scaled(torch.where(chosen, torch.as_tensor(factor, dtype=self.gain.dtype), 1.0).to(self.gain.dtype))


def bone_geometry(joints: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Midpoint, axis vector (parent -> child, not normalised) and length of each bone, metres."""
    parent = torch.as_tensor(BONE_PARENT, device=joints.device)
    child = torch.as_tensor(BONE_CHILD, device=joints.device)
    a, b = joints[..., parent, :], joints[..., child, :]
    axis = b - a
    length = torch.sqrt((axis * axis).sum(-1).clamp_min(1e-18))
    return 0.5 * (a + b), axis, length


def bone_rcs_m2(midpoint: torch.Tensor, axis: torch.Tensor, length: torch.Tensor, radii: torch.Tensor,
                wavelength_m: float, exponent: float = 1.0) -> torch.Tensor:
    """Cylinder RCS of each bone seen from the radar at the origin (line of sight = midpoint)."""
    return cylinder_rcs_m2(cos_angle(midpoint, axis), radii, length, wavelength_m, exponent)


def bone_scatterers(joints: torch.Tensor, mask: torch.Tensor, wavelength_m: float,
                    radii: torch.Tensor, rcs_exponent: float = 1.0) -> Scatterers:
    """One scattering centre per bone (bone midpoint), slots hand * 19 + bone; untracked: gain 0."""
    b, t = joints.shape[:2]
    mid, axis, length = bone_geometry(joints)  # (B, T, 2, 19, ...)
    rcs = bone_rcs_m2(mid, axis, length, radii.to(joints.dtype), wavelength_m, rcs_exponent).reshape(b, t, N_SLOTS)
    gain = mask.to(joints.dtype)[..., None].expand(b, t, 2, N_BONES).reshape(b, t, N_SLOTS)
    pos = mid.reshape(b, t, N_SLOTS, 3)
    return Scatterers(pos, pos, rcs, gain, torch.arange(N_SLOTS, device=joints.device))


def radar_amplitude(rcs_m2: torch.Tensor, r_tx_m: torch.Tensor, r_rx_m: torch.Tensor, wavelength_m: float,
                    tx_power_w: float, gain_tx_dbi: float, gain_rx_dbi: float) -> torch.Tensor:
    """Received amplitude sqrt(P_r) of a point of RCS sigma at (bistatic) ranges R_tx, R_rx."""
    g = 10.0 ** ((gain_tx_dbi + gain_rx_dbi) / 10.0)
    c = wavelength_m * math.sqrt(g * tx_power_w) / (4.0 * math.pi) ** 1.5
    return c * torch.sqrt(rcs_m2.clamp_min(0.0) + 1e-30) / (r_tx_m * r_rx_m).clamp_min(1e-6)
