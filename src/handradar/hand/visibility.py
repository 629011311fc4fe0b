"""Per-bone visible-vertex counts seen from the radar (the origin of the radar frame).

A mesh vertex is *visible* when the segment from it to the radar crosses no triangle of the
scene: all cylinders of every tracked hand, so a hand shadows itself and the other hand. A
vertex is *facing* when at least one of its triangles faces the radar and it is not *buried*
inside another cylinder; for a closed convex cylinder exactly the facing vertices are visible when
nothing else is in the way, so ``visible / facing`` is the un-occluded fraction of a bone (1 = in
full view, 0 = hidden). Buried vertices are left out of both counts because neighbouring cylinders
of the mesh overlap (the four metacarpals of a flat hand, a phalanx where it meets the next): that
overlap is an artefact of modelling a hand as separate cylinders, not a part hiding another, and
counting it as shadow left a flat hand's metacarpals only 27-65 % visible.
Only facing vertices are ray cast (the others are hidden by their own cylinder), against the
cylinders' occluder triangles (mesh.CylinderTemplate.occluder_faces: the same surface without the
intermediate rings, 10x fewer triangles).

Ray casting backends:

- ``"embree"``: trimesh's Embree intersector (``trimesh.ray.ray_pyembree``, package embreex), the
  default; single-precision BVH, ~1e-7 relative precision, far below the 1e-5 m ray offset.
- ``"triangle"``: trimesh's pure-Python/numpy intersector (``trimesh.ray.ray_triangle``, rtree
  broad phase, exact Moller-Trumbore tests). The fallback where embreex is not installed; same
  answers, about 10-100x slower.
- ``"auto"``: embree when importable, else triangle.

Public API:

    visibility(joints (T, 2, 21, 3), mask (T, 2), *, radii=None, template=None, backend="auto",
               stride=1) -> Visibility(visible (T, 2, 19) int32, facing (T, 2, 19) int32)
        joints in radar-frame metres (already retargeted if wanted); untracked hands count 0.
        stride > 1 casts every stride-th step (and the last) and interpolates the counts linearly
        in between (rounded): a speed/accuracy trade, visibility changes slowly. A cast step where
        a hand is untracked contributes 0 to its neighbours' interpolation.
    visibility_step(joints (H, 21, 3), ...) -> (visible (H, 19), facing (H, 19)) for one step
    Visibility.fraction() -> (T, 2, 19) float32 visible / facing (0 where nothing faces)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from handradar.hand.mesh import (
    CylinderTemplate,
    bone_frames,
    bone_radii,
    bone_vertices,
    default_template,
)
from handradar.hand.skeleton import N_BONES

RAY_OFFSET_M = 1e-5  # start rays this far from the vertex, off its own surface


def embree_available() -> bool:
    try:
        import embreex  # noqa: F401
        from trimesh.ray import ray_pyembree  # noqa: F401
    except ImportError:
        return False
    return True


def _intersector(mesh: trimesh.Trimesh, backend: str):
    if backend == "auto":
        backend = "embree" if embree_available() else "triangle"
    if backend == "embree":
        from trimesh.ray.ray_pyembree import RayMeshIntersector
        return RayMeshIntersector(mesh), False
    if backend == "triangle":
        from trimesh.ray.ray_triangle import RayMeshIntersector
        return RayMeshIntersector(mesh), True
    raise ValueError(f"unknown ray-casting backend {backend!r}; expected 'auto', 'embree' or 'triangle'")


@dataclass
class Visibility:
    visible: np.ndarray  # (T, 2, 19) int32 vertices with a clear line to the radar
    facing: np.ndarray  # (T, 2, 19) int32 vertices with a triangle facing the radar

    def fraction(self) -> np.ndarray:
        """visible / facing, (T, 2, 19) float32 in [0, 1]; 0 where no vertex faces the radar."""
        return np.divide(self.visible, self.facing, out=np.zeros(self.visible.shape, np.float32),
                         where=self.facing > 0).astype(np.float32)


def _facing(verts: np.ndarray, template: CylinderTemplate) -> np.ndarray:
    """(C, V) bool: the vertex lies on at least one surface triangle whose outward normal points to
    the origin (evaluated on the occluder triangles, which carry the same planes as the fine mesh)."""
    tri = verts[:, template.occluder_faces]  # (C, F, 3, 3)
    normal = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
    toward = -(normal * tri[:, :, 0]).sum(-1) > 0  # (C, F): n . (origin - p) > 0 (degenerate: False)
    vf = template.vertex_occluder_faces
    return np.where(vf >= 0, toward[:, np.clip(vf, 0, None)], False).any(-1)


def _buried(verts: np.ndarray, start: np.ndarray, axis: np.ndarray, length: np.ndarray,
            radius: np.ndarray) -> np.ndarray:
    """(C, V) bool: the vertices ``verts`` (C, V, 3) of each of C cylinders that lie strictly inside
    another one; cylinders given by start (C, 3), unit axis (C, 3), length and radius (C,), metres.
    Only pairs whose bounding spheres meet are tested (a bone has a handful of neighbours)."""
    centre = start + 0.5 * length[:, None] * axis
    reach = np.hypot(0.5 * length, radius)
    gap = np.linalg.norm(centre[:, None] - centre[None], axis=-1) - reach[:, None] - reach[None]
    own, other = np.nonzero((gap < 0) & ~np.eye(len(start), dtype=bool) & (length[None] > 0))
    rel = verts[own] - start[other][:, None]  # (P, V, 3)
    along = np.einsum("pvj,pj->pv", rel, axis[other])
    radial2 = np.einsum("pvj,pvj->pv", rel, rel) - along**2
    inside = ((along > RAY_OFFSET_M) & (along < length[other][:, None] - RAY_OFFSET_M)
              & (radial2 < (radius[other][:, None] - RAY_OFFSET_M) ** 2))
    out = np.zeros(verts.shape[:2], bool)
    np.logical_or.at(out, own, inside)
    return out


def visibility_step(joints: np.ndarray, *, radii: np.ndarray | None = None,
                    template: CylinderTemplate | None = None, backend: str = "auto") -> tuple[np.ndarray, np.ndarray]:
    """Visible and facing vertex counts (H, 19) of the cylinders of ``joints`` (H, 21, 3), all of
    which are in the scene (pass tracked hands only)."""
    template = template or default_template()
    h = joints.shape[0]
    if h == 0:
        return np.zeros((0, N_BONES), np.int32), np.zeros((0, N_BONES), np.int32)
    radii = bone_radii() if radii is None else np.asarray(radii, np.float64)
    verts = bone_vertices(joints, radii, template).reshape(h * N_BONES, template.n_vertices, 3)
    facing = _facing(verts, template)  # (C, V)
    # buried = inside another cylinder's inscribed prism (radius x cos(pi / sections)), where the ray
    # caster, which sees the faceted surface, blocks it anyway: leaving it out changes facing only
    start, axis, length = bone_frames(joints)
    radius = np.tile(radii, h) * np.cos(np.pi / template.sections)
    facing &= ~_buried(verts, start.reshape(-1, 3), axis.reshape(-1, 3), length.reshape(-1), radius)
    n_occ = len(template.occluder_vertices)
    faces = (template.occluder_faces_compact[None] + n_occ * np.arange(h * N_BONES)[:, None, None]).reshape(-1, 3)
    mesh = trimesh.Trimesh(verts[:, template.occluder_vertices].reshape(-1, 3), faces, process=False, validate=False)
    flat = verts.reshape(-1, 3)
    cast = np.flatnonzero(facing.reshape(-1))
    p = flat[cast]
    dist = np.linalg.norm(p, axis=-1)
    direction = -p / dist[:, None]
    origins = p + RAY_OFFSET_M * direction
    intersector, all_hits = _intersector(mesh, backend)
    index_tri, index_ray, locations = intersector.intersects_id(
        origins, direction, multiple_hits=all_hits, return_locations=True)
    blocked = np.zeros(len(cast), bool)
    if len(index_ray):
        hit_dist = np.linalg.norm(locations - origins[index_ray], axis=-1)
        before_radar = hit_dist < dist[index_ray] - RAY_OFFSET_M
        blocked[index_ray[before_radar]] = True
    visible = np.zeros(flat.shape[0], bool)
    visible[cast[~blocked]] = True
    visible = visible.reshape(h, N_BONES, template.n_vertices).sum(-1).astype(np.int32)
    return visible, facing.reshape(h, N_BONES, -1).sum(-1).astype(np.int32)


def visibility(joints: np.ndarray, mask: np.ndarray, *, radii: np.ndarray | None = None,
               template: CylinderTemplate | None = None, backend: str = "auto", stride: int = 1) -> Visibility:
    """Per step and bone: visible and facing vertex counts of the two-hand scene (see module doc)."""
    joints = np.asarray(joints, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    if joints.ndim != 4 or joints.shape[1:] != (2, 21, 3) or mask.shape != joints.shape[:2]:
        raise ValueError(f"expected joints (T, 2, 21, 3) and mask (T, 2), found {joints.shape} and {mask.shape}")
    if stride < 1:
        raise ValueError(f"stride must be >= 1, found {stride}")
    t_steps = joints.shape[0]
    visible = np.zeros((t_steps, 2, N_BONES), np.int32)
    facing = np.zeros_like(visible)
    steps = sorted(set(range(0, t_steps, stride)) | {t_steps - 1}) if t_steps else []
    for t in steps:
        hands = np.flatnonzero(mask[t])
        v, f = visibility_step(joints[t, hands], radii=radii, template=template, backend=backend)
        visible[t, hands], facing[t, hands] = v, f
    if stride > 1:  # linear in time between cast steps, rounded; untracked hands count 0
        steps_a = np.asarray(steps)
        t_all = np.arange(t_steps)
        hi = np.clip(np.searchsorted(steps_a, t_all, side="left"), 1, len(steps_a) - 1) if len(steps_a) > 1 else np.zeros(t_steps, int)
        lo = np.maximum(hi - 1, 0)
        span = np.maximum(steps_a[hi] - steps_a[lo], 1)
        frac = np.clip((t_all - steps_a[lo]) / span, 0.0, 1.0)[:, None, None]

        def interp(x: np.ndarray) -> np.ndarray:
            v = x[steps_a[lo]] * (1 - frac) + x[steps_a[hi]] * frac
            return (np.rint(v) * mask[..., None]).astype(np.int32)

        visible, facing = interp(visible), interp(facing)
    return Visibility(visible, facing)
