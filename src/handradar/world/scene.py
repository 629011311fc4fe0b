"""The radar scene: hands and forearms as smooth surfaces, their returns, shadowing and multipath.

Surfaces. Every part is a smooth surface rebuilt at each physics step (``scene.rate_hz``): finger
bones as tapered cylinders (fingertips capped by a cone), the palm and back of the hand as a flat
slab whose outline runs through the wrist and the knuckles, the forearm as a truncated cone from the
wrist to an elbow fixed per recording. The scene's facets (``finger_sides`` x ``finger_rings``,
``forearm_sides`` x ``forearm_rings``, ``palm_subdivisions``) tessellate these surfaces into the
renderer's tracks (one range and one complex amplitude per facet and chirp) and into the elements
of the surface integral; they are not scatterers, so where the facets lie (``scene.facet_turn``
lays them out differently) changes a spectrogram by little more than rounding
(benchmarks/world_convergence.py).

Coherent return (physical optics): the surface integral, in ADC counts,

    A = K sqrt(4 pi) / lambda * Gamma * integral over the lit surface of cos(theta) G / R^2 vis exp(+2 j k R) dA,

Gamma the skin's amplitude reflectivity (``scene.skin_reflectivity``, the mirror-like part of its
glossy response), theta the incidence, G the antenna gain, vis the shadowing, K the radar-equation
scale below. A flat plate of area A at normal incidence in its far field has sigma = 4 pi Gamma^2
A^2 / lambda^2, a long cylinder of radius a broadside 2 pi a L^2 Gamma^2 / lambda. Elements:

- a cylinder (or cap cone) facet is cut into strips at most 30 deg wide and, along the axis,
  segments whose near-field phase departs from linear by at most ``scene.po_phase_tol_rad`` at
  ``scene.po_ref_range_m``. Across a strip the integral is exact: the phase is quadratic through
  its two sides and its centre, cos(theta) a shifted cosine of the angle around the axis, and the
  integral over the lit part three Fresnel integrals (Strips.across, at the cast steps). Along it
  the phase is quadratic too (the near field), integrated to first order in its small curvature
  at every chirp (:func:`strip_along_factor`);
- a palm facet (flat) is cut into sub-triangles within half that tolerance (their phase is taken
  linear), each a closed form from its three corners' phases (handradar.world.optics.triangle_factor).

Incoherent return (skin texture). Skin is rough and layered on the scale of the wavelength; its
glossy/diffuse response per unit area (``skin_diffuse``, ``skin_specular``, ``specular_exponent``;
zero for back-facing surface, theta from the surface normal)

    sigma0(theta) = rho_d cos(theta) + rho_s cos(theta)^m

is carried by texture points fixed on the smooth surfaces (``scene.texture_per_cm2`` per cm^2,
uniform over each part, drawn from the recording's scene seed, independent of the facets), each
standing for its share dA of the part's area with amplitude K sqrt(sigma0 dA) G / R^2 vis and a
random phase of its own. Bistatic bounces use the half-vector of the two directions.

The radar equation, in ADC counts: A = K sqrt(sigma) G(direction) / R^2, K = ref_counts * (0.3 m)^2 /
sqrt(0.01 m^2); a double bounce radar -> P -> Q -> radar (Friis on each leg)

    A = K sqrt(sigma_P sigma_Q / (4 pi)) sqrt(G_P G_Q) / (|P| |PQ| |Q|)   at range (|P| + |PQ| + |Q|) / 2.

Surface inside another part's solid (a phalanx where it meets the next, the metacarpals inside the
palm slab) is no surface: it neither scatters nor is lit, whatever the occlusion setting.
Shadowing: a ray from the antenna to the centre of every front-facing element and texture point,
Embree, against the smooth surfaces tessellated finely on their own (``occluders_of``), at
``scene.visibility_rate_hz``. Double bounces: hand-table-hand (the table is a mirror a little
below the antenna: Q is replaced by its image Q') and hand-hand, between ``samples_per_hand`` lit
texture points of each hand; their radar legs use the points' visibility, the bounce legs are not
ray-cast. The strongest ``n_paths`` are kept.

``scene.scattering: bone_points`` builds the direct returns from discrete point scatterers with
an RCS law of their own instead (handradar.world.points, :func:`point_tracks`); the bounces, the
shadowing and the static clutter are the same.

Tracks: one per facet, at the mean range of its elements, with the complex sum of its elements
and texture points, each taken relative to that range with the wavenumber :func:`group_wavenumber`
(the slope of the phase that the chain's range FFT sees), so a facet's track reproduces its
elements in every range bin to first order in their spread. Weights (reflectivity, incidence,
gain, 1/R^2, shadow) are evaluated at the cast steps, ranges and phase steps at every physics
step; :class:`SurfaceTracks` evaluates the sums at any instant (the renderer: every chirp).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import trimesh
from scipy.interpolate import CubicSpline

from handradar.hand.skeleton import BONE_NAMES, BONES
from handradar.radar.config import SPEED_OF_LIGHT_M_S, RadarConfig
from handradar.radar.signal import carrier_phase_rad
from handradar.world.config import AntennaPattern, Effects, Scene, StaticClutter
from handradar.world.kinematics import Pose
from handradar.world.optics import SERIES_BELOW_RAD, quadratic_integral
from handradar.world.points import bone_points, face_normals, point_rcs

REF_RANGE_M = 0.3
REF_RCS_M2 = 0.01
CAP_HEIGHT = 0.9  # fingertip cap: a cone of height 0.9 r beyond the last joint
RAY_TOLERANCE_M = 2e-4  # a hit this close to the point itself is the point's own surface

# kinds of scatterer columns
DIRECT, BOUNCE, STATIC = 0, 1, 2


# ---- surfaces ------------------------------------------------------------------------------------
def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.sqrt(np.einsum("...i,...i->...", v, v)), 1e-12)[..., None]


def frustum(a: np.ndarray, b: np.ndarray, up: np.ndarray, r0: float, r1: float, sides: int, rings: int,
            cap_end: bool = False, turn: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Tapered cylinder from a to b (T, 3): vertices (T, V, 3) and faces (F, 3); ``up`` fixes the seam,
    ``turn`` rotates the facets about the axis by that fraction of one side (same shape, other facets)."""
    e = _unit(b - a)
    u = _unit(up - (up * e).sum(-1, keepdims=True) * e)
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
        return points, _unit(radial - slope[:, None, None] * axis[:, None, :])

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
        return sum(_polygon_area(f) for f in self.slab_faces)

    def to_radar(self, local: np.ndarray) -> np.ndarray:
        """Hand-local points (..., 3) of the slab -> radar frame (T, ..., 3)."""
        flat = local.reshape(-1, 3)
        out = self.origin[:, None, :] + np.einsum("tij,nj->tni", self.rotation, flat)
        return out.reshape((len(self.origin),) + local.shape)


def _polygon_area(poly: np.ndarray) -> float:
    c = poly.mean(0)
    return 0.5 * float(np.linalg.norm(np.cross(poly - c, np.roll(poly, -1, 0) - c).sum(0)))


def _revolved(a: np.ndarray, b: np.ndarray, up: np.ndarray, r0: float, r1: float, sides: int, rings: int,
              cap: bool, turn: float) -> list[Cone]:
    """The cones of a tapered cylinder from a to b (and its fingertip cap), framed as :func:`frustum`."""
    e = _unit(b - a)
    u = _unit(up - (up * e).sum(-1, keepdims=True) * e)
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


# ---- physical-optics elements ---------------------------------------------------------------------
def group_wavenumber(radar: RadarConfig) -> float:
    """Wavenumber (rad/m) of the phase slope a reflector shows in the chain's range bins.

    A reflector at R contributes exp(+j 4 pi R / lambda_0) exp(j 2 pi nu(R) n) at ADC sample n
    (handradar.radar.signal's convention); the windowed range FFT of a symmetric window weighs the
    samples about n = (N - 1) / 2, so in every range bin the phase rises by 2 k_g per metre with
    k_g = 2 pi / lambda_0 + pi (N - 1) S / (c f_s) (the wavenumber at the sampling centre). Elements
    summed into one facet track take their phase relative to the track with k_g."""
    return 0.5 * (carrier_phase_rad(radar, 1.0)
                  + 2 * np.pi * (radar.n_samples - 1) * radar.slope_hz_per_s / (SPEED_OF_LIGHT_M_S * radar.sample_rate_hz))


def element_size_m(scene: Scene, k: float, radius_m: float | None = None, tol_scale: float = 1.0) -> float:
    """Largest element size (m) whose round-trip phase departs from linear by at most
    ``tol_scale * po_phase_tol_rad``: 2 k s^2 / (8 rho) <= tol, rho the radius of the surface's
    curvature (``radius_m``, none for flat) combined with the near field at ``po_ref_range_m``."""
    inv_rho = 1.0 / scene.po_ref_range_m + (0.0 if radius_m is None else 1.0 / radius_m)
    return math.sqrt(4.0 * tol_scale * scene.po_phase_tol_rad / (k * inv_rho))


STRIP_MAX_ARC_RAD = np.pi / 6  # a strip spans at most 30 deg of its cylinder (its quadratic phase holds)


@dataclass
class Strips:
    """The physical-optics strips of one cone: its facets cut into n_phi strips around (each at most
    STRIP_MAX_ARC_RAD) and n_w segments along (near field within ``po_phase_tol_rad``). Strip (r, c)
    spans phi in [phi_b[c], phi_b[c + 1]] and w in [w_b[r], w_b[r + 1]]."""

    cone: Cone
    part: int
    facet0: int  # global index of the cone's first facet
    n_phi: int
    n_w: int

    @property
    def cols(self) -> int:
        return self.cone.sides * self.n_phi

    @property
    def rows(self) -> int:
        return self.cone.rings * self.n_w

    @property
    def size(self) -> int:
        return self.cols * self.rows

    def phi_b(self) -> np.ndarray:
        return 2 * np.pi * (np.arange(self.cols + 1) / self.n_phi + 0.5 + self.cone.turn) / self.cone.sides

    def w_b(self) -> np.ndarray:
        return np.arange(self.rows + 1) / self.rows

    def grid(self, idx: np.ndarray | slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) of the strips ``idx`` (row-major numbering)."""
        r, c = np.meshgrid(np.arange(self.rows), np.arange(self.cols), indexing="ij")
        return r.ravel()[idx], c.ravel()[idx]

    def facet(self, idx: np.ndarray | slice = slice(None)) -> np.ndarray:
        r, c = self.grid(idx)
        return self.facet0 + c // self.n_phi + self.cone.sides * (r // self.n_w)

    def _at(self, idx: np.ndarray | slice, dphi: float, dw: float) -> tuple[np.ndarray, np.ndarray]:
        """Parameters (phi, w) of a point of each strip: dphi, dw in [0, 1] across and along it."""
        r, c = self.grid(idx)
        pb, wb = self.phi_b(), self.w_b()
        return pb[c] + dphi * (pb[c + 1] - pb[c]), wb[r] + dw * (wb[r + 1] - wb[r])

    def centres(self, steps: np.ndarray | slice, idx: np.ndarray | slice = slice(None),
                normals: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """The surface at each strip's parameter centre (S, E, 3) and its normal."""
        return self.cone.surface(*self._at(idx, 0.5, 0.5), steps, normals)

    def ranges(self, steps: np.ndarray | slice, idx: np.ndarray | slice, dphi: float, dw: float) -> np.ndarray:
        """Range (S, E) of a point of each strip (see _at)."""
        return np.linalg.norm(self.cone.surface(*self._at(idx, dphi, dw), steps, False)[0], axis=-1)

    def areas(self, steps: np.ndarray | slice, idx: np.ndarray | slice = slice(None)) -> np.ndarray:
        r, c = self.grid(idx)
        pb, wb = self.phi_b(), self.w_b()
        return self.cone.patch_area(pb[c], pb[c + 1], wb[r], wb[r + 1], steps)

    def across(self, steps: np.ndarray, k: float, centre: np.ndarray) -> np.ndarray:
        """(S, E) complex: the mean over each strip's width of cos(theta) exp(+2 j k (R - R_centre)),
        theta the incidence, over the part of the strip that faces the radar (0 where none does).

        Across a strip (x = -1/2 .. 1/2, phi = phi_c + alpha x) the phase is quadratic through its two
        sides and its centre (step s, curvature q), and cos(theta) = n(phi) . u = A cos(phi - phi*) + C
        (u towards the radar from the centre, n the cone's normal), so the integral is three exact
        quadratic-phase integrals (optics.quadratic_integral), with slopes s + alpha, s - alpha, s,
        taken over the lit interval A cos(phi - phi*) + C >= 0."""
        cone = self.cone
        r_c = np.linalg.norm(centre, axis=-1)
        to_radar = -centre / r_c[..., None]
        slope = ((cone.r1 - cone.r0) / (cone.l1[steps] - cone.l0[steps]))[:, None]
        norm = np.sqrt(1 + slope ** 2)
        cu = np.einsum("sej,sj->se", to_radar, cone.u[steps])
        cv = np.einsum("sej,sj->se", to_radar, cone.v[steps])
        amp = np.hypot(cu, cv) / norm
        const = -slope * np.einsum("sej,sj->se", to_radar, cone.axis[steps]) / norm
        _, c = self.grid()
        pb = self.phi_b()
        alpha = pb[1] - pb[0]
        beta = np.angle(np.exp(1j * (0.5 * (pb[c] + pb[c + 1]) - np.arctan2(cv, cu))))  # centre - phi*, wrapped
        half = np.arccos(np.clip(-const / np.maximum(amp, 1e-12), -1.0, 1.0))  # lit: |phi - phi*| <= half
        lo = np.clip((-half - beta) / alpha, -0.5, 0.5)
        hi = np.clip((half - beta) / alpha, -0.5, 0.5)
        lit = hi > lo
        out = np.zeros(lit.shape, np.complex128)
        cols = np.flatnonzero(lit.any(0))
        if not cols.size:
            return out
        side0, side1 = self.ranges(steps, cols, 0.0, 0.5), self.ranges(steps, cols, 1.0, 0.5)
        on = lit[:, cols]
        s = (2 * k * (side1 - side0))[on]
        q = (4 * k * (side0 + side1 - 2 * r_c[:, cols]))[on]
        lo, hi, beta, amp, const = (x[:, cols][on] for x in (lo, hi, beta, amp, const))
        vals = (0.5 * amp * (np.exp(1j * beta) * quadratic_integral(s + alpha, q, lo, hi)
                             + np.exp(-1j * beta) * quadratic_integral(s - alpha, q, lo, hi))
                + const * quadratic_integral(s, q, lo, hi))
        sub = np.zeros(on.shape, np.complex128)
        sub[on] = vals
        out[:, cols] = sub
        return out


@dataclass
class Elements:
    """Flat or gently curved physical-optics elements on the smooth surfaces, grouped by facet.

    strips: the cones' strips (:class:`Strips`). Triangles (palm elements): ``tris`` (Et, 3) corner
    indices into ``tri_vertices`` (T, V, 3), their centroids (T, Et, 3), outward normals in the
    slab's frame and the part that carries them. Facet indices are global (over every part),
    labels ``slot:part`` per facet."""

    strips: list[Strips]
    tri_vertices: np.ndarray
    tris: np.ndarray
    tri_centre: np.ndarray
    tri_facet: np.ndarray
    tri_normal_local: np.ndarray
    tri_part: np.ndarray
    facet_label: np.ndarray  # (F,) str
    facet_slot: np.ndarray  # (F,)


def _triangle_grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric coordinates (P, 3) of the uniform n x n subdivision of a triangle and its n^2
    sub-triangles (n^2, 3) as point indices."""
    idx = {}
    bary = []
    for i in range(n + 1):
        for j in range(n + 1 - i):
            idx[i, j] = len(bary)
            bary.append((1 - (i + j) / n, i / n, j / n))
    tris = []
    for i in range(n):
        for j in range(n - i):
            tris.append((idx[i, j], idx[i + 1, j], idx[i, j + 1]))
            if i + j < n - 1:
                tris.append((idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]))
    return np.asarray(bary), np.asarray(tris, dtype=np.int64)


def po_elements(parts: list[Part], scene: Scene, k: float) -> Elements:
    """Cut every facet into physical-optics elements: cone facets into strips of at most 30 deg
    around and, along, segments whose near-field phase departs from linear by at most
    ``scene.po_phase_tol_rad``; palm triangles into sub-triangles of that size."""
    strips, verts, tris, tcentre, tfacet, tnormal, tpart = [], [], [], [], [], [], []
    labels, slots = [], []
    n_v = n_f = 0
    along = element_size_m(scene, k)  # strips: the along factor is exact to second order in the curvature
    flat = element_size_m(scene, k, tol_scale=0.5)  # triangles: linear phase, so half the tolerance
    t_steps = parts[0].mesh_vertices.shape[0] if parts else 0
    for ip, p in enumerate(parts):
        f0 = n_f
        for cone in p.cones:
            slant = math.hypot(float(np.max(cone.l1 - cone.l0)), cone.r1 - cone.r0) / cone.rings
            n_phi = max(1, math.ceil(2 * np.pi / cone.sides / STRIP_MAX_ARC_RAD - 1e-9))
            strips.append(Strips(cone, ip, n_f, n_phi, max(1, math.ceil(slant / along))))
            n_f += cone.sides * cone.rings
        if p.slab_triangles is not None:
            tri = p.slab_triangles  # (F, 3, 3) hand-local
            centre = np.r_[p.slab_faces[0][:, :2].mean(0), 0.0]  # inside the convex slab
            locals_, cents = [], []
            for fi, t in enumerate(tri):
                edge = max(np.linalg.norm(t[1] - t[0]), np.linalg.norm(t[2] - t[1]), np.linalg.norm(t[0] - t[2]))
                bary, sub = _triangle_grid(max(1, math.ceil(edge / flat)))
                local = bary @ t  # (P, 3)
                n_loc = np.cross(t[1] - t[0], t[2] - t[0])
                n_loc = n_loc / np.linalg.norm(n_loc)
                if n_loc @ (t.mean(0) - centre) < 0:
                    n_loc = -n_loc
                locals_.append(local)
                cents.append(local[sub].mean(1))
                tris.append(sub + n_v)
                tfacet.append(np.full(len(sub), n_f + fi))
                tnormal.append(np.broadcast_to(n_loc, (len(sub), 3)))
                tpart.append(np.full(len(sub), ip))
                n_v += len(local)
            verts.append(p.to_radar(np.concatenate(locals_)))  # one rigid motion for the whole slab
            tcentre.append(p.to_radar(np.concatenate(cents)))
            n_f += len(tri)
        labels += [f"{p.slot}:{p.name}"] * (n_f - f0)
        slots += [p.slot] * (n_f - f0)

    def cat(xs: list, shape: tuple, dtype: type = np.float64, axis: int = 0) -> np.ndarray:
        return np.concatenate(xs, axis) if xs else np.zeros(shape, dtype)

    return Elements(strips, cat(verts, (t_steps, 0, 3), axis=1), cat(tris, (0, 3), np.int64),
                    cat(tcentre, (t_steps, 0, 3), axis=1), cat(tfacet, (0,), np.int64), cat(tnormal, (0, 3)),
                    cat(tpart, (0,), np.int64), np.asarray(labels, dtype=str), np.asarray(slots, dtype=int))


# ---- skin texture ----------------------------------------------------------------------------------
@dataclass
class Texture:
    """Texture points fixed on the smooth surfaces: positions and outward normals (T, P, 3), the
    area each stands for (P,) m^2, its random phase (P,) rad, the facet whose track carries it and
    its hand slot."""

    points: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    phase: np.ndarray
    facet: np.ndarray
    slot: np.ndarray
    part: np.ndarray  # (P,) index of the part


def _cone_samples(rng: np.random.Generator, cone: Cone, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n parameters (phi, w) uniform over a cone's area (the radius is linear in w)."""
    phi = rng.uniform(0, 2 * np.pi, n)
    u = rng.random(n)
    r0, r1 = cone.r0, cone.r1
    if abs(r1 - r0) < 1e-9 * max(r0, r1):
        w = u
    else:  # inverse of the area fraction (r0 w + (r1 - r0) w^2 / 2) / ((r0 + r1) / 2)
        w = (np.sqrt(r0 ** 2 + (r1 ** 2 - r0 ** 2) * u) - r0) / (r1 - r0)
    return phi, np.clip(w, 0.0, 1.0)


def _polygon_samples(rng: np.random.Generator, poly: np.ndarray, n: int) -> np.ndarray:
    """n points (n, 3) uniform over a flat convex polygon (a fan from its first vertex)."""
    a, b, c = poly[0], poly[1:-1], poly[2:]
    w = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    k = rng.choice(len(w), size=n, p=w / w.sum())
    s, t = rng.random(n), rng.random(n)
    flip = s + t > 1
    s, t = np.where(flip, 1 - s, s), np.where(flip, 1 - t, t)
    return a + s[:, None] * (b[k] - a) + t[:, None] * (c[k] - a)


def skin_texture(parts: list[Part], scene: Scene, rng: np.random.Generator) -> Texture:
    """Texture points on every part, ``scene.texture_per_cm2`` per cm^2 of its smooth surface; which
    facet's track carries a point is its only link to the tessellation."""
    pts, nrm, area, facet, slot, owner = [], [], [], [], [], []
    n_f = 0
    density = scene.texture_per_cm2 * 1e4  # per m^2
    for ip, p in enumerate(parts):
        n_before = sum(len(a) for a in area)
        if p.cones:
            f0 = n_f
            for cone in p.cones:
                n = max(1, round(cone.area() * density))
                phi, w = _cone_samples(rng, cone, n)
                x, nn = cone.surface(phi, w)
                pts.append(x)
                nrm.append(nn)
                area.append(np.full(n, cone.area() / n))
                facet.append(f0 + cone.facet_of(phi, w))
                slot.append(np.full(n, p.slot))
                f0 += cone.sides * cone.rings
        else:
            centre = np.r_[p.slab_faces[0][:, :2].mean(0), 0.0]
            tri_c = p.slab_triangles.mean(1)  # facet centroids, hand-local
            for poly in p.slab_faces:
                n = max(1, round(_polygon_area(poly) * density))
                local = _polygon_samples(rng, poly, n)
                pts.append(p.to_radar(local))
                nrm.append(face_normals(poly, centre, p.rotation, n))
                area.append(np.full(n, _polygon_area(poly) / n))
                near = np.linalg.norm(local[:, None] - tri_c[None], axis=-1).argmin(1)
                facet.append(n_f + near)
                slot.append(np.full(n, p.slot))
        n_f += p.n_facets
        owner.append(np.full(sum(len(a) for a in area) - n_before, ip))
    phase = rng.uniform(0, 2 * np.pi, sum(len(a) for a in area))
    return Texture(np.concatenate(pts, 1), np.concatenate(nrm, 1), np.concatenate(area), phase,
                   np.concatenate(facet), np.concatenate(slot), np.concatenate(owner))


# ---- facet geometry and returns -------------------------------------------------------------------
def facet_geometry(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangles (..., 3, 3) -> centroids (..., 3), unit normals (..., 3), areas (...)."""
    c = tri.mean(-2)
    n = np.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :])
    norm = np.linalg.norm(n, axis=-1)
    return c, n / np.maximum(norm, 1e-15)[..., None], 0.5 * norm


def facet_rcs(normal: np.ndarray, area: np.ndarray, u_in: np.ndarray, u_out: np.ndarray, scene: Scene) -> np.ndarray:
    """Glossy/diffuse skin RCS (m^2) of a piece of surface for incoming-from ``u_in`` and outgoing-to
    ``u_out`` unit directions: area * (rho_d sqrt(cos_in cos_out) + rho_s cos_h^m)."""
    c_in = np.clip((normal * u_in).sum(-1), 0.0, None)
    c_out = np.clip((normal * u_out).sum(-1), 0.0, None)
    h = _unit(u_in + u_out)
    c_h = np.clip((normal * h).sum(-1), 0.0, None) * (c_in > 0) * (c_out > 0)
    return area * (scene.skin_diffuse * np.sqrt(c_in * c_out) + scene.skin_specular * c_h ** scene.specular_exponent)


def pattern_exponents(p: AntennaPattern) -> tuple[float, float]:
    """cos^n exponents giving the half-power beamwidths in the azimuth (x-z) and elevation (y-z) planes."""
    return tuple(float(np.log(0.5) / np.log(np.cos(np.deg2rad(bw) / 2))) for bw in (p.hpbw_az_deg, p.hpbw_el_deg))


def antenna_gain(points: np.ndarray, p: AntennaPattern) -> np.ndarray:
    """Relative one-way power gain (boresight 1) towards points (..., 3) in the radar frame.

    G = cos(theta)^n(phi), n(phi) = n_az cos^2(phi) + n_el sin^2(phi), floored at ``floor_db``;
    a monostatic return is scaled by sqrt(G_tx G_rx) = G in amplitude.
    """
    if not p.enabled:
        return np.ones(points.shape[:-1])
    n_az, n_el = pattern_exponents(p)
    r = np.linalg.norm(points, axis=-1)
    cos_t = points[..., 2] / np.maximum(r, 1e-12)
    rho2 = np.maximum(points[..., 0] ** 2 + points[..., 1] ** 2, 1e-30)
    n = n_az * points[..., 0] ** 2 / rho2 + n_el * points[..., 1] ** 2 / rho2
    g = np.clip(cos_t, 0.0, None) ** n
    return np.maximum(g, 10 ** (p.floor_db / 10))


def amplitude_scale(scene: Scene) -> float:
    """K of A = K sqrt(sigma) G / R^2 (counts m / m): ``ref_counts`` for 0.01 m^2 at 0.3 m on boresight."""
    return scene.ref_counts * REF_RANGE_M ** 2 / np.sqrt(REF_RCS_M2)


# ---- buried surface -------------------------------------------------------------------------------
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


# ---- shadowing ---------------------------------------------------------------------------------------
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
    return _lerp(cast, cast_visibility(surfaces, cast, points[cast], front[cast]), front.shape[0])


# ---- tracks ----------------------------------------------------------------------------------------
def _segments(values: np.ndarray, facet: np.ndarray, n_facets: int) -> np.ndarray:
    """Sum the columns of values (N, E) by facet (E,), facet sorted: (N, n_facets)."""
    out = np.zeros((values.shape[0], n_facets), dtype=values.dtype)
    if facet.size:
        starts = np.flatnonzero(np.r_[True, facet[1:] != facet[:-1]])
        out[:, facet[starts]] = np.add.reduceat(values, starts, axis=1)
    return out


def _lerp_index(times: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    hi = np.clip(np.searchsorted(times, t, side="right"), 1, len(times) - 1)
    lo = hi - 1
    return lo, (t - times[lo]) / (times[hi] - times[lo])


STRIP, TRIANGLE, POINT = "strip", "triangle", "point"


def triangle_centroid_factor(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(1/A) integral of exp(j psi) over a triangle relative to the phase at its centroid, from the
    phase steps a = psi1 - psi0 and b = psi2 - psi0 (radians, float32 arrays): optics.triangle_factor
    around the middle phase, written out to keep the renderer's inner loop short."""
    zero = np.zeros_like(a)
    lo = np.minimum(np.minimum(a, b), zero)
    hi = np.maximum(np.maximum(a, b), zero)
    mid = a + b - lo - hi
    big, small = hi - mid, lo - mid  # >= 0, <= 0
    d = big - small
    wide = d >= SERIES_BELOW_RAD
    m = mid - (a + b) / 3  # the middle corner's phase relative to the centroid
    p1, p2 = m + 0.5 * big, m + 0.5 * small
    s1, s2 = _sinc32(0.5 * big), _sinc32(0.5 * small)
    num = (np.cos(p1) * s1 - np.cos(p2) * s2) + 1j * (np.sin(p1) * s1 - np.sin(p2) * s2)
    exact = num * (2 / np.where(wide, d, 1)).astype(a.dtype) * np.complex64(-1j)
    mean = (a + b) / 3
    var = (mean ** 2 + (a - mean) ** 2 + (b - mean) ** 2) / 12
    return np.where(wide, exact, (1 - 0.5 * var).astype(np.complex64))


def strip_along_factor(s: np.ndarray, q: np.ndarray) -> np.ndarray:
    """integral_{-1/2}^{1/2} exp(j (s x + q x^2)) dx to second order in the curvature q (float32):
    sinc(s / 2) + j q M2(s) - q^2 / 2 M4(s), Mn(s) = integral x^n cos(s x) dx (series below |s| = 3).
    The near field bends the phase along a strip by |q| / 4 <= po_phase_tol_rad; what is left out
    is at most |q|^3 / 2688 (the third-order term at s = 0) plus the series' first dropped term,
    |q| s^6 / 1658880 <= 4.4e-4 |q| just below |s| = 3 (tests/world/test_scene.py). Adding that
    term would change the world's data, so it waits for the next WORLD_VERSION."""
    half = np.float32(0.5) * s
    sn, cs = np.sin(half), np.cos(half)
    big = np.abs(s) > 3
    inv = np.float32(1) / np.where(big, s, np.float32(1))
    inv2 = inv * inv  # powers by products: numpy's ``x ** 3`` and up is a generic pow, 17x slower here
    sn1, cs2 = sn * inv, cs * inv2  # sin(s/2) / s, cos(s/2) / s^2
    s2 = s * s
    s4 = s2 * s2
    m2 = np.where(big, np.float32(0.5) * sn1 + 2 * cs2 - 4 * sn1 * inv2,
                  np.float32(1 / 12) - s2 / np.float32(160) + s4 / np.float32(10752))
    m4 = np.where(big, np.float32(0.125) * sn1 + cs2 - 6 * sn1 * inv2 - 24 * cs2 * inv2 + 48 * sn1 * inv2 * inv2,
                  np.float32(1 / 80) - s2 / np.float32(896) + s4 / np.float32(55296))
    out = np.empty(s.shape, np.complex64)
    out.real = _sinc32(half) - np.float32(0.5) * q * q * m4
    out.imag = q * m2
    return out


def _sinc32(x: np.ndarray) -> np.ndarray:
    """sin(x) / x in float32 (1 at 0)."""
    x = np.where(x == 0, np.float32(1e-20), x)
    return np.sin(x) / x


def _runs(index: np.ndarray) -> list[tuple[int, slice]]:
    """(value, slice) of each run of equal values in a sorted index array."""
    edges = np.flatnonzero(np.diff(index)) + 1
    starts, ends = np.r_[0, edges], np.r_[edges, len(index)]
    return [(int(index[s]), slice(int(s), int(e))) for s, e in zip(starts, ends)]


def _spline_eval(coef: np.ndarray, knots: np.ndarray, t: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Splines with coefficients coef (4, T - 1, E) over the uniform knots' indices, columns ``cols``,
    at sorted instants t -> (N, len(cols)); one Horner pass per knot interval touched."""
    x = np.clip((t - knots[0]) / (knots[1] - knots[0]), 0.0, len(knots) - 1.0)
    i = np.minimum(x.astype(np.int64), len(knots) - 2)
    h = (x - i)[:, None]
    out = np.empty((len(t), len(cols)))
    for seg, rows in _runs(i):
        c = coef[:, seg, cols]
        hh = h[rows]
        out[rows] = ((c[0] * hh + c[1]) * hh + c[2]) * hh + c[3]
    return out


def _lerp_eval(values: np.ndarray, knots: np.ndarray, t: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """values (K, E) at knots, columns ``cols``, interpolated linearly at sorted instants t."""
    lo, frac = _lerp_index(knots, t)
    out = np.empty((len(t), len(cols)), dtype=values.dtype)
    for k, rows in _runs(lo):
        v0, v1 = values[k, cols], values[k + 1, cols]
        out[rows] = v0 + (v1 - v0) * frac[rows, None].astype(values.real.dtype)
    return out


@dataclass
class ElementGroup:
    """Elements of one shape (strips, triangles or texture points), sorted by facet.

    At the physics times (T, E), splined: ``centre_ranges``, the range of each element's phase
    centre, and its phase steps across the element (radians; strip: along the cylinder, between its
    two ends; triangle: corner 1 and corner 2 minus corner 0). At the weight times (Tw, E),
    interpolated linearly: complex ``weights`` (counts; a strip's includes its exact quadratic-phase
    factor across the cylinder, a texture point's its random phase) and ``centres`` (radar frame,
    float32, for diagnostics)."""

    kind: str
    facet: np.ndarray
    centre_ranges: np.ndarray
    weights: np.ndarray
    step_a: np.ndarray | None = None
    step_b: np.ndarray | None = None
    centres: np.ndarray | None = None

    def subset(self, keep: np.ndarray, new_index: np.ndarray) -> ElementGroup:
        m = keep[self.facet]

        def pick(x: np.ndarray | None) -> np.ndarray | None:
            return None if x is None else x[:, m]

        return ElementGroup(self.kind, new_index[self.facet[m]], self.centre_ranges[:, m], self.weights[:, m],
                            pick(self.step_a), pick(self.step_b), pick(self.centres))

    @cached_property
    def splines(self) -> list[np.ndarray]:
        """Cubic-spline coefficients (4, T - 1, E) over the step index (not-a-knot, as CubicSpline) of
        the centre ranges and the phase steps."""
        t = np.arange(self.centre_ranges.shape[0])
        return [CubicSpline(t, x, axis=0).c for x in (self.centre_ranges, self.step_a, self.step_b) if x is not None]


@dataclass
class SurfaceTracks:
    """The facets' coherent sums, evaluated at any instant from their elements and texture points.

    times (T,) physics times (uniform), weight_times (Tw,) a subset of them; per group of elements
    the centre ranges are splined (cubic) and the weights and phase steps (reflectivity, incidence,
    gain, 1/R^2 and shadow: smooth) interpolated linearly to the requested instants; the facet
    centres' ranges facet_ranges (T, F) are the tracks' ranges."""

    times: np.ndarray
    weight_times: np.ndarray
    wavenumber: float  # rad/m, the relative phase exp(+2 j k (R - R_facet))
    groups: list[ElementGroup]
    facet_ranges: np.ndarray

    @property
    def n_facets(self) -> int:
        return self.facet_ranges.shape[1]

    @property
    def n_elements(self) -> int:
        return sum(g.facet.size for g in self.groups if g.kind != POINT)

    @property
    def n_points(self) -> int:
        return sum(g.facet.size for g in self.groups if g.kind == POINT)

    @cached_property
    def _facet_spline(self) -> CubicSpline:
        return CubicSpline(self.times, self.facet_ranges, axis=0)

    def amplitudes(self, times: np.ndarray) -> np.ndarray:
        """Complex amplitude (counts) of every facet track at ``times`` (any shape) -> (*shape, F),
        relative to the facet's own range (the renderer adds its carrier).

        The instants of one call should be close together (a frame): splines and linear
        interpolation are written as small matrix products over the knots they touch."""
        t = np.asarray(times, dtype=np.float64)
        flat = t.reshape(-1)
        order = np.argsort(flat, kind="stable")
        ts = flat[order]
        k = self.wavenumber
        r_f = self._facet_spline(ts)
        out = np.zeros((len(ts), self.n_facets), dtype=np.complex128)
        lo, _ = _lerp_index(self.weight_times, ts)
        knots = slice(int(lo.min()), int(lo.max()) + 2)
        for g in self.groups:
            act = np.flatnonzero((g.weights[knots] != 0).any(0))  # only what is lit somewhere in this stretch
            if not act.size:
                continue
            fac = g.facet[act]
            splines = g.splines
            rel = (_spline_eval(splines[0], self.times, ts, act) - r_f[:, fac]).astype(np.float32)  # from the facet
            phase = np.float32(2 * k) * rel
            val = _lerp_eval(g.weights, self.weight_times, ts, act) * (np.cos(phase) + 1j * np.sin(phase))
            if g.kind == STRIP:  # along the cylinder (the exact factor across it is in the weight)
                a, b = (_spline_eval(c, self.times, ts, act).astype(np.float32) for c in splines[1:])
                val *= strip_along_factor(a, b)
            elif g.kind == TRIANGLE:
                a, b = (_spline_eval(c, self.times, ts, act).astype(np.float32) for c in splines[1:])
                val *= triangle_centroid_factor(a, b)
            out += _segments(val, fac, self.n_facets)
        res = np.empty_like(out)
        res[order] = out
        return res.reshape(t.shape + (self.n_facets,))

    def subset(self, keep: np.ndarray) -> SurfaceTracks:
        """The tracks of the facets where ``keep`` (F,) is true (their elements and points only)."""
        new = np.cumsum(keep) - 1
        return SurfaceTracks(self.times, self.weight_times, self.wavenumber, [g.subset(keep, new) for g in self.groups],
                             self.facet_ranges[:, keep])


@dataclass
class ScatterTracks:
    """Scatterers at the physics rate: effective range (T, K) metres and complex amplitude (T, K) counts.

    kind: (K,) DIRECT / BOUNCE / STATIC; label: (K,) part name (``slot:part``) or path description.
    surface: when set, the first ``surface.n_facets`` columns are facet tracks whose amplitudes at
    any instant come from :meth:`SurfaceTracks.amplitudes` (``amplitudes`` holds them at ``times``);
    the other columns are point scatterers, amplitudes interpolated linearly.
    """

    times: np.ndarray
    ranges: np.ndarray
    amplitudes: np.ndarray
    kind: np.ndarray
    label: np.ndarray
    surface: SurfaceTracks | None = None

    @property
    def n_surface(self) -> int:
        return 0 if self.surface is None else self.surface.n_facets

    def select(self, mask: np.ndarray) -> ScatterTracks:
        """The columns where ``mask``; facet tracks are kept or dropped together."""
        mask = np.asarray(mask, bool)
        f = self.n_surface
        surface = self.surface
        if f:
            if mask[:f].all():
                pass
            elif not mask[:f].any():
                surface = None
            else:
                raise ValueError("select keeps all facet tracks or none; use SurfaceTracks.subset for some")
        return ScatterTracks(self.times, self.ranges[:, mask], self.amplitudes[:, mask], self.kind[mask],
                             self.label[mask], surface)

    @staticmethod
    def concat(parts: list[ScatterTracks]) -> ScatterTracks:
        """Columns side by side; a part with facet tracks must come first."""
        parts = [p for p in parts if p.kind.size]
        if any(p.surface is not None for p in parts[1:]):
            raise ValueError("only the first part of a concatenation may carry facet tracks")
        return ScatterTracks(parts[0].times, np.concatenate([p.ranges for p in parts], 1),
                             np.concatenate([p.amplitudes.astype(np.complex128) for p in parts], 1),
                             np.concatenate([p.kind for p in parts]), np.concatenate([p.label for p in parts]),
                             parts[0].surface)

    @cached_property
    def _range_spline(self) -> CubicSpline:
        return CubicSpline(self.times, self.ranges, axis=0)

    def at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ranges (cubic spline) and complex amplitudes at ``times`` (any shape) -> (*times.shape, K):
        facet tracks from their elements, point scatterers interpolated linearly."""
        t = np.asarray(times, dtype=np.float64)
        flat = t.reshape(-1)
        if flat.min() < self.times[0] - 1e-9 or flat.max() > self.times[-1] + 1e-9:
            raise ValueError(f"times {flat.min():.4f}..{flat.max():.4f} s outside the tracks "
                             f"{self.times[0]:.4f}..{self.times[-1]:.4f} s")
        ranges = self._range_spline(flat)
        lo, frac = _lerp_index(self.times, flat)
        f = self.n_surface
        amps = np.empty((len(flat), self.kind.size), dtype=np.complex128)
        pts = self.amplitudes[:, f:]
        amps[:, f:] = pts[lo] * (1 - frac)[:, None] + pts[lo + 1] * frac[:, None]
        if f:
            amps[:, :f] = self.surface.amplitudes(flat)
        shape = t.shape + (self.kind.size,)
        return ranges.reshape(shape), amps.reshape(shape)


def _sample_points(rng: np.random.Generator, slot: np.ndarray, lit: np.ndarray,
                   per_hand: int) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``per_hand`` of each hand's texture points that are ever lit, uniformly (the points are
    uniform over the surface, so this is an area-weighted draw of its lit part); returns their
    indices and how many candidates each one stands for.

    Every point gets a random priority whatever its lighting and the lit ones of highest priority
    are taken, so a point that gains or loses a sliver of light (another shadow edge) changes one
    pick, not the whole draw."""
    priority = rng.random(len(slot))
    idx, share = [], []
    for s in np.unique(slot):
        cand = np.flatnonzero((slot == s) & lit)
        if not cand.size:
            continue
        pick = np.sort(cand[np.argsort(priority[cand], kind="stable")[:per_hand]])
        idx.append(pick)
        share.append(np.full(len(pick), len(cand) / len(pick)))
    if not idx:
        return np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(idx), np.concatenate(share)


def bounce_paths(c: np.ndarray, n: np.ndarray, vis: np.ndarray, slot: np.ndarray, rep_area: np.ndarray,
                 effects: Effects, scene: Scene, rcs: Callable[..., np.ndarray] | None = None,
                 ) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Double-bounce paths between sampled surface points: ranges (T, P), amplitudes (T, P), labels.

    c, n: (T, M, 3) positions and normals of the sampled points; vis (T, M) their radar-leg visibility;
    rep_area (M,) the area each one stands for; rcs: their bistatic law (normal, area, u_in, u_out,
    scene) -> m^2, the skin's :func:`facet_rcs` unless given.
    """
    rcs = rcs or facet_rcs
    mp = effects.multipath
    k_amp = amplitude_scale(scene)
    gain = antenna_gain(c, effects.antenna_pattern)  # (T, M)
    r = np.linalg.norm(c, axis=-1)
    to_radar = -c / r[..., None]
    out_r, out_a, labels = [], [], []
    m = c.shape[1]
    i, j = np.triu_indices(m)
    pairs = []
    if mp.table:
        pairs.append(("table", i, j, True))
    if mp.hand_hand and len(np.unique(slot)) == 2:
        a = np.flatnonzero(slot == 0)
        b = np.flatnonzero(slot == 1)
        ii, jj = np.meshgrid(a, b, indexing="ij")
        pairs.append(("hand-hand", ii.ravel(), jj.ravel(), False))
    for name, pi, qi, table in pairs:
        p, q = c[:, pi], c[:, qi]
        if table:
            mirror = np.array([1.0, 1.0, -1.0])
            shift = np.array([0.0, 0.0, -2.0 * mp.table_below_m])
            q_img = q * mirror + shift
            p_img = p * mirror + shift
            leg = q_img - p
            u_out_p = _unit(leg)
            u_in_q = _unit(p_img - q)
            coef = mp.table_reflection * np.where(pi == qi, 1.0, 2.0)  # both orderings of distinct points
        else:
            leg = q - p
            u_out_p = _unit(leg)
            u_in_q = -u_out_p
            coef = np.full(len(pi), 2.0)
        d = np.linalg.norm(leg, axis=-1)
        s_p = rcs(n[:, pi], rep_area[pi], to_radar[:, pi], u_out_p, scene)
        s_q = rcs(n[:, qi], rep_area[qi], u_in_q, to_radar[:, qi], scene)
        amp = (k_amp * coef * np.sqrt(s_p * s_q / (4 * np.pi)) * np.sqrt(gain[:, pi] * gain[:, qi])
               / (r[:, pi] * np.maximum(d, 1e-3) * r[:, qi]) * vis[:, pi] * vis[:, qi])
        out_r.append((r[:, pi] + d + r[:, qi]) / 2)
        out_a.append(amp)
        labels += [name] * len(pi)
    if not out_r:
        return np.zeros((c.shape[0], 0)), np.zeros((c.shape[0], 0)), []
    ranges, amps = np.concatenate(out_r, 1), np.concatenate(out_a, 1)
    keep = np.argsort(-np.sqrt((amps ** 2).mean(0)), kind="stable")[: mp.n_paths]
    return ranges[:, keep], amps[:, keep], [labels[k] for k in keep]


def static_tracks(times: np.ndarray, clutter: StaticClutter, scene: Scene) -> ScatterTracks:
    """TX-RX leakage and fixed reflectors: constant range and amplitude (relative to ref_counts)."""
    ranges = [clutter.leakage_range_m, *clutter.reflector_ranges_m]
    levels = [clutter.leakage_db, *clutter.reflector_db]
    amps = [scene.ref_counts * 10 ** (db / 20) for db in levels]
    t = len(times)
    return ScatterTracks(times, np.tile(np.asarray(ranges, float), (t, 1)),
                         np.tile(np.asarray(amps, np.complex128), (t, 1)),
                         np.full(len(ranges), STATIC), np.asarray(["leakage"] + ["static"] * (len(ranges) - 1)))


def _lerp(steps: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Values (len(steps), K) at integer steps -> (n, K) by linear interpolation."""
    if len(steps) == n:
        return values
    idx = np.arange(n)
    hi = np.clip(np.searchsorted(steps, idx, side="right"), 1, len(steps) - 1)
    lo = hi - 1
    frac = ((idx - steps[lo]) / (steps[hi] - steps[lo]))[:, None]
    return values[lo] * (1 - frac) + values[hi] * frac


def _hold(steps: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Boolean values (len(steps), K) at sorted indices ``steps`` of 0..n-1 -> (n, K): each index takes
    the OR of the two samples around it (a point counts as buried while either neighbour says so)."""
    hi = np.clip(np.searchsorted(steps, np.arange(n), side="left"), 0, len(steps) - 1)
    lo = np.clip(hi - 1, 0, None)
    exact = steps[hi] == np.arange(n)
    return np.where(exact[:, None], values[hi], values[lo] | values[hi])


def surface_tracks(parts: list[Part], surf: Surfaces, effects: Effects, scene: Scene, radar: RadarConfig,
                   rng: np.random.Generator, times: np.ndarray,
                   every: int) -> tuple[SurfaceTracks, Texture, np.ndarray, np.ndarray, np.ndarray]:
    """The facet tracks of the parts (facets never lit left out), the texture, the cast steps and
    the texture's visibility there (for the bounces), and the kept facets' labels.

    Weights, shadowing and burial are evaluated at the cast steps (every ``every``-th physics step),
    phase centres and phase steps at every physics step. Elements and texture points that never
    face the radar are dropped first."""
    k = group_wavenumber(radar)
    el = po_elements(parts, scene, k)
    tex = skin_texture(parts, scene, rng)
    cast = cast_steps(len(times), every)
    k_amp = amplitude_scale(scene)
    po_scale = k_amp * math.sqrt(4 * math.pi) / radar.wavelength_m * scene.skin_reflectivity
    n_f = len(el.facet_label)

    # strips at the cast steps: centre, normal, area and the exact incidence and phase across them;
    # only strips that ever face the radar are kept
    st_c, st_n, st_area, st_across, st_facet, st_part, st_idx = [], [], [], [], [], [], []
    for sp in el.strips:
        c, n = sp.centres(cast)
        acr = sp.across(cast, k, c)
        idx = np.flatnonzero((acr != 0).any(0))
        st_idx.append(idx)
        st_across.append(acr[:, idx])
        st_c.append(c[:, idx])
        st_n.append(n[:, idx])
        st_area.append(sp.areas(cast, idx))
        st_facet.append(sp.facet(idx))
        st_part.append(np.full(len(idx), sp.part))

    def cat1(xs: list[np.ndarray], shape: tuple) -> np.ndarray:
        return np.concatenate(xs, 1) if xs else np.zeros(shape)

    e_s = sum(len(i) for i in st_idx)
    tri0 = el.tri_vertices[0][el.tris]
    area_t = 0.5 * np.linalg.norm(np.cross(tri0[:, 1] - tri0[:, 0], tri0[:, 2] - tri0[:, 0]), axis=-1)
    n_t = np.zeros((len(cast), len(el.tris), 3))
    for i in np.unique(el.tri_part):  # the flat palm is rigid: its normals follow the slab's rotation
        on = el.tri_part == i
        n_t[:, on] = np.einsum("tij,ej->tei", parts[i].rotation[cast], el.tri_normal_local[on])
    centres = np.concatenate([cat1(st_c, (len(cast), 0, 3)), el.tri_centre[cast], tex.points[cast]], 1)
    normals = np.concatenate([cat1(st_n, (len(cast), 0, 3)), n_t, tex.normals[cast]], 1)
    r = np.linalg.norm(centres, axis=-1)
    cos_t = np.clip(-(normals * centres).sum(-1) / r, 0.0, None)
    across = cat1(st_across, (len(cast), 0))
    cos_t[:, :e_s] = np.where(across != 0, np.maximum(cos_t[:, :e_s], 1e-6), 0.0)  # a strip faces when any of it does
    e_t = len(el.tris)
    keep = np.flatnonzero((cos_t > 0).any(0))  # what ever faces the radar
    ks, kt, kp = keep[keep < e_s], keep[(keep >= e_s) & (keep < e_s + e_t)] - e_s, keep[keep >= e_s + e_t] - e_s - e_t
    centres, r, cos_t = centres[:, keep], r[:, keep], cos_t[:, keep]
    owner = np.r_[np.concatenate(st_part) if st_part else np.zeros(0, int), el.tri_part, tex.part][keep]
    # surface buried in another part: evaluated at every other cast step, held in between
    sub = np.unique(np.r_[np.arange(0, len(cast), 2), len(cast) - 1])
    hidden = _hold(sub, buried(parts, owner, centres[sub], cast[sub]), len(cast))
    front = (cos_t > 0) & ~hidden
    sl_s, sl_t, sl_p = slice(0, len(ks)), slice(len(ks), len(ks) + len(kt)), slice(len(ks) + len(kt), None)
    vis = cast_visibility(surf, cast, centres, front) if effects.occlusion.enabled else front.astype(float)
    path = antenna_gain(centres, effects.antenna_pattern) / r ** 2 * vis  # (Tc, N)
    w_s = po_scale * cat1(st_area, (len(cast), 0))[:, ks] * path[:, sl_s] * across[:, ks]
    w_t = po_scale * cos_t[:, sl_t] * area_t[kt] * path[:, sl_t]
    to_radar = -centres[:, sl_p] / r[:, sl_p, None]
    sigma = facet_rcs(tex.normals[cast][:, kp], tex.area[kp], to_radar, to_radar, scene)
    w_p = k_amp * np.sqrt(sigma) * path[:, sl_p] * np.exp(1j * tex.phase[kp])
    tex_vis = np.zeros((len(cast), len(tex.area)))
    tex_vis[:, kp] = vis[:, sl_p]

    # at every physics step: along a strip (through the middles of its ends and its centre) the phase
    # is quadratic: its centre's range, the step between its ends and the curvature of the near field
    r0 = cat1([sp.ranges(slice(None), i, 0.5, 0.0) for sp, i in zip(el.strips, st_idx)], (len(times), 0))
    r1 = cat1([sp.ranges(slice(None), i, 0.5, 1.0) for sp, i in zip(el.strips, st_idx)], (len(times), 0))
    mid = cat1([sp.ranges(slice(None), i, 0.5, 0.5) for sp, i in zip(el.strips, st_idx)], (len(times), 0))
    c_s, a_s, b_s = mid[:, ks], 2 * k * (r1 - r0)[:, ks], 4 * k * (r0 + r1 - 2 * mid)[:, ks]
    r_v = np.linalg.norm(el.tri_vertices, axis=-1)  # (T, V)
    rt = r_v[:, el.tris[kt]]  # (T, Et, 3)
    lin = rt.mean(-1)
    # a flat triangle's phase centre: its corners' mean range moved towards the range of its centroid
    # by the mean of the near field's quadratic departure (3/4 of it)
    c_t = lin + 0.75 * (np.linalg.norm(el.tri_centre[:, kt], axis=-1) - lin)
    a_t, b_t = 2 * k * (rt[..., 1] - rt[..., 0]), 2 * k * (rt[..., 2] - rt[..., 0])

    # the tracks' ranges: each facet's area-weighted mean range of all its elements
    fac = np.r_[np.concatenate(st_facet) if st_facet else np.zeros(0, int), el.tri_facet]
    area0 = np.r_[cat1(st_area, (len(cast), 0))[0], area_t]
    rng_all = np.concatenate([mid, np.linalg.norm(el.tri_centre, axis=-1)], 1)
    facet_r = np.zeros((len(times), n_f))
    np.add.at(facet_r.T, fac, (rng_all * area0).T)
    facet_r /= np.maximum(np.bincount(fac, area0, minlength=n_f), 1e-30)

    def by_facet(kind: str, facet: np.ndarray, cols: slice, centre: np.ndarray, weight: np.ndarray,
                 *steps: np.ndarray) -> ElementGroup:
        order = np.argsort(facet, kind="stable")  # the renderer sums each facet's run of elements
        # single precision where the renderer's inner loop reads the weights
        weight = weight[:, order].astype(np.complex64)
        a, b = ([x[:, order] for x in steps] + [None, None])[:2]
        return ElementGroup(kind, facet[order], centre[:, order], weight, a, b,
                            centres[:, cols][:, order].astype(np.float32))

    groups = [by_facet(STRIP, np.concatenate(st_facet)[ks] if st_facet else np.zeros(0, int), sl_s, c_s, w_s, a_s, b_s),
              by_facet(TRIANGLE, el.tri_facet[kt], sl_t, c_t, w_t, a_t, b_t),
              by_facet(POINT, tex.facet[kp], sl_p, np.linalg.norm(tex.points[:, kp], axis=-1), w_p)]
    groups = [g for g in groups if g.facet.size]
    st = SurfaceTracks(times, times[cast], k, groups, facet_r)
    lit = np.zeros(n_f, bool)
    for g in groups:
        lit[g.facet[(g.weights != 0).any(0)]] = True
    return st.subset(lit), tex, cast, tex_vis, el.facet_label[lit]


@dataclass
class BounceSources:
    """The points that may take part in double bounces: positions and outward normals (T, M, 3) at
    every physics step, the area each stands for (M,) m^2, hand slot (M,), visibility (Tc, M) at the
    cast steps ``cast`` (Tc,), and their bistatic RCS law (:func:`bounce_paths`'s ``rcs``)."""

    points: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    slot: np.ndarray
    cast: np.ndarray
    vis: np.ndarray
    rcs: Callable[..., np.ndarray]


def point_tracks(parts: list[Part], surf: Surfaces, effects: Effects, scene: Scene, rng: np.random.Generator,
                 times: np.ndarray, every: int) -> tuple[ScatterTracks, BounceSources]:
    """Direct returns of the parts' bone point scatterers (``scene.scattering: bone_points``; the
    placement and the RCS law: handradar.world.points), one track per point, and the points for
    the bounces. Points that never face the radar are dropped; burial and shadowing are evaluated
    as for the surfaces (every other cast step, and at the cast steps, interpolated linearly in
    between), and points whose peak stays ``scene.prune_db`` below the strongest are dropped."""
    ps = bone_points(parts, scene.points.spacing_m, rng)
    r = np.linalg.norm(ps.points, axis=-1)  # (T, N)
    to_radar = -ps.points / r[..., None]
    sigma = point_rcs(ps.normals, ps.gain * ps.area, to_radar, to_radar, scene)
    facing = np.flatnonzero((sigma > 0).any(0))
    ps, r, sigma = ps.take(facing), r[:, facing], sigma[:, facing]
    cast = cast_steps(len(times), every)
    sub = np.unique(np.r_[np.arange(0, len(cast), 2), len(cast) - 1])
    hidden = _hold(sub, buried(parts, ps.part, ps.points[cast[sub]], cast[sub]), len(cast))
    front = (sigma[cast] > 0) & ~hidden
    vis = cast_visibility(surf, cast, ps.points[cast], front) if effects.occlusion.enabled else front.astype(float)
    amps = (amplitude_scale(scene) * np.sqrt(sigma) * antenna_gain(ps.points, effects.antenna_pattern) / r ** 2
            * _lerp(cast, vis, len(times)) * np.exp(1j * ps.phase))
    peak = np.abs(amps).max(0)
    keep = peak > (peak.max() if peak.size else 0.0) * 10 ** (-scene.prune_db / 20)
    direct = ScatterTracks(times, r[:, keep], amps[:, keep], np.full(int(keep.sum()), DIRECT), ps.label[keep])
    return direct, BounceSources(ps.points, ps.normals, ps.area * ps.gain, ps.slot, cast, vis, point_rcs)


def scene_tracks(pose: Pose, effects: Effects, scene: Scene, rng: np.random.Generator,
                 radar: RadarConfig) -> ScatterTracks:
    """All scatterers of one recording at the pose times (physics rate): the direct returns of the
    surfaces (:func:`surface_tracks`) or of bone point scatterers (:func:`point_tracks`, as
    ``scene.scattering`` says), double bounces between their points, static clutter."""
    parts = build_parts(pose, effects, scene)
    surf = occluders_of(parts)
    every = max(1, round(scene.rate_hz / scene.visibility_rate_hz))
    if scene.scattering == "bone_points":
        direct, src = point_tracks(parts, surf, effects, scene, rng, pose.times, every)
    else:
        st, tex, cast, tex_vis, labels = surface_tracks(parts, surf, effects, scene, radar, rng, pose.times, every)
        direct = ScatterTracks(pose.times, st.facet_ranges, st.amplitudes(pose.times), np.full(st.n_facets, DIRECT),
                               labels, st)
        src = BounceSources(tex.points, tex.normals, tex.area, tex.slot, cast, tex_vis, facet_rcs)
    amps = direct.amplitudes
    tracks = [direct]
    if effects.multipath.enabled:
        pick, share = _sample_points(rng, src.slot, (src.vis > 0).any(0), effects.multipath.samples_per_hand)
        rep = src.area[pick] * share  # the lit area each sampled point stands for
        # double bounces are evaluated at the visibility rate and interpolated linearly in between
        cast = src.cast
        sub = np.ix_(cast, pick)
        br, ba, bl = bounce_paths(src.points[sub], src.normals[sub], src.vis[:, pick], src.slot[pick], rep,
                                  effects, scene, src.rcs)
        br, ba = (_lerp(cast, x, len(pose.times)) for x in (br, ba))
        peak_direct = np.abs(amps).max() if amps.size else 0.0
        keep = np.abs(ba).max(0) > peak_direct * 10 ** (-scene.prune_db / 20)
        tracks.append(ScatterTracks(pose.times, br[:, keep], ba[:, keep].astype(np.complex128),
                                    np.full(int(keep.sum()), BOUNCE), np.asarray(bl, dtype=str)[keep]))
    if effects.static_clutter.enabled:
        tracks.append(static_tracks(pose.times, effects.static_clutter, scene))
    return ScatterTracks.concat(tracks)
