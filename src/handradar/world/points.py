"""Discrete bone scatterers: the direct returns of ``world.scene.scattering: bone_points``.

A reference world whose scattering is built differently in kind from the surfaces world
(handradar.world.scattering: physical optics over smooth surfaces plus a skin texture) and from the
simulator (handradar.sim: one cylinder per bone with the paper's cylinder RCS): every part of the
hands carries a fixed set of point scatterers, each with an RCS law of its own, and the hand's
return is their coherent sum. Nothing is integrated over a surface, so there is no specular flash
of a cylinder's broadside nor a plate lobe of the palm; the points' returns fluctuate from point to
point instead (Swerling I) and interfere along each bone.

Placement, per recording, on the parts of :func:`handradar.world.geometry.build_parts` (so the palm,
forearm and occlusion effects keep their meaning). On every cone (finger bone, fingertip cap,
forearm) a grid at its cells' centres, ``n_around`` azimuths by ``n_along`` rings,

    n_around = max(MIN_AROUND, ceil(2 pi r_max / s)),   n_along = max(1, ceil(slant / s)),

s = ``scene.points.spacing_m`` (8 mm, about two wavelengths at 77 GHz), the grid turned about the
axis by a random fraction of a cell. On every flat face of the palm slab (back, palm, rim), a square
grid of pitch s at a random offset (its centroid when none of the grid falls inside). Each point's
normal is the surface's outward normal there, dA_i (m^2) the area of its cell.

RCS law (m^2), monostatic, theta_i the angle between the point's outward normal and the direction
to the radar:

    sigma_i = g_i dA_i (rho cos(theta_i)^q + rho_iso)   where cos(theta_i) > 0, else 0,

rho = ``points.rcs_per_area`` and rho_iso = ``points.isotropic`` (m^2 per m^2 of skin), q =
``points.exponent``; g_i ~ Exponential(mean 1) and a phase phi_i ~ U(0, 2 pi) drawn once per
recording, so each point's complex amplitude is circular Gaussian (Swerling I: constant over a
recording, independent between points and recordings). Bistatic (double bounces, handradar.world.
scattering.bounce_paths): theta from the half-vector of the two directions, zero unless both lie in front.

Amplitude in ADC counts, the radar equation of the surfaces world (scattering.amplitude_scale K, the
antenna's power gain G when the antenna_pattern effect is on):

    A_i = K sqrt(sigma_i) G / R_i^2 vis_i exp(j phi_i)   at range R_i (the renderer adds the carrier),

vis_i the ray-cast visibility (handradar.world.scene.point_tracks).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from handradar.world.config import Scene

MIN_AROUND = 4  # azimuths on the thinnest cone: one point per quarter turn at least


@dataclass
class PointSet:
    """Point scatterers of one recording: positions and outward unit normals (T, N, 3) in the radar
    frame (metres), the area dA each stands for (N,) m^2, its Swerling gain g (N,), its phase (N,)
    rad, its hand slot (N,), the index of its part (N,) and a ``slot:part`` label (N,)."""

    points: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    gain: np.ndarray
    phase: np.ndarray
    slot: np.ndarray
    part: np.ndarray
    label: np.ndarray

    def take(self, idx: np.ndarray) -> PointSet:
        return PointSet(self.points[:, idx], self.normals[:, idx], self.area[idx], self.gain[idx], self.phase[idx],
                        self.slot[idx], self.part[idx], self.label[idx])


def cone_grid(cone: Any, spacing_m: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell centres (phi, w) (N,) of the grid on a cone (handradar.world.geometry.Cone) and each cell's
    area (N,) m^2 (at the first step); the grid is turned by a random fraction of one azimuth cell."""
    slant = math.hypot(float(cone.l1[0] - cone.l0[0]), cone.r1 - cone.r0)
    n_around = max(MIN_AROUND, math.ceil(2 * math.pi * max(cone.r0, cone.r1) / spacing_m))
    n_along = max(1, math.ceil(slant / spacing_m))
    turn = rng.random()
    j, i = np.meshgrid(np.arange(n_around), np.arange(n_along))
    phi0 = 2 * np.pi * (j.ravel() + turn) / n_around
    w0 = i.ravel() / n_along
    area = cone.patch_area(phi0, phi0 + 2 * np.pi / n_around, w0, w0 + 1.0 / n_along, slice(0, 1))[0]
    return phi0 + np.pi / n_around, w0 + 0.5 / n_along, area


def face_grid(poly: np.ndarray, spacing_m: float, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Points (N, 3) of a square grid of pitch ``spacing_m`` at a random offset inside a flat convex
    polygon (n, 3), and the area (m^2) each stands for (the polygon's area / N)."""
    c = poly.mean(0)
    e1 = (poly[1] - poly[0]) / np.linalg.norm(poly[1] - poly[0])
    normal = np.cross(poly[1] - poly[0], poly[2] - poly[0])
    normal /= np.linalg.norm(normal)
    e2 = np.cross(normal, e1)
    xy = np.stack([(poly - c) @ e1, (poly - c) @ e2], 1)
    lo, hi = xy.min(0), xy.max(0)
    off = rng.random(2) * spacing_m
    gx, gy = (np.arange(a + o, b, spacing_m) for a, b, o in zip(lo, hi, off))
    g = np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2)
    edge = np.roll(xy, -1, 0) - xy
    cross = edge[:, 0] * (g[:, None, 1] - xy[:, 1]) - edge[:, 1] * (g[:, None, 0] - xy[:, 0])  # (N, n)
    inside = (cross >= 0).all(1) | (cross <= 0).all(1)  # on one side of every edge (either winding)
    g = g[inside] if inside.any() else np.zeros((1, 2))
    poly_area = 0.5 * abs(float(np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])))
    return c + g[:, :1] * e1 + g[:, 1:] * e2, poly_area / len(g)


def face_normals(poly: np.ndarray, inside: np.ndarray, rotation: np.ndarray, n: int) -> np.ndarray:
    """(T, n, 3): the unit normal of a slab face ``poly`` (hand-local, pointing away from the point
    ``inside``), turned by the part's ``rotation`` (T, 3, 3) at every step, for its ``n`` points."""
    n_loc = np.cross(poly[1] - poly[0], poly[2] - poly[0])
    n_loc = n_loc / np.linalg.norm(n_loc)
    if n_loc @ (poly.mean(0) - inside) < 0:
        n_loc = -n_loc
    return np.broadcast_to(np.einsum("tij,j->ti", rotation, n_loc)[:, None, :], (len(rotation), n, 3))


def bone_points(parts: Sequence[Any], spacing_m: float, rng: np.random.Generator) -> PointSet:
    """The point scatterers of every part (handradar.world.geometry.Part) at every step: cones' grids,
    the palm slab's face grids; the Swerling gains and phases drawn last."""
    pts, nrm, area, slot, owner, label = [], [], [], [], [], []
    for ip, p in enumerate(parts):
        n_before = sum(len(a) for a in area)
        for cone in p.cones:
            phi, w, a = cone_grid(cone, spacing_m, rng)
            x, n = cone.surface(phi, w)
            pts.append(x)
            nrm.append(n)
            area.append(a)
        if p.slab_faces:
            centre = np.r_[p.slab_faces[0][:, :2].mean(0), 0.0]  # inside the convex slab
            for poly in p.slab_faces:
                local, a = face_grid(poly, spacing_m, rng)
                pts.append(p.to_radar(local))
                nrm.append(face_normals(poly, centre, p.rotation, len(local)))
                area.append(np.full(len(local), a))
        n = sum(len(a) for a in area) - n_before
        slot.append(np.full(n, p.slot))
        owner.append(np.full(n, ip))
        label += [f"{p.slot}:{p.name}"] * n
    total = sum(len(a) for a in area)
    gain = rng.exponential(1.0, total)
    phase = rng.uniform(0, 2 * np.pi, total)
    return PointSet(np.concatenate(pts, 1), np.concatenate(nrm, 1), np.concatenate(area), gain, phase,
                    np.concatenate(slot), np.concatenate(owner), np.asarray(label, dtype=str))


def point_rcs(normal: np.ndarray, area: np.ndarray, u_in: np.ndarray, u_out: np.ndarray, scene: Scene) -> np.ndarray:
    """RCS (m^2) of points with outward ``normal`` (..., 3) standing for ``area`` (...) m^2 (the
    Swerling gain included) for incoming-from ``u_in`` and outgoing-to ``u_out`` unit directions:
    area (rho cos_h^q + rho_iso), cos_h from the half-vector, zero unless both directions are in front.
    The same signature as handradar.world.scattering.facet_rcs (the surfaces' law) for bounce_paths."""
    law = scene.points
    c_in = (normal * u_in).sum(-1)
    c_out = (normal * u_out).sum(-1)
    h = u_in + u_out
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
    c_h = np.clip((normal * h).sum(-1), 0.0, None)
    front = (c_in > 0) & (c_out > 0)
    return np.where(front, area * (law.rcs_per_area * c_h ** law.exponent + law.isotropic), 0.0)
