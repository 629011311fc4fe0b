"""How skin scatters: physical-optics elements, skin texture, the antenna pattern, the radar
equation and double bounces.

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
  at every chirp (handradar.world.tracks.strip_along_factor);
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

Double bounces (:func:`bounce_paths`): hand-table-hand (the table is a mirror a little below the
antenna: Q is replaced by its image Q') and hand-hand, between ``samples_per_hand`` lit texture
points of each hand; their radar legs use the points' visibility, the bounce legs are not
ray-cast. The strongest ``n_paths`` are kept.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from handradar.radar.config import SPEED_OF_LIGHT_M_S, RadarConfig
from handradar.radar.signal import carrier_phase_rad
from handradar.world.config import AntennaPattern, Effects, Scene
from handradar.world.geometry import Cone, Part, polygon_area, unit_vectors
from handradar.world.optics import quadratic_integral
from handradar.world.points import face_normals

REF_RANGE_M = 0.3
REF_RCS_M2 = 0.01


# ---- physical-optics elements --------------------------------------------------------------------
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
                n = max(1, round(polygon_area(poly) * density))
                local = _polygon_samples(rng, poly, n)
                pts.append(p.to_radar(local))
                nrm.append(face_normals(poly, centre, p.rotation, n))
                area.append(np.full(n, polygon_area(poly) / n))
                near = np.linalg.norm(local[:, None] - tri_c[None], axis=-1).argmin(1)
                facet.append(n_f + near)
                slot.append(np.full(n, p.slot))
        n_f += p.n_facets
        owner.append(np.full(sum(len(a) for a in area) - n_before, ip))
    phase = rng.uniform(0, 2 * np.pi, sum(len(a) for a in area))
    return Texture(np.concatenate(pts, 1), np.concatenate(nrm, 1), np.concatenate(area), phase,
                   np.concatenate(facet), np.concatenate(slot), np.concatenate(owner))


# ---- facet geometry and returns ------------------------------------------------------------------
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
    h = unit_vectors(u_in + u_out)
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


# ---- double bounces ------------------------------------------------------------------------------
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
            u_out_p = unit_vectors(leg)
            u_in_q = unit_vectors(p_img - q)
            coef = mp.table_reflection * np.where(pi == qi, 1.0, 2.0)  # both orderings of distinct points
        else:
            leg = q - p
            u_out_p = unit_vectors(leg)
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
