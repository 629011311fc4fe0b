"""The hand's parts in the radar scene: finger bones, palm slab and forearm as smooth surfaces.

Every part is a smooth surface rebuilt at each physics step (``scene.rate_hz``): finger bones as
tapered cylinders (fingertips capped by a cone), the palm and back of the hand as a flat slab whose
outline runs through the wrist and the knuckles, the forearm as a truncated cone from the wrist to an
elbow fixed per recording (:func:`build_parts`). The scene's facets (``finger_sides`` x
``finger_rings``, ``forearm_sides`` x ``forearm_rings``, ``palm_subdivisions``) tessellate these
surfaces into the renderer's tracks (one range and one complex amplitude per facet and chirp) and
into the elements of the surface integral (handradar.world.scattering); they are not scatterers,
so where the facets lie (``scene.facet_turn`` lays them out differently) changes a spectrogram by
little more than rounding (benchmarks/world_convergence.py). The ray caster sees the surfaces
tessellated finely on their own (:func:`occluders_of`), so that shadows do not depend on the facets.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from handradar.hand.skeleton import BONE_NAMES, BONES
from handradar.world.config import Effects, Scene
from handradar.world.kinematics import Pose

CAP_HEIGHT = 0.9  # fingertip cap: a cone of height 0.9 r beyond the last joint


def unit_vectors(v: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) scaled to unit length (a zero vector stays zero)."""
    return v / np.maximum(np.sqrt(np.einsum("...i,...i->...", v, v)), 1e-12)[..., None]


def frustum(a: np.ndarray, b: np.ndarray, up: np.ndarray, r0: float, r1: float, sides: int, rings: int,
            cap_end: bool = False, turn: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Tapered cylinder from a to b (T, 3): vertices (T, V, 3) and faces (F, 3); ``up`` fixes the seam,
    ``turn`` rotates the facets about the axis by that fraction of one side (same shape, other facets)."""
    e = unit_vectors(b - a)
    u = unit_vectors(up - (up * e).sum(-1, keepdims=True) * e)
    v = np.cross(e, u)
    length = np.linalg.norm(b - a, axis=-1, keepdims=True)
    phi = 2 * np.pi * (np.arange(sides) + 0.5 + turn) / sides
    verts = []
    for i in range(rings + 1):
        z = i / rings
        r = r0 + (r1 - r0) * z
        ring = (a + e * length * z)[:, None, :] + r * (np.cos(phi)[None, :, None] * u[:, None, :]
                                                       + np.sin(phi)[None, :, None] * v[:, None, :])
        verts.append(ring)
    faces = []
    for i in range(rings):
        for s in range(sides):
            p0, p1 = i * sides + s, i * sides + (s + 1) % sides
            q0, q1 = p0 + sides, p1 + sides
            faces += [(p0, p1, q1), (p0, q1, q0)]
    if cap_end:
        tip = (b + e * r1 * CAP_HEIGHT)[:, None, :]
        verts.append(tip)
        c = (rings + 1) * sides
        last = rings * sides
        faces += [(last + s, last + (s + 1) % sides, c) for s in range(sides)]
    return np.concatenate(verts, axis=1), np.asarray(faces, dtype=np.int64)


# Palm outline (right-hand form, hand-local metres at scale 1): wrist ulnar side, pinky, ring,
# middle and index knuckles, thumb web, wrist radial side. Convex, counter-clockwise seen from +z.
_PALM_OUTLINE = np.array([[0.030, 0.0], [0.040, 0.076], [0.018, 0.090], [-0.004, 0.096], [-0.028, 0.092],
                          [-0.038, 0.045], [-0.027, 0.0]])


def _subdivide(tri: np.ndarray, levels: int) -> np.ndarray:
    """(n, 3, 2) triangles -> (n * 4^levels, 3, 2) by midpoint splitting."""
    for _ in range(levels):
        a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        tri = np.concatenate([np.stack(x, 1) for x in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return tri


_PALM_APEX_CIRCLE_M = 0.01  # facet_turn moves the apex of the palm's triangle fan around a circle this big (scale 1)


def palm_template(scale: float, thickness_m: float, subdivisions: int, left: bool,
                  turn: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Palm slab in hand-local coordinates: vertices (V, 3), faces (F, 3) (a triangle soup).

    The faces are a fan from an apex inside the outline; ``turn`` (scene.facet_turn) moves the apex
    around a circle through the outline's mean, which keeps the slab and moves every facet."""
    outline = _PALM_OUTLINE * scale
    a = 2 * np.pi * turn
    centre = outline.mean(0) + _PALM_APEX_CIRCLE_M * scale * np.array([np.cos(a) - 1.0, np.sin(a)])
    fan = np.stack([np.broadcast_to(centre, outline.shape), outline, np.roll(outline, -1, 0)], 1)
    tris2d = _subdivide(fan, subdivisions)
    h = thickness_m / 2
    tris = []
    for z in (h, -h):  # back of the hand, then palm
        tris.append(np.concatenate([tris2d, np.full(tris2d.shape[:2] + (1,), z)], -1))
    o0, o1 = outline, np.roll(outline, -1, 0)
    for z0, z1 in ((h, -h),):
        top0, top1 = np.c_[o0, np.full(len(o0), z0)], np.c_[o1, np.full(len(o0), z0)]
        bot0, bot1 = np.c_[o0, np.full(len(o0), z1)], np.c_[o1, np.full(len(o0), z1)]
        tris.append(np.stack([top0, bot0, bot1], 1))
        tris.append(np.stack([top0, bot1, top1], 1))
    tri = np.concatenate(tris)
    if left:
        tri = tri * np.array([-1.0, 1.0, 1.0])
    return tri.reshape(-1, 3), np.arange(len(tri) * 3).reshape(-1, 3)


def _palm_faces(scale: float, thickness_m: float, left: bool) -> list[np.ndarray]:
    """The slab's flat faces as polygons (n, 3) in hand-local coordinates, independent of any
    triangulation: back of the hand, palm, and one rectangle per outline edge."""
    outline = _PALM_OUTLINE * scale
    h = thickness_m / 2
    faces = [np.c_[outline, np.full(len(outline), h)], np.c_[outline, np.full(len(outline), -h)]]
    for p, q in zip(outline, np.roll(outline, -1, 0)):
        faces.append(np.array([[*p, h], [*q, h], [*q, -h], [*p, -h]]))
    if left:
        faces = [f * np.array([-1.0, 1.0, 1.0]) for f in faces]
    return faces


@dataclass
class Cone:
    """A truncated cone about a straight axis, at every time step: the points

        base + axis * (l0 + (l1 - l0) w) + (r0 + (r1 - r0) w) (cos(phi) u + sin(phi) v),  w in [0, 1],

    (r1 = 0: a cone to its apex). Facets: ``sides`` around (the first one centred on phi = 2 pi
    (0.5 + turn) / sides, as :func:`frustum` lays them), ``rings`` along."""

    base: np.ndarray  # (T, 3)
    axis: np.ndarray  # (T, 3) unit
    u: np.ndarray  # (T, 3) unit, perpendicular to axis
    v: np.ndarray  # (T, 3) = axis x u
    l0: np.ndarray  # (T,) metres along the axis
    l1: np.ndarray  # (T,)
    r0: float
    r1: float
    sides: int
    rings: int
    turn: float

    def surface(self, phi: np.ndarray, w: np.ndarray, steps: np.ndarray | slice = slice(None),
                normals: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Points (S, N, 3) and outward unit normals (S, N, 3) at parameters phi, w (N,), at ``steps``."""
        u, v, axis = self.u[steps], self.v[steps], self.axis[steps]
        l0, l1 = self.l0[steps], self.l1[steps]
        radial = np.cos(phi)[None, :, None] * u[:, None, :] + np.sin(phi)[None, :, None] * v[:, None, :]
        along = l0[:, None] + (l1 - l0)[:, None] * w[None, :]
        r = self.r0 + (self.r1 - self.r0) * w
        points = self.base[steps][:, None, :] + axis[:, None, :] * along[..., None] + r[None, :, None] * radial
        if not normals:
            return points, None
        slope = (self.r1 - self.r0) / (l1 - l0)  # (S,) d radius / d axial position
        return points, unit_vectors(radial - slope[:, None, None] * axis[:, None, :])

    def area(self) -> float:
        """Lateral area at the first step (m^2)."""
        return float(self.patch_area(0.0, 2 * np.pi, 0.0, 1.0, slice(0, 1))[0, 0])

    def patch_area(self, phi0: np.ndarray | float, phi1: np.ndarray | float, w0: np.ndarray | float,
                   w1: np.ndarray | float, steps: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Area (S, N) of the surface over [phi0, phi1] x [w0, w1] (m^2): the slant length times the
        mean radius times the angle."""
        slant = np.hypot(self.l1[steps] - self.l0[steps], self.r1 - self.r0)[:, None]
        r_mean = self.r0 + (self.r1 - self.r0) * 0.5 * (np.asarray(w0) + np.asarray(w1))
        return slant * (np.asarray(w1) - np.asarray(w0)) * r_mean * (np.asarray(phi1) - np.asarray(phi0))

    def facet_of(self, phi: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Index (side + sides * ring) of the facet whose parameter domain holds (phi, w)."""
        s = np.floor(np.mod(phi / (2 * np.pi) * self.sides - 0.5 - self.turn, self.sides)).astype(int) % self.sides
        ring = np.clip(np.floor(w * self.rings).astype(int), 0, self.rings - 1)
        return s + self.sides * ring


@dataclass
class Part:
    """One named part of one hand: a list of cones (a bone and its cap, the forearm) or a flat slab."""

    name: str
    slot: int
    mesh_vertices: np.ndarray  # (T, V, 3) the facets' corners (the ray caster's triangles)
    mesh_faces: np.ndarray  # (F, 3)
    cones: list[Cone] = field(default_factory=list)
    # flat slab (the palm): template triangles, their rigid motion and the slab's faces as polygons
    slab_triangles: np.ndarray | None = None  # (F, 3, 3) hand-local, one per facet
    slab_faces: list[np.ndarray] = field(default_factory=list)
    origin: np.ndarray | None = None  # (T, 3)
    rotation: np.ndarray | None = None  # (T, 3, 3) hand-local -> radar

    @property
    def n_facets(self) -> int:
        if self.cones:
            return sum(c.sides * c.rings for c in self.cones)
        return len(self.slab_triangles)

    def area(self) -> float:
        if self.cones:
            return sum(c.area() for c in self.cones)
        return sum(polygon_area(f) for f in self.slab_faces)

    def to_radar(self, local: np.ndarray) -> np.ndarray:
        """Hand-local points (..., 3) of the slab -> radar frame (T, ..., 3)."""
        flat = local.reshape(-1, 3)
        out = self.origin[:, None, :] + np.einsum("tij,nj->tni", self.rotation, flat)
        return out.reshape((len(self.origin),) + local.shape)


def polygon_area(poly: np.ndarray) -> float:
    """Area (m^2) of a flat polygon (n, 3) in metres."""
    c = poly.mean(0)
    return 0.5 * float(np.linalg.norm(np.cross(poly - c, np.roll(poly, -1, 0) - c).sum(0)))


def _revolved(a: np.ndarray, b: np.ndarray, up: np.ndarray, r0: float, r1: float, sides: int, rings: int,
              cap: bool, turn: float) -> list[Cone]:
    """The cones of a tapered cylinder from a to b (and its fingertip cap), framed as :func:`frustum`."""
    e = unit_vectors(b - a)
    u = unit_vectors(up - (up * e).sum(-1, keepdims=True) * e)
    v = np.cross(e, u)
    length = np.linalg.norm(b - a, axis=-1)
    cones = [Cone(a, e, u, v, np.zeros_like(length), length, r0, r1, sides, rings, turn)]
    if cap:
        cones.append(Cone(a, e, u, v, length, length + CAP_HEIGHT * r1, r1, 0.0, sides, 1, turn))
    return cones


def build_parts(pose: Pose, effects: Effects, scene: Scene) -> list[Part]:
    """Finger bones, palm slab and forearm of every present hand at every pose time."""
    geom = pose.geometry
    parts = []
    for s in np.flatnonzero(pose.present):
        j = pose.joints[:, s]
        rot = pose.rotations[:, s]
        dorsal = rot[:, :, 2]
        for (a, b), bname in zip(BONES, BONE_NAMES):
            chain = 0 if b <= 4 else (b - 1) // 4  # thumb, index .. pinky
            r_base = geom.finger_radius_m[chain]
            if a == 0:  # metacarpal, inside the palm
                r0 = r1 = 0.8 * r_base
            else:
                pos = a - 1 if chain == 0 else (a - 1) % 4  # 0 for the bone at the chain base
                r0 = r_base * (1 - 0.25 * pos / 3)
                r1 = r_base * (1 - 0.25 * (pos + 1) / 3)
            tip = b in (4, 8, 12, 16, 20)
            v, f = frustum(j[:, a], j[:, b], dorsal, r0, r1, scene.finger_sides, scene.finger_rings, cap_end=tip,
                           turn=scene.facet_turn)
            cones = _revolved(j[:, a], j[:, b], dorsal, r0, r1, scene.finger_sides, scene.finger_rings, tip,
                              scene.facet_turn)
            parts.append(Part(bname, int(s), v, f, cones=cones))
        if effects.palm.enabled:
            left = s == 1
            pv, pf = palm_template(geom.scale, effects.palm.thickness_m, scene.palm_subdivisions, left=left,
                                   turn=scene.facet_turn)
            part = Part("palm", int(s), np.zeros((len(j), 0, 3)), pf, slab_triangles=pv[pf],
                        slab_faces=_palm_faces(geom.scale, effects.palm.thickness_m, left), origin=j[:, 0],
                        rotation=rot)
            part.mesh_vertices = part.to_radar(pv)
            parts.append(part)
        if effects.forearm.enabled:
            elbow = np.broadcast_to(pose.elbows[s], j[:, 0].shape)
            fa = effects.forearm
            r0, r1 = fa.radius_elbow_m * geom.scale, fa.radius_wrist_m * geom.scale
            v, f = frustum(elbow, j[:, 0], dorsal, r0, r1, scene.forearm_sides, scene.forearm_rings,
                           turn=scene.facet_turn)
            cones = _revolved(elbow, j[:, 0], dorsal, r0, r1, scene.forearm_sides, scene.forearm_rings, False,
                              scene.facet_turn)
            parts.append(Part("forearm", int(s), v, f, cones=cones))
    return parts


@dataclass
class Surfaces:
    """Triangle surfaces of the scene over time (the facets, as the ray caster sees them)."""

    vertices: np.ndarray  # (T, V, 3) metres, radar frame
    faces: np.ndarray  # (F, 3)
    part: np.ndarray  # (F,) index into part_names
    slot: np.ndarray  # (F,) hand slot 0 right / 1 left
    part_names: list[str] = field(default_factory=list)

    @property
    def triangles(self) -> np.ndarray:
        return self.vertices[:, self.faces]  # (T, F, 3, 3)


def surfaces_of(parts: list[Part]) -> Surfaces:
    """The parts' facets as one triangle surface, every face wound outwards (parts are convex)."""
    verts, faces, part, slot = [], [], [], []
    names: list[str] = []
    n_v = 0
    for p in parts:
        v, f = p.mesh_vertices, p.mesh_faces
        tri = v[0][f]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        inward = ((tri.mean(1) - v[0].mean(0)) * n).sum(-1) < 0
        f = np.where(inward[:, None], f[:, ::-1], f)
        if p.name not in names:
            names.append(p.name)
        verts.append(v)
        faces.append(f + n_v)
        part.append(np.full(len(f), names.index(p.name)))
        slot.append(np.full(len(f), p.slot))
        n_v += v.shape[1]
    return Surfaces(np.concatenate(verts, 1), np.concatenate(faces), np.concatenate(part), np.concatenate(slot), names)


OCCLUDER_SIDES = 12  # the ray caster's cylinders: inscribed 12-gons (within 3.4 % of the radius, 0.3 mm on a finger)


def occluders_of(parts: list[Part]) -> Surfaces:
    """The smooth surfaces as the ray caster's triangles, at a fixed resolution of their own (every
    cone OCCLUDER_SIDES sides, seam at phi = 0; the flat slab as its facets, exact whatever their
    layout), so that shadows do not depend on the scene's facets."""
    occ = []
    for p in parts:
        if not p.cones:
            occ.append(p)
            continue
        verts, faces, n_v = [], [], 0
        for c in p.cones:
            phi = 2 * np.pi * np.arange(OCCLUDER_SIDES) / OCCLUDER_SIDES
            ring = [c.surface(phi, np.full(OCCLUDER_SIDES, w), slice(None), False)[0] for w in (0.0, 1.0)]
            verts += ring
            i = np.arange(OCCLUDER_SIDES)
            j = (i + 1) % OCCLUDER_SIDES
            faces.append(np.r_[np.c_[i, j, j + OCCLUDER_SIDES], np.c_[i, j + OCCLUDER_SIDES, i + OCCLUDER_SIDES]] + n_v)
            n_v += 2 * OCCLUDER_SIDES
        occ.append(Part(p.name, p.slot, np.concatenate(verts, 1), np.concatenate(faces)))
    return surfaces_of(occ)


def build_surfaces(pose: Pose, effects: Effects, scene: Scene) -> Surfaces:
    """Finger bones, palm slab and forearm of every present hand at every pose time, as facets."""
    return surfaces_of(build_parts(pose, effects, scene))
