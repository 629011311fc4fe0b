"""What the radar cannot see: surface buried inside another part's solid, and shadows.

Surface inside another part's solid (a phalanx where it meets the next, the metacarpals inside the
palm slab) is no surface: it neither scatters nor is lit, whatever the occlusion setting
(:func:`buried`). Shadowing: a ray from the antenna to the centre of every front-facing element and
texture point, Embree, against the smooth surfaces tessellated finely on their own
(handradar.world.geometry.occluders_of), at ``scene.visibility_rate_hz`` (:func:`cast_steps`; values
at the steps in between are interpolated linearly, :func:`lerp_steps`).
"""

from __future__ import annotations

import numpy as np
import trimesh

from handradar.world.geometry import Part, Surfaces

RAY_TOLERANCE_M = 2e-4  # a hit this close to the point itself is the point's own surface


# ---- buried surface ------------------------------------------------------------------------------
BURIED_MARGIN_M = 1e-4  # a point must lie this deep inside another part's solid to count as buried


def _segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Shortest distance between segments p0-p1 and q0-q1 (arrays (..., 3), broadcast)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = (d1 * d1).sum(-1), (d2 * d2).sum(-1), (d2 * r).sum(-1)
    b, c = (d1 * d2).sum(-1), (d1 * r).sum(-1)
    denom = np.maximum(a * e - b * b, 1e-18)
    s = np.clip((b * f - c * e) / denom, 0.0, 1.0)
    t = np.clip((b * s + f) / np.maximum(e, 1e-18), 0.0, 1.0)
    s = np.clip((b * t - c) / np.maximum(a, 1e-18), 0.0, 1.0)
    return np.linalg.norm(p0 + d1 * s[..., None] - q0 - d2 * t[..., None], axis=-1)


def _capsule(p: Part, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Ends (S, 3) x 2 and radius of a capsule holding the part at those steps."""
    if p.cones:
        first, last = p.cones[0], p.cones[-1]
        a = first.base[steps] + first.axis[steps] * first.l0[steps][:, None]
        b = last.base[steps] + last.axis[steps] * last.l1[steps][:, None]
        return a, b, max(max(c.r0, c.r1) for c in p.cones)
    corners = np.concatenate(p.slab_faces)
    mid = corners.mean(0)
    centre = p.to_radar(mid[None])[steps][:, 0]
    return centre, centre, float(np.max(np.linalg.norm(corners - mid, axis=1)))


def _inside(p: Part, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """(S, M) bool: points x (S, M, 3) strictly inside the part's solid at those steps."""
    eps = BURIED_MARGIN_M
    inside = np.zeros(x.shape[:2], bool)
    for c in p.cones:
        rel = x - c.base[steps][:, None, :]
        along = (rel * c.axis[steps][:, None, :]).sum(-1)
        l0, l1 = c.l0[steps][:, None], c.l1[steps][:, None]
        radial2 = (rel * rel).sum(-1) - along ** 2
        r = c.r0 + (c.r1 - c.r0) * (along - l0) / (l1 - l0)
        inside |= (along > l0 + eps) & (along < l1 - eps) & (radial2 < np.square(np.clip(r - eps, 0, None)))
    if p.slab_faces:
        local = np.einsum("tji,tnj->tni", p.rotation[steps], x - p.origin[steps][:, None, :])
        top = p.slab_faces[0]
        edge = np.roll(top[:, :2], -1, 0) - top[:, :2]
        sense = np.sign(edge[0, 0] * edge[1, 1] - edge[0, 1] * edge[1, 0])  # winding (mirrored: left hand)
        side = sense * (edge[:, 0] * (local[..., None, 1] - top[:, 1]) - edge[:, 1] * (local[..., None, 0] - top[:, 0]))
        inside |= (np.abs(local[..., 2]) < abs(top[0, 2]) - eps) & (side > eps * np.linalg.norm(edge, axis=1)).all(-1)
    return inside


def buried(parts: list[Part], owner: np.ndarray, points: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """(len(steps), N) bool: the point (len(steps), N, 3) of part ``owner`` (N,) lies inside the
    solid of another part at those steps. Neighbouring parts of the model overlap (a phalanx where it
    meets the next, the metacarpals inside the palm slab): surface inside a solid is no surface and
    neither scatters nor is lit, whatever the occlusion setting. Only parts whose bounding capsules
    meet at some step are tested against each other."""
    out = np.zeros(points.shape[:2], bool)
    caps = [_capsule(p, steps) for p in parts]
    a = np.stack([c[0] for c in caps], 1)  # (S, P, 3)
    b = np.stack([c[1] for c in caps], 1)
    r = np.array([c[2] for c in caps])
    gap = _segment_distance(a[:, :, None], b[:, :, None], a[:, None], b[:, None]) - r[:, None] - r[None, :]
    meet = (gap < 0).any(0) & ~np.eye(len(parts), dtype=bool)  # (owner, solid)
    for q in range(len(parts)):
        idx = np.flatnonzero(meet[owner, q])  # the points of every part that meets solid q
        if idx.size:
            out[:, idx] |= _inside(parts[q], points[:, idx], steps)
    return out


# ---- shadowing -----------------------------------------------------------------------------------
_BATCH_STEPS = 16  # time steps ray cast together (each step's copy of the scene set apart by _SPACING_M)
_SPACING_M = 4.0


def _occluded_embree(verts: np.ndarray, faces: np.ndarray, points: list[np.ndarray]) -> list[np.ndarray]:
    """Per step s: is the segment from the origin to each point (within RAY_TOLERANCE_M of it) blocked
    by that step's triangles (verts[s] (V, 3), faces (F, 3))? Steps are cast together, each set apart
    on a grid, so one Embree scene serves many (building a scene costs more than its rays); indexed
    triangles build about twice as fast as a triangle soup."""
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    out = []
    n_v = verts.shape[1]
    for b0 in range(0, len(verts), _BATCH_STEPS):
        batch = range(b0, min(b0 + _BATCH_STEPS, len(verts)))
        offsets = [np.array([(i % 4) * _SPACING_M, (i // 4) * _SPACING_M, 0.0]) for i in range(len(batch))]
        scene = rtcs.EmbreeScene()
        TriangleMesh(scene, np.concatenate([verts[s] + o for s, o in zip(batch, offsets)]).astype(np.float32),
                     np.concatenate([faces + i * n_v for i in range(len(batch))]).astype(np.int32))
        origins = np.concatenate([np.broadcast_to(o, points[s].shape) for s, o in zip(batch, offsets)])
        p = np.concatenate([points[s] for s in batch])
        dist = np.linalg.norm(p, axis=-1)
        dirs = p / np.maximum(dist, 1e-12)[:, None]
        if len(p):
            hit = scene.run(origins.astype(np.float32), dirs.astype(np.float32),
                            dists=np.maximum(dist - RAY_TOLERANCE_M, 0.0).astype(np.float32), query="OCCLUDED")
            hit = np.asarray(hit) >= 0
        else:
            hit = np.zeros(0, bool)
        counts = np.cumsum([0] + [len(points[s]) for s in batch])
        out += [hit[counts[i]:counts[i + 1]] for i in range(len(batch))]
    return out


def _occluded_trimesh(verts: np.ndarray, faces: np.ndarray, points: list[np.ndarray]) -> list[np.ndarray]:
    """The same as :func:`_occluded_embree` with trimesh's numpy intersector (no Embree installed)."""
    from trimesh.ray.ray_triangle import RayMeshIntersector

    out = []
    for v, p in zip(verts, points):
        blocked = np.zeros(len(p), bool)
        if len(p):
            mesh = trimesh.Trimesh(v, faces, process=False, validate=False)
            dist = np.linalg.norm(p, axis=-1)
            dirs = p / dist[:, None]
            loc, ray, _ = RayMeshIntersector(mesh).intersects_location(np.zeros_like(p), dirs, multiple_hits=True)
            near = np.linalg.norm(loc, axis=-1) < dist[ray] - RAY_TOLERANCE_M
            blocked[ray[near]] = True
        out.append(blocked)
    return out


def occluded(verts: np.ndarray, faces: np.ndarray, points: list[np.ndarray]) -> list[np.ndarray]:
    """Per step s: (N_s,) bool, the segment from the antenna to points[s] (N_s, 3) crosses a triangle
    (verts[s] (V, 3), faces (F, 3)) short of the point (Embree when installed, else trimesh)."""
    try:
        import embreex  # noqa: F401
    except ImportError:
        return _occluded_trimesh(verts, faces, points)
    return _occluded_embree(verts, faces, points)


def cast_visibility(surfaces: Surfaces, cast: np.ndarray, points: np.ndarray, front: np.ndarray) -> np.ndarray:
    """(len(cast), N) 0/1: at each cast step, 1 where a front-facing point (len(cast), N, 3) has a
    clear line to the antenna (the origin)."""
    idx = [np.flatnonzero(f) for f in front]
    blocked = occluded(surfaces.vertices[cast], surfaces.faces, [p[i] for p, i in zip(points, idx)])
    vis = np.zeros(front.shape)
    for k, (i, b) in enumerate(zip(idx, blocked)):
        vis[k, i] = ~b
    return vis


def cast_steps(n_steps: int, every: int) -> np.ndarray:
    """Every ``every``-th step and the last: where rays are cast (and weights evaluated)."""
    return np.unique(np.r_[np.arange(0, n_steps, max(1, every)), n_steps - 1])


def visibility(surfaces: Surfaces, points: np.ndarray, front: np.ndarray, every: int = 1) -> np.ndarray:
    """(T, N) in [0, 1]: 1 where a front-facing point (T, N, 3) has a clear line to the antenna (the
    origin). Rays are cast at every ``every``-th step (and the last); steps in between are
    interpolated linearly, so a point fades in or out of shadow between two casts."""
    cast = cast_steps(front.shape[0], every)
    return lerp_steps(cast, cast_visibility(surfaces, cast, points[cast], front[cast]), front.shape[0])


def lerp_steps(steps: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Values (len(steps), K) at integer steps -> (n, K) by linear interpolation."""
    if len(steps) == n:
        return values
    idx = np.arange(n)
    hi = np.clip(np.searchsorted(steps, idx, side="right"), 1, len(steps) - 1)
    lo = hi - 1
    frac = ((idx - steps[lo]) / (steps[hi] - steps[lo]))[:, None]
    return values[lo] * (1 - frac) + values[hi] * frac
