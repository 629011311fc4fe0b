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
Only facing vertices are tested (the others are hidden by their own cylinder), against the
cylinders' occluder triangles (mesh.CylinderTemplate.occluder_faces: the same surface without the
intermediate rings, 10x fewer triangles), i.e. against each bone's closed 20-gon prism. The test
segment runs from RAY_OFFSET_M in front of the vertex to the radar.

Backends (same definitions; ``HandModelConfig.backend``):

- ``"analytic"`` (what ``"auto"`` picks): closed form, numpy, all cast steps of a window in one
  batch. A vertex's segment meets a prism iff, clipped to the prism's slab, it enters the
  inscribed cylinder (sure), or enters the circumscribed one and survives clipping by the side
  planes (the thin band between them); buried = inside another's inscribed prism, as below. A
  prism around the radar itself blocks a vertex iff the segment's far end is outside it (the ray
  caster counts surface crossings).
  Candidate (vertex, cylinder) pairs are culled conservatively first: bounding balls seen from
  the radar, then five linear conditions per occluder (depth, wedge and slab, _shadow_constraints)
  that bound each vertex line's ring range. Measured against the ray casters on 43 windows (39
  SFINGE3D, 4 demo; every step): facing counts identical; visible counts equal the exact
  triangle intersector's in all but 24 of 6688 bone-steps (+1 vertex each, where trimesh counts a
  hit just behind the ray's start) and embree's in all but 305 of 261 440 (embree, through
  trimesh, reports hits on the vertex's own cylinder at the ray's start, up to 17 vertices of a
  bone; mean |visible fraction difference| 2.6e-5). About 10x faster than embree per window.
- ``"embree"``: trimesh's Embree intersector (``trimesh.ray.ray_pyembree``, package embreex), one
  BVH per step; single precision.
- ``"triangle"``: trimesh's pure-Python/numpy intersector (``trimesh.ray.ray_triangle``, rtree
  broad phase, Moller-Trumbore in float64), 10-100x slower than embree: the reference in tests.
- ``"auto"``: analytic.

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

import functools
from dataclasses import dataclass

import numpy as np
import trimesh

from handradar.hand.mesh import (
    CylinderTemplate,
    bone_basis,
    bone_frames,
    bone_radii,
    bone_vertices,
    default_template,
)
from handradar.hand.skeleton import N_BONES

RAY_OFFSET_M = 1e-5  # start rays this far from the vertex, off its own surface
STEPS_PER_BATCH = 96  # analytic backend: steps per batch (a 1.6 s window at stride 2 is one batch)


def embree_available() -> bool:
    try:
        import embreex  # noqa: F401
        from trimesh.ray import ray_pyembree  # noqa: F401
    except ImportError:
        return False
    return True


def _resolve(backend: str) -> str:
    if backend == "auto":
        return "analytic"
    if backend not in ("analytic", "embree", "triangle"):
        raise ValueError(f"unknown visibility backend {backend!r}; expected 'auto', 'analytic', 'embree' or 'triangle'")
    return backend


def _intersector(mesh: trimesh.Trimesh, backend: str):
    if backend == "embree":
        from trimesh.ray.ray_pyembree import RayMeshIntersector
        return RayMeshIntersector(mesh), False
    if backend == "triangle":
        from trimesh.ray.ray_triangle import RayMeshIntersector
        return RayMeshIntersector(mesh), True
    raise ValueError(f"unknown ray-casting backend {backend!r}; expected 'embree' or 'triangle'")


@dataclass
class Visibility:
    visible: np.ndarray  # (T, 2, 19) int32 vertices with a clear line to the radar
    facing: np.ndarray  # (T, 2, 19) int32 vertices with a triangle facing the radar

    def fraction(self) -> np.ndarray:
        """visible / facing, (T, 2, 19) float32 in [0, 1]; 0 where no vertex faces the radar."""
        return np.divide(self.visible, self.facing, out=np.zeros(self.visible.shape, np.float32),
                         where=self.facing > 0).astype(np.float32)


def _toward(tri: np.ndarray) -> np.ndarray:
    """(C, F) bool: the outward normal of each triangle (C, F, 3 corners, 3) points to the origin."""
    normal = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
    return -(normal * tri[:, :, 0]).sum(-1) > 0  # n . (origin - p) > 0 (degenerate: False)


def _facing_of(toward: np.ndarray, template: CylinderTemplate) -> np.ndarray:
    """(C, V) bool from the occluder triangles' ``toward`` (C, F): a vertex faces when one of its does."""
    g = template.facing_groups  # vertices with the same triangles are tested once
    per_group = np.where(g >= 0, toward[:, np.clip(g, 0, None)], False).any(-1)
    return per_group[:, template.vertex_facing_group]


def _facing(verts: np.ndarray, template: CylinderTemplate) -> np.ndarray:
    """(C, V) bool: the vertex lies on at least one surface triangle whose outward normal points to
    the origin (evaluated on the occluder triangles, which carry the same planes as the fine mesh)."""
    return _facing_of(_toward(verts[:, template.occluder_faces]), template)


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


# ---- analytic backend: exact segment / prism tests, batched over many scenes -------------------------
_GROW = 1.0 + 1e-9  # widens every culling bound so that rounding never drops a real candidate
_PAIR_CHUNK = 512  # bone pairs per pass of the exact tests (temporaries stay in the CPU cache and the allocator's heap)


def _plane_facing(start: np.ndarray, axis: np.ndarray, length: np.ndarray, e1: np.ndarray, e2: np.ndarray,
                  radius: np.ndarray, sections: int) -> np.ndarray:
    """(C, sections + 2) bool: the origin is strictly outside each face plane of the prisms (side
    faces, bottom cap, top cap), i.e. the face's outward normal points to the radar: the occluder
    triangles' test (_toward) evaluated on their planes instead of their corners."""
    theta = 2.0 * np.pi * (np.arange(sections) + 0.5) / sections  # side face normals, between vertices
    side = (np.einsum("cj,cj->c", e1, start)[:, None] * np.cos(theta)
            + np.einsum("cj,cj->c", e2, start)[:, None] * np.sin(theta)
            + (radius * np.cos(np.pi / sections))[:, None]) < 0.0
    along = np.einsum("cj,cj->c", axis, start)
    return np.concatenate([side, (along > 0.0)[:, None], (along + length < 0.0)[:, None]], axis=1)


def _cone_pairs(centre: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(S, m, m) bool for the m balls (centre (S, m, 3), radius reach (S, m)) of each of S scenes:
    [s, i, j] where some segment from the origin to a point of ball i may meet ball j (conservative):
    their angular discs seen from the origin overlap and ball j reaches nearer to the origin than
    ball i's far side."""
    dist = np.linalg.norm(centre, axis=-1)
    unit = centre / np.maximum(dist, 1e-300)[..., None]
    sin = reach / np.maximum(dist, 1e-300)  # sine of the angular radius (>= 1: the ball holds the origin)
    cos = np.sqrt(np.clip(1.0 - sin * sin, 0.0, None))
    cos_apart = unit @ np.swapaxes(unit, 1, 2)
    inside = sin >= 1.0
    overlap = (inside[:, :, None] | inside[:, None, :]
               | (cos_apart >= cos[:, :, None] * cos[:, None, :] - sin[:, :, None] * sin[:, None, :] - 1e-9))
    return overlap & ((dist - reach)[:, None, :] <= ((dist + reach) * _GROW)[:, :, None])


def _polygon_hits(p: np.ndarray, s: np.ndarray, e1: np.ndarray, e2: np.ndarray, radius: np.ndarray,
                  lo: np.ndarray, hi: np.ndarray, sections: int) -> np.ndarray:
    """(M,) bool: points t * p, t in [lo, hi] (inside the prism's slab), cross inside the regular
    ``sections``-gon of circumradius ``radius`` about the axis through s (cross-section axes e1 e2):
    Cyrus-Beck clipping by the side planes m . (x - s) <= radius cos(pi / sections)."""
    theta = 2.0 * np.pi * (np.arange(sections) + 0.5) / sections
    normals = np.stack([np.cos(theta), np.sin(theta)])  # (2, sections): m in the (e1, e2) frame
    u = np.stack([np.einsum("mj,mj->m", e1, p), np.einsum("mj,mj->m", e2, p)], axis=1) @ normals
    w = np.stack([np.einsum("mj,mj->m", e1, s), np.einsum("mj,mj->m", e2, s)], axis=1) @ normals
    w += (radius * np.cos(np.pi / sections))[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = w / u
    lo = np.maximum(lo, np.where(u < 0.0, bound, -np.inf).max(-1))
    hi = np.minimum(hi, np.where(u > 0.0, bound, np.inf).min(-1))
    return (lo <= hi) & ~((u == 0.0) & (w < 0.0)).any(-1)


def _in_prism(x: np.ndarray, s: np.ndarray, a: np.ndarray, e1: np.ndarray, e2: np.ndarray, length: np.ndarray,
              radius: np.ndarray, sections: int) -> np.ndarray:
    """(M,) bool: points x (M, 3) inside (or on) the closed prism of each row (start s, unit axis a,
    cross-section axes e1 e2, length, circumradius; metres)."""
    rel = x - s
    along = np.einsum("mj,mj->m", rel, a)
    theta = 2.0 * np.pi * (np.arange(sections) + 0.5) / sections
    face = (np.einsum("mj,mj->m", rel, e1)[:, None] * np.cos(theta)
            + np.einsum("mj,mj->m", rel, e2)[:, None] * np.sin(theta)).max(-1)
    return (along >= 0.0) & (along <= length) & (face <= radius * np.cos(np.pi / sections))


def _shadow_constraints(start: np.ndarray, axis: np.ndarray, length: np.ndarray,
                        radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Five linear conditions g . p <= h, (C, 5, 3) and (C, 5), that every point p shadowed by a
    cylinder (circumradius ``radius``, so its prism too) satisfies; zero rows (always true) where
    the origin is within the radius of the axis line.

    With D the distance from the origin to the axis line, m the unit vector from the origin's foot
    on it and n the normal of the plane through the origin and the axis, every cylinder point y has
    m . y >= D - r and |n . y| <= r. The blocking point is y = t p, t in (0, 1], so: depth m . p >=
    D - r; wedge |n . p| <= r / (D - r) m . p; and a . (t p) must reach the slab [a . s, a . s + L]
    for some t in [(D - r) / (m . p), 1], which bounds a . p on each side."""
    along = np.einsum("cj,cj->c", start, axis)
    foot = start - along[:, None] * axis
    dist = np.linalg.norm(foot, axis=-1)
    front = dist - radius
    ok = (front > 1e-9) & (length > 1e-9)
    m = np.divide(foot, dist[:, None], out=np.zeros_like(foot), where=ok[:, None])
    n = np.cross(m, axis)
    kappa = np.where(ok, radius / np.where(ok, front, 1.0), 0.0)[:, None] * _GROW
    front_, end = front[:, None], (along + length)[:, None]
    g = np.stack([-m, n - kappa * m, -n - kappa * m,
                  np.where(along[:, None] > 0.0, -axis, along[:, None] * m - front_ * axis),
                  np.where(end < 0.0, axis, front_ * axis - end * m)], axis=1)
    h = np.stack([-front, np.zeros_like(front), np.zeros_like(front),
                  np.where(along > 0.0, -along, 0.0), np.where(end[:, 0] < 0.0, end[:, 0], 0.0)], axis=1)
    g[~ok], h[~ok] = 0.0, 0.0
    return g, h + 1e-12  # the margin keeps rounding from culling a vertex on a bound


def _shadow_pass(z: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact tests of candidates: vertex p = A + z B (metres) against occluder j (start s, unit
    axis a, length L). ``k`` (13, M) holds per candidate a.A and a.B; the two coefficients of
    (s - (a.s) a) . p; |A|^2, 2 A.B and |B|^2; j's a.s, a.s + L and |s|^2 - (a.s)^2; its inscribed
    radius squared (less 1e-9), circumscribed radius squared (plus 1e-9) and the buried test's
    (inscribed radius - RAY_OFFSET_M)^2 (-1 where that test does not apply).

    The points t p, t in [0, 1 - RAY_OFFSET_M / |p|] (the ray caster's segment), clipped to j's
    slab [lo, hi], come within sqrt(d2) of j's axis, d2 = A t^2 - 2 B t + C at the best t.
    Returns (sure, band, lo, hi, inside): sure = the segment enters the inscribed cylinder, so the
    prism; band = only the circumscribed one (the prism's faces decide); inside = p is buried in j."""
    ap = k[0] + z * k[1]
    pp = k[4] + z * (k[5] + z * k[6])
    quad_a = pp - ap * ap
    quad_b = k[2] + z * k[3]
    as_, ae = k[7], k[8]
    with np.errstate(divide="ignore", invalid="ignore"):  # ap = 0: parallel to the caps, +-inf do it
        inv = 1.0 / ap
        t1 = as_ * inv
        t2 = ae * inv
        lo = np.maximum(np.minimum(t1, t2), 0.0)
        hi = np.minimum(np.maximum(t1, t2), 1.0 - RAY_OFFSET_M / np.sqrt(pp))
        t = np.minimum(np.maximum(quad_b / np.maximum(quad_a, 1e-300), lo), hi)
    d2 = (quad_a * t - 2.0 * quad_b) * t + k[9]
    ok = lo <= hi
    sure = ok & (d2 < k[10])
    band = ok & ~sure & (d2 <= k[11])
    # p itself strictly inside j: a . p - a . s in (offset, L - offset), squared distance from the axis
    inside = ((ap > as_ + RAY_OFFSET_M) & (ap < ae - RAY_OFFSET_M) & (quad_a - 2.0 * quad_b + k[9] < k[12]))
    return sure, band, lo, hi, inside


@functools.cache
def _line_layout(template: CylinderTemplate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The template's vertices on lines: (lines, rings) template index of each (line, ring) slot,
    -1 where there is none, for the ``sections`` generators and the two cap centres (ring 0 only);
    the (lines, 4) homogeneous template point of each line's ring 0; and (lines * rings, P) the
    face planes (_plane_facing's columns) of each slot's occluder triangles, padded with the extra
    column sections + 2 (empty slots: all padding). A vertex faces iff one of its planes does."""
    sec, rings, n_side = template.sections, template.rings, template.sections * template.rings
    index = np.full((sec + 2, rings), -1, np.int64)
    index[:sec] = np.arange(rings)[None] * sec + np.arange(sec)[:, None]
    index[sec:, 0] = n_side, n_side + 1
    faces = template.vertex_occluder_faces[np.clip(index, 0, None)]  # (lines, rings, degree)
    plane = np.where((faces >= 0) & (index >= 0)[..., None], template.occluder_face_plane[np.clip(faces, 0, None)],
                     sec + 2)
    sets = [sorted(set(row) - {sec + 2}) for row in plane.reshape(-1, plane.shape[-1]).tolist()]
    planes = np.full((len(sets), max(map(len, sets))), sec + 2, np.int64)
    for i, row in enumerate(sets):
        planes[i, :len(row)] = row
    hom_a = template.homogeneous[index[:, 0]]
    assert np.array_equal(hom_a[sec:], [[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0]])  # _analytic_counts relies on it
    return index, hom_a, planes


def _analytic_counts(joints: np.ndarray, scene: np.ndarray, radii: np.ndarray, template: CylinderTemplate,
                     cull: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Visible and facing counts (N, 19) of N hands ``joints`` (N, 21, 3); hands with equal
    ``scene`` (N,), which must be sorted, are one scene (one step) and shadow each other.

    The ray caster's definitions, in closed form: a vertex faces when one of its occluder
    triangles' planes does; buried vertices are out; a facing vertex is visible unless the segment
    to the radar (less RAY_OFFSET_M) meets another cylinder's prism. The vertices lie on lines: the
    sections' generators (rings at z = 0 .. 1) and the two cap centres, so candidates are (line,
    occluder) rows with a range of rings, culled conservatively (bone bounding balls, then the
    linear conditions of _shadow_constraints); each candidate then gets the exact test.
    ``cull=False`` tests every facing vertex against every other cylinder of its scene (for tests:
    culling must not change a count)."""
    n, sec, rings = joints.shape[0], template.sections, template.rings
    c, n_lines = n * N_BONES, template.sections + 2
    start, axis, length = (x.reshape(c, *x.shape[2:]) for x in bone_frames(joints))
    e1, e2 = bone_basis(axis)
    radius = np.tile(radii, n)
    inner = radius * np.cos(np.pi / sec)  # the prism's inscribed radius

    # vertices in line layout (C, lines, rings): line l, ring r is A_l + z_r B, z_r = r / (rings - 1),
    # the sections' generators, then the bottom and top cap centres (ring 0 only)
    index, hom_a, planes = _line_layout(template)
    toward = np.zeros((c, sec + 3), bool)  # the face planes that face the radar; last column: padding
    toward[:, :-1] = _plane_facing(start, axis, length, e1, e2, radius, sec)
    facing = toward[:, planes[:, 0]]
    for k in range(1, planes.shape[1]):
        facing |= toward[:, planes[:, k]]
    facing = facing.reshape(c, n_lines, rings)
    any_facing = facing.any(-1)  # (C, lines); a line's facing rings are contiguous (all, or a cap's)
    face_lo = np.where(any_facing, facing.argmax(-1), rings)
    face_hi = np.where(any_facing, rings - 1 - facing[:, :, ::-1].argmax(-1), -1)
    is_side = (np.arange(n_lines) < sec).astype(np.float64)
    frame = np.stack([radius[:, None] * e1, radius[:, None] * e2, length[:, None] * axis, start], axis=-1)
    point_a = np.ascontiguousarray(np.swapaxes((frame.reshape(-1, 4) @ hom_a.T).reshape(c, 3, n_lines), 1, 2))  # (C, lines, 3)
    vec_b = length[:, None] * axis  # (C, 3): the generators' direction
    a_sq = np.einsum("clx,clx->cl", point_a, point_a).reshape(-1)  # (C * lines,)
    ab2 = (2.0 * np.einsum("clx,cx->cl", point_a, vec_b) * is_side).reshape(-1)
    length_sq = length**2

    # bone pairs of one scene (i: source, j: occluder) whose bounding balls can shadow, from each
    # scene's (m, m) matrix (scenes padded to the largest)
    _, first, size = np.unique(np.repeat(np.asarray(scene), N_BONES), return_index=True, return_counts=True)
    slot = np.arange(size.max())
    valid = slot < size[:, None]
    pad = np.where(valid, first[:, None] + slot, 0)  # (S, m) cylinder of each slot
    centre = start + 0.5 * length[:, None] * axis
    ok = _cone_pairs(centre[pad], np.hypot(0.5 * length, radius)[pad]) | (not cull)
    ok &= (valid & any_facing.any(1)[pad])[:, :, None] & (valid & (length[pad] > 1e-9))[:, None, :]
    ok &= ~np.eye(len(slot), dtype=bool)
    s_, a_, b_ = np.nonzero(ok)
    ii, jj = pad[s_, a_], pad[s_, b_]
    # ... and whose source capsule can meet the occluder's five conditions
    g_all, h_all = _shadow_constraints(start, axis, length, radius)
    g = g_all[jj]  # (P, 5, 3)
    g_s = np.einsum("pkj,pj->pk", g, start[ii])
    g_e = g_s + np.einsum("pkj,pj->pk", g, vec_b[ii])
    keep = (np.minimum(g_s, g_e) - radius[ii, None] * np.linalg.norm(g_all, axis=-1)[jj] <= h_all[jj]).all(1) | (not cull)
    ii, jj = ii[keep], jj[keep]
    reach_in = np.hypot(0.5 * length, inner)  # the buried test's pairs (as in _buried)
    touch = np.linalg.norm(centre[ii] - centre[jj], axis=-1) - reach_in[ii] - reach_in[jj] < 0

    # per occluder: the five conditions, a_j and s_j - (a_j . s_j) a_j as linear functionals, and
    # the exact tests' scalars
    as_j = np.einsum("cj,cj->c", axis, start)
    # a prism holding the radar (a hand on the antenna) meets a segment to it iff the segment's
    # far end is outside: the ray caster counts surface crossings
    holds = _in_prism(np.zeros_like(start), start, axis, e1, e2, length, radius, sec) & (length > 1e-9)
    funcs = np.concatenate([g_all, axis[:, None], (start - as_j[:, None] * axis)[:, None]], axis=1)  # (C, 7, 3)
    occ_k = np.stack([as_j, as_j + length, np.einsum("cj,cj->c", start, start) - as_j**2, inner**2 * (1.0 - 1e-9),
                      radius**2 * _GROW, (inner - RAY_OFFSET_M) ** 2])  # (6, C)
    blocked = np.zeros(c * n_lines * rings, bool)  # line layout, flat
    buried = np.zeros_like(blocked)
    band_tests = []  # (flat index, point, occluder, lo, hi) of the band candidates
    for p0 in range(0, len(ii), _PAIR_CHUNK):
        i_c, j_c = ii[p0:p0 + _PAIR_CHUNK], jj[p0:p0 + _PAIR_CHUNK]
        npc = len(i_c)
        fm = funcs[j_c] @ frame[i_c]  # f^T M_i, (P, 7, 4): f . (A_l + z B) = fm . (x_l, y_l, z, 1)
        f1 = fm[:, :, 2]  # f . B along the generators (the caps' lines are single points)
        # ring range of each line where all five conditions can hold: on a generator condition k
        # holds for z (ring units) >= or <= (h_k - f_k . A_l) * inv_k as f1 < 0 or > 0, so both bounds
        # of every side line come from one matmul each of the functionals times -inv_k, their
        # constant column shifted by h_k inv_k -+ a margin; a condition that is no bound on that
        # side gets the constant -+1e300 (and zeros: the matmul gives exactly that)
        h5 = h_all[j_c]
        f1_5 = f1[:, :5]
        inv = (rings - 1) / np.where(f1_5 == 0.0, 1.0, f1_5)
        # laid out (5, P, ...): the reductions over the conditions run over contiguous slabs
        scaled = (fm[:, :5] * -inv[:, :, None]).transpose(1, 0, 2)
        below_lo, below_hi, shift = (f1_5 < 0.0).T, (f1_5 > 0.0).T, (h5 * inv).T
        side_a = hom_a[:sec].T  # the generators' ring-0 points (z = 0)
        r_lo = np.full((npc, n_lines), -np.inf)
        r_hi = np.full((npc, n_lines), np.inf)
        for below, out, margin, reduce in ((below_lo, r_lo, -1e-6, np.max), (below_hi, r_hi, 1e-6, np.min)):
            lin = np.where(below[:, :, None], scaled, 0.0)
            lin[:, :, 3] = np.where(below, lin[:, :, 3] + shift + margin, -1e300 if margin < 0 else 1e300)
            out[:, :sec] = reduce((lin.reshape(-1, 4) @ side_a).reshape(5, npc, sec), axis=0)
        never = np.zeros((npc, n_lines), bool)
        h_c = h5[:, :, None]
        flat_pairs = np.flatnonzero((f1_5 == 0.0).any(1))
        if len(flat_pairs):  # parallel to a condition's plane: the condition holds on all or none of a line
            f0_side = (fm[flat_pairs, :5].reshape(-1, 4) @ side_a).reshape(-1, 5, sec)
            never[flat_pairs, :sec] = ((f1_5[flat_pairs] == 0.0)[:, :, None] & (f0_side > h_c[flat_pairs])).any(1)
        # the cap centres are template points (0, 0, 0, 1) and (0, 0, 1, 1): f . A = fm_3, fm_2 + fm_3
        never[:, sec] = (fm[:, :5, 3] > h5).any(1)
        never[:, sec + 1] = (fm[:, :5, 2] + fm[:, :5, 3] > h5).any(1)
        f0 = (fm[:, 5:].reshape(-1, 4) @ hom_a.T).reshape(npc, 2, n_lines)  # a . A_l, s-perp . A_l
        if not cull:
            r_lo, r_hi, never = np.full_like(r_lo, -np.inf), np.full_like(r_hi, np.inf), np.zeros_like(never)
        r_lo = np.maximum(np.ceil(r_lo), face_lo[i_c])
        r_hi = np.minimum(np.floor(r_hi), face_hi[i_c])
        pr, ln = np.nonzero(~never & (r_lo <= r_hi))  # rows: (pair, line)
        if not len(pr):
            continue
        lo_row = r_lo[pr, ln].astype(np.int64)
        count = r_hi[pr, ln].astype(np.int64) - lo_row + 1
        # per row values of _shadow_pass, then repeated for each candidate ring
        i_r, j_r = i_c[pr], j_c[pr]
        il = i_r * n_lines + ln
        side = is_side[ln]
        row_k = np.empty((13, len(pr)))
        row_k[0] = f0[pr, 0, ln]
        row_k[1] = f1[pr, 5] * side
        row_k[2] = f0[pr, 1, ln]
        row_k[3] = f1[pr, 6] * side
        row_k[4], row_k[5], row_k[6] = a_sq[il], ab2[il], length_sq[i_r] * side
        row_k[7:13] = occ_k[:, j_r]
        row_k[12] = np.where(touch[p0 + pr], row_k[12], -1.0)
        k = np.repeat(row_k, count, axis=1)
        rep = np.repeat(np.arange(len(pr)), count)  # each candidate's row
        ring = lo_row[rep] + np.arange(len(rep)) - (np.cumsum(count) - count)[rep]
        z = ring / (rings - 1)
        sure, band, lo, hi, inside = _shadow_pass(z, k)
        flat = (il * rings)[rep] + ring
        if holds[j_r].any():  # a prism holding the radar: the far end decides (replaces sure and band)
            h_ = np.flatnonzero(holds[j_r[rep]])
            rh, jh = rep[h_], j_r[rep[h_]]
            p = point_a.reshape(c * n_lines, 3)[il[rh]] + (z[h_] * side[rh])[:, None] * vec_b[i_r[rh]]
            p *= (1.0 - RAY_OFFSET_M / np.linalg.norm(p, axis=-1))[:, None]
            sure[h_] = ~_in_prism(p, start[jh], axis[jh], e1[jh], e2[jh], length[jh], radius[jh], sec)
            band[h_] = False
        if band.any():  # the prism's faces decide: collected, tested once after the loop
            b = np.flatnonzero(band)
            rb, jb = rep[b], j_r[rep[b]]
            p = point_a.reshape(c * n_lines, 3)[il[rb]] + (z[b] * side[rb])[:, None] * vec_b[i_r[rb]]
            band_tests.append((flat[b], p, jb, lo[b], hi[b]))
        blocked[flat[sure]] = True
        buried[flat[inside]] = True  # inside j implies the segment meets j: buried is blocked too
    if band_tests:  # one call for all chunks (its cost is mostly per call)
        flat_b, p, jb, lo, hi = (np.concatenate(x) for x in zip(*band_tests))
        blocked[flat_b[_polygon_hits(p, start[jb], e1[jb], e2[jb], radius[jb], lo, hi, sec)]] = True
    facing = facing.reshape(-1) & ~buried
    visible = facing & ~blocked
    return (visible.reshape(n, N_BONES, -1).sum(-1).astype(np.int32),
            facing.reshape(n, N_BONES, -1).sum(-1).astype(np.int32))


def visibility_step(joints: np.ndarray, *, radii: np.ndarray | None = None,
                    template: CylinderTemplate | None = None, backend: str = "auto") -> tuple[np.ndarray, np.ndarray]:
    """Visible and facing vertex counts (H, 19) of the cylinders of ``joints`` (H, 21, 3), all of
    which are in the scene (pass tracked hands only)."""
    template = template or default_template()
    backend = _resolve(backend)
    h = joints.shape[0]
    if h == 0:
        return np.zeros((0, N_BONES), np.int32), np.zeros((0, N_BONES), np.int32)
    radii = bone_radii() if radii is None else np.asarray(radii, np.float64)
    if backend == "analytic":
        return _analytic_counts(np.asarray(joints, np.float64), np.zeros(h, np.int64), radii, template)
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
    if _resolve(backend) == "analytic":  # all cast steps at once, in batches of scenes
        template = template or default_template()
        radii_ = bone_radii() if radii is None else np.asarray(radii, np.float64)
        steps_a = np.asarray(steps, np.int64)
        for b0 in range(0, len(steps_a), STEPS_PER_BATCH):
            batch = steps_a[b0:b0 + STEPS_PER_BATCH]
            t_i, h_i = np.nonzero(mask[batch])  # sorted by step: one scene per step
            if len(t_i):
                v, f = _analytic_counts(joints[batch[t_i], h_i], t_i, radii_, template)
                visible[batch[t_i], h_i], facing[batch[t_i], h_i] = v, f
    else:
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
