"""The radar scene: surface facets of hands and forearms, their returns, shadowing and multipath.

Every part is a closed-ish triangle surface rebuilt at each physics step (``scene.rate_hz``):
finger bones as tapered cylinders (tips capped), the palm and back of the hand as a slab whose
outline runs through the wrist and the knuckles, the forearm as a truncated cone from the wrist to
an elbow fixed per recording. Each triangle is a scatterer at its centroid with a glossy facet
return (radar cross-section per unit area, metres^2/metres^2, at incidence theta on the facet)

    sigma = area * (rho_d cos(theta) + rho_s cos(theta)^m),  theta from the facet normal,

zero for back-facing facets. Bistatic bounces use the half-vector of the two directions. The
single-bounce amplitude follows the radar equation, in ADC counts,

    A = K sqrt(sigma) G(direction) / R^2,      K = ref_counts * (0.3 m)^2 / sqrt(0.01 m^2),

and a double bounce radar -> P -> Q -> radar (Friis on each leg)

    A = K sqrt(sigma_P sigma_Q / (4 pi)) sqrt(G_P G_Q) / (|P| |PQ| |Q|)   at range (|P| + |PQ| + |Q|) / 2.

Shadowing: a ray from the antenna to each front-facing facet centroid (trimesh + embree); the facet
is visible when the first triangle hit is its own. Double bounces: hand-table-hand (the table is a
mirror a little below the antenna: Q is replaced by its image Q') and hand-hand, between an
area-weighted sample of facets of each hand; their radar legs use the facets' visibility, the
bounce legs are not ray-cast. The strongest ``n_paths`` are kept.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from handradar.hand.skeleton import BONE_NAMES, BONES
from handradar.world.config import AntennaPattern, Effects, Scene, StaticClutter
from handradar.world.kinematics import Pose

REF_RANGE_M = 0.3
REF_RCS_M2 = 0.01

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
        tip = (b + e * r1 * 0.9)[:, None, :]
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


@dataclass
class Surfaces:
    """Triangle surfaces of the scene over time."""

    vertices: np.ndarray  # (T, V, 3) metres, radar frame
    faces: np.ndarray  # (F, 3)
    part: np.ndarray  # (F,) index into part_names
    slot: np.ndarray  # (F,) hand slot 0 right / 1 left
    part_names: list[str] = field(default_factory=list)

    @property
    def triangles(self) -> np.ndarray:
        return self.vertices[:, self.faces]  # (T, F, 3, 3)


def build_surfaces(pose: Pose, effects: Effects, scene: Scene) -> Surfaces:
    """Finger bones, palm slab and forearm of every present hand at every pose time."""
    geom = pose.geometry
    verts, faces, part, slot = [], [], [], []
    names: list[str] = []
    n_v = 0

    def add(v: np.ndarray, f: np.ndarray, name: str, s: int) -> None:
        nonlocal n_v
        # outward winding: faces must point away from the part's interior (parts are convex)
        tri = v[0][f]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        inward = ((tri.mean(1) - v[0].mean(0)) * n).sum(-1) < 0
        f = np.where(inward[:, None], f[:, ::-1], f)
        if name not in names:
            names.append(name)
        verts.append(v)
        faces.append(f + n_v)
        part.append(np.full(len(f), names.index(name)))
        slot.append(np.full(len(f), s))
        n_v += v.shape[1]

    for s in np.flatnonzero(pose.present):
        j = pose.joints[:, s]
        rot = pose.rotations[:, s]
        dorsal = rot[:, :, 2]
        for k, ((a, b), bname) in enumerate(zip(BONES, BONE_NAMES)):
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
            add(v, f, bname, s)
        if effects.palm.enabled:
            pv, pf = palm_template(geom.scale, effects.palm.thickness_m, scene.palm_subdivisions, left=s == 1,
                                   turn=scene.facet_turn)
            v = j[:, 0][:, None, :] + np.einsum("tij,vj->tvi", rot, pv)
            add(v, pf, "palm", s)
        if effects.forearm.enabled:
            elbow = np.broadcast_to(pose.elbows[s], j[:, 0].shape)
            fa = effects.forearm
            v, f = frustum(elbow, j[:, 0], dorsal, fa.radius_elbow_m * geom.scale, fa.radius_wrist_m * geom.scale,
                           scene.forearm_sides, scene.forearm_rings, turn=scene.facet_turn)
            add(v, f, "forearm", s)
    return Surfaces(np.concatenate(verts, 1), np.concatenate(faces), np.concatenate(part),
                    np.concatenate(slot), names)


# ---- facet geometry and returns -------------------------------------------------------------------
def facet_geometry(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangles (..., 3, 3) -> centroids (..., 3), unit normals (..., 3), areas (...)."""
    c = tri.mean(-2)
    n = np.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :])
    norm = np.linalg.norm(n, axis=-1)
    return c, n / np.maximum(norm, 1e-15)[..., None], 0.5 * norm


def facet_rcs(normal: np.ndarray, area: np.ndarray, u_in: np.ndarray, u_out: np.ndarray, scene: Scene) -> np.ndarray:
    """Glossy facet RCS (m^2) for incoming-from ``u_in`` and outgoing-to ``u_out`` unit directions."""
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


def first_hits(vertices: np.ndarray, faces: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Index of the first triangle hit by rays from the origin along ``dirs`` (-1: none); trimesh's
    ray intersector, Embree (embreex) where installed."""
    mesh = trimesh.Trimesh(vertices, faces, process=False, validate=False)
    return mesh.ray.intersects_first(np.zeros_like(dirs), dirs)


def visibility(surfaces: Surfaces, centroids: np.ndarray, front: np.ndarray, every: int = 1) -> np.ndarray:
    """(T, F) in [0, 1]: 1 where the ray from the antenna (origin) to a front-facing centroid first hits
    its own facet. Rays are cast at every ``every``-th step (and the last); steps in between are
    interpolated linearly, so a facet fades in or out of shadow between two casts."""
    t_steps, n_f = front.shape
    cast = np.unique(np.r_[np.arange(0, t_steps, max(1, every)), t_steps - 1])
    hits = np.zeros((len(cast), n_f))
    for i, t in enumerate(cast):
        idx = np.flatnonzero(front[t])
        if not len(idx):
            continue
        dirs = _unit(centroids[t, idx])
        hits[i, idx] = first_hits(surfaces.vertices[t], surfaces.faces, dirs) == idx
    return _lerp(cast, hits, t_steps)


# ---- tracks ----------------------------------------------------------------------------------------
@dataclass
class ScatterTracks:
    """Scatterers at the physics rate: effective range (T, K) metres and real amplitude (T, K) counts.

    kind: (K,) DIRECT / BOUNCE / STATIC; label: (K,) part name (``slot:part``) or path description.
    """

    times: np.ndarray
    ranges: np.ndarray
    amplitudes: np.ndarray
    kind: np.ndarray
    label: np.ndarray

    def select(self, mask: np.ndarray) -> ScatterTracks:
        return ScatterTracks(self.times, self.ranges[:, mask], self.amplitudes[:, mask], self.kind[mask], self.label[mask])

    @staticmethod
    def concat(parts: list[ScatterTracks]) -> ScatterTracks:
        parts = [p for p in parts if p.kind.size]
        return ScatterTracks(parts[0].times, np.concatenate([p.ranges for p in parts], 1),
                             np.concatenate([p.amplitudes for p in parts], 1), np.concatenate([p.kind for p in parts]),
                             np.concatenate([p.label for p in parts]))


def _sample_facets(rng: np.random.Generator, area: np.ndarray, slot: np.ndarray, per_hand: int) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted draw of facets per hand; returns indices and the area each one stands for."""
    idx, rep_area = [], []
    for s in np.unique(slot):
        cand = np.flatnonzero(slot == s)
        w = area[cand] / area[cand].sum()
        k = min(per_hand, len(cand))
        pick = rng.choice(cand, size=k, replace=False, p=w)
        idx.append(pick)
        rep_area.append(np.full(k, area[cand].sum() / k))
    return np.concatenate(idx), np.concatenate(rep_area)


def bounce_paths(c: np.ndarray, n: np.ndarray, vis: np.ndarray, slot: np.ndarray, rep_area: np.ndarray,
                 effects: Effects, scene: Scene) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Double-bounce paths between sampled facets: ranges (T, P), amplitudes (T, P), labels.

    c, n: (T, M, 3) centroids and normals of the sampled facets; vis (T, M) their radar-leg visibility.
    """
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
            coef = mp.table_reflection * np.where(pi == qi, 1.0, 2.0)  # both orderings of distinct facets
        else:
            leg = q - p
            u_out_p = _unit(leg)
            u_in_q = -u_out_p
            coef = np.full(len(pi), 2.0)
        d = np.linalg.norm(leg, axis=-1)
        s_p = facet_rcs(n[:, pi], rep_area[pi], to_radar[:, pi], u_out_p, scene)
        s_q = facet_rcs(n[:, qi], rep_area[qi], u_in_q, to_radar[:, qi], scene)
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
    return ScatterTracks(times, np.tile(np.asarray(ranges, float), (t, 1)), np.tile(np.asarray(amps, float), (t, 1)),
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


def scene_tracks(pose: Pose, effects: Effects, scene: Scene, rng: np.random.Generator) -> ScatterTracks:
    """All scatterers of one recording at the pose times (physics rate)."""
    surf = build_surfaces(pose, effects, scene)
    c, n, area = facet_geometry(surf.triangles)
    r = np.linalg.norm(c, axis=-1)
    to_radar = -c / r[..., None]
    cos_t = (n * to_radar).sum(-1)
    front = cos_t > 0
    every = max(1, int(round(scene.rate_hz / scene.visibility_rate_hz)))
    vis = visibility(surf, c, front, every) if effects.occlusion.enabled else front.astype(float)
    sigma = facet_rcs(n, area, to_radar, to_radar, scene)
    amp = amplitude_scale(scene) * np.sqrt(sigma) * antenna_gain(c, effects.antenna_pattern) / r ** 2 * vis
    labels = np.asarray([f"{s}:{surf.part_names[p]}" for s, p in zip(surf.slot, surf.part)])
    parts = [ScatterTracks(pose.times, r, amp, np.full(len(labels), DIRECT), labels)]
    if effects.multipath.enabled:
        pick, rep = _sample_facets(rng, area[0], surf.slot, effects.multipath.samples_per_hand)
        # double bounces are evaluated at the visibility rate and interpolated linearly in between
        steps = np.unique(np.r_[np.arange(0, len(pose.times), every), len(pose.times) - 1])
        sub = np.ix_(steps, pick)
        br, ba, bl = bounce_paths(c[sub], n[sub], vis[sub], surf.slot[pick], rep, effects, scene)
        br, ba = (_lerp(steps, x, len(pose.times)) for x in (br, ba))
        parts.append(ScatterTracks(pose.times, br, ba, np.full(len(bl), BOUNCE), np.asarray(bl, dtype=str)))
    tracks = ScatterTracks.concat(parts)
    peak = np.abs(tracks.amplitudes).max(0)
    tracks = tracks.select(peak > peak.max() * 10 ** (-scene.prune_db / 20))
    if effects.static_clutter.enabled:
        tracks = ScatterTracks.concat([tracks, static_tracks(pose.times, effects.static_clutter, scene)])
    return tracks
