"""The radar scene of one recording: every scatterer's track at the physics rate (:func:`scene_tracks`).

The parts of every present hand (handradar.world.geometry) return directly through their smooth
surfaces (:func:`surface_tracks`: physical-optics elements and skin texture, handradar.world.scattering)
or, with ``scene.scattering: bone_points``, through discrete point scatterers with an RCS law of
their own (handradar.world.points, :func:`point_tracks`); burial and shadowing hide what the radar
cannot see (handradar.world.shadowing); double bounces run between lit points sampled on each
hand; static clutter adds the leakage and fixed reflectors. The bounces, the shadowing and the
static clutter are the same for both kinds of direct return. The result is one
handradar.world.tracks.ScatterTracks, which the renderer evaluates at every chirp.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from handradar.radar.config import RadarConfig
from handradar.world.config import Effects, Scene, StaticClutter
from handradar.world.geometry import Part, Surfaces, build_parts, occluders_of
from handradar.world.kinematics import Pose
from handradar.world.points import bone_points, point_rcs
from handradar.world.scattering import (
    Texture,
    amplitude_scale,
    antenna_gain,
    bounce_paths,
    facet_rcs,
    group_wavenumber,
    po_elements,
    skin_texture,
)
from handradar.world.shadowing import buried, cast_steps, cast_visibility, lerp_steps
from handradar.world.tracks import (
    BOUNCE,
    DIRECT,
    POINT,
    STATIC,
    STRIP,
    TRIANGLE,
    ElementGroup,
    ScatterTracks,
    SurfaceTracks,
)


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


def static_tracks(times: np.ndarray, clutter: StaticClutter, scene: Scene) -> ScatterTracks:
    """TX-RX leakage and fixed reflectors: constant range and amplitude (relative to ref_counts)."""
    ranges = [clutter.leakage_range_m, *clutter.reflector_ranges_m]
    levels = [clutter.leakage_db, *clutter.reflector_db]
    amps = [scene.ref_counts * 10 ** (db / 20) for db in levels]
    t = len(times)
    return ScatterTracks(times, np.tile(np.asarray(ranges, float), (t, 1)),
                         np.tile(np.asarray(amps, np.complex128), (t, 1)),
                         np.full(len(ranges), STATIC), np.asarray(["leakage"] + ["static"] * (len(ranges) - 1)))


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
    cast steps ``cast`` (Tc,), and their bistatic RCS law (the ``rcs`` of handradar.world.scattering.bounce_paths)."""

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
            * lerp_steps(cast, vis, len(times)) * np.exp(1j * ps.phase))
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
        br, ba = (lerp_steps(cast, x, len(pose.times)) for x in (br, ba))
        peak_direct = np.abs(amps).max() if amps.size else 0.0
        keep = np.abs(ba).max(0) > peak_direct * 10 ** (-scene.prune_db / 20)
        tracks.append(ScatterTracks(pose.times, br[:, keep], ba[:, keep].astype(np.complex128),
                                    np.full(int(keep.sum()), BOUNCE), np.asarray(bl, dtype=str)[keep]))
    if effects.static_clutter.enabled:
        tracks.append(static_tracks(pose.times, effects.static_clutter, scene))
    return ScatterTracks.concat(tracks)
