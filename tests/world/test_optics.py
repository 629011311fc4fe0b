"""Physical-optics returns: the closed forms against independent ones, a flat plate's RCS, and the
return of one surface at different tessellations (the world's layout invariance on a small case)."""

from __future__ import annotations

import numpy as np
import pytest

from handradar.world.config import Effects, Scene
from handradar.world.geometry import Part, _palm_faces, _revolved, frustum, palm_template, surfaces_of
from handradar.world.optics import (
    parallelogram_factor,
    polygon_integral,
    rcs_of_integral,
    triangle_factor,
)
from handradar.world.scattering import amplitude_scale, group_wavenumber, skin_texture
from handradar.world.scene import surface_tracks
from handradar.world.shadowing import buried
from handradar.world.tracks import triangle_centroid_factor

RNG = np.random.default_rng(7)


def _triangle_integral(v: np.ndarray, q: np.ndarray) -> complex:
    area = 0.5 * np.linalg.norm(np.cross(v[1] - v[0], v[2] - v[0]))
    return complex(area * triangle_factor(*(v @ q)))


@pytest.mark.parametrize("trial", range(6))
def test_triangle_and_parallelogram_factors_match_gordons_edge_sum(trial):
    """Two closed forms of the integral of exp(j q.r) over a flat facet agree to rounding, for random
    facets a few wavelengths across and random q (the monostatic 2k u has |q| ~ 3200 rad/m)."""
    v = RNG.normal(size=(3, 3)) * 0.004
    q = RNG.normal(size=3) * 2000.0
    ref = polygon_integral(v, q)
    assert abs(_triangle_integral(v, q) - ref) < 1e-9 * abs(ref) + 1e-15
    # a parallelogram on the same first corner and sides
    p = np.array([v[0], v[1], v[1] + v[2] - v[0], v[2]])
    area = np.linalg.norm(np.cross(v[1] - v[0], v[2] - v[0]))
    psi = p @ q
    par = area * parallelogram_factor(psi.mean(), psi[1] - psi[0], psi[3] - psi[0])
    ref = polygon_integral(p, q)
    assert abs(par - ref) < 1e-9 * abs(ref) + 1e-15


def test_a_facets_integral_is_the_sum_of_its_halves():
    """Cutting a facet in two (through a corner and the opposite edge's midpoint, or across a
    parallelogram) leaves the phase linear on each half: the halves' integrals add up exactly."""
    for _ in range(5):
        v = RNG.normal(size=(3, 3)) * 0.005
        q = RNG.normal(size=3) * 3000.0
        m = 0.5 * (v[1] + v[2])
        whole = _triangle_integral(v, q)
        halves = _triangle_integral(np.array([v[0], v[1], m]), q) + _triangle_integral(np.array([v[0], m, v[2]]), q)
        assert abs(whole - halves) < 1e-10 * abs(whole)
        quad = np.array([v[0], v[1], v[1] + v[2] - v[0], v[2]])
        two = (_triangle_integral(quad[[0, 1, 2]], q) + _triangle_integral(quad[[0, 2, 3]], q))
        assert abs(polygon_integral(quad, q) - two) < 1e-10 * abs(two)


def test_closed_forms_are_stable_in_their_limits():
    """All corners in phase (q along the normal or q -> 0), two corners in phase (an edge across q),
    nearly equal phases: the factors stay finite and continuous (series branch vs the exact one)."""
    assert triangle_factor(5.0, 5.0, 5.0) == pytest.approx(np.exp(5j))
    assert parallelogram_factor(0.3, 0.0, 0.0) == pytest.approx(np.exp(0.3j))
    v = np.array([[0, 0, 0], [1e-3, 0, 0], [0, 1e-3, 0.0]])
    for q in (np.array([0, 0, 3e3]), np.array([1e-9, 0, 3e3]), np.array([0, 2e3, 0]), np.array([1e-2, 1e-2, 0.0])):
        assert abs(_triangle_integral(v, q) - polygon_integral(v, q)) < 1e-9 * 0.5e-6
    # across the series threshold (phase spread 1e-2 rad) the two branches agree
    for spread in (0.0099, 0.0101):
        a = np.float32(spread)
        exact = triangle_factor(0.0, spread, 0.3 * spread) * np.exp(-1j * spread * 1.3 / 3)
        assert abs(complex(triangle_centroid_factor(np.array([a]), np.array([np.float32(0.3) * a]))[0]) - exact) < 1e-6


# ---- the world's machinery on single surfaces ------------------------------------------------------
def _radar_default():
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    from handradar.config import VERSION_BASE, config_dir

    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        return instantiate(compose("world", overrides=["out=unused"]).radar)


RADAR = _radar_default()
BARE = Effects().only()  # no shadowing, no antenna pattern: the surface alone
COHERENT = Scene(skin_diffuse=0.0, skin_specular=0.0)  # physical optics only (the texture carries nothing)


def _total(parts: list[Part], scene: Scene, times: np.ndarray) -> np.ndarray:
    """The coherent return of the parts at ``times`` (counts), all facets added with their ranges."""
    st, *_ = surface_tracks(parts, surfaces_of(parts), BARE, scene, RADAR, np.random.default_rng(0), times, 1)
    return (st.amplitudes(times) * np.exp(2j * st.wavenumber * st.facet_ranges)).sum(-1)


def _cylinder(axis_dir: np.ndarray, centre: np.ndarray, times: np.ndarray, sides: int, rings: int, turn: float,
              radius: float = 0.0085, length: float = 0.04, swing: bool = True) -> Part:
    """A cylinder about ``axis_dir`` through ``centre``; with ``swing`` its far end moves at 0.3 m/s
    (mostly towards the radar's boresight), so it turns through broadside and away from it."""
    t = len(times)
    a = np.tile(centre - 0.5 * length * axis_dir, (t, 1))
    b = np.tile(centre + 0.5 * length * axis_dir, (t, 1)) + np.outer(times, [0.0, 0.05, 0.3]) * swing
    up = np.tile([0.0, 1.0, 0.0], (t, 1))
    v, f = frustum(a, b, up, radius, radius, sides, rings, turn=turn)
    return Part("bone", 0, v, f, cones=_revolved(a, b, up, radius, radius, sides, rings, False, turn))


def test_flat_square_at_normal_incidence_has_the_closed_form_rcs():
    """A 2 cm square facing the radar 2 m away (its far field starts at 2 s^2 / lambda = 0.2 m):
    |A| = K sqrt(sigma) / R^2 with sigma = 4 pi Gamma^2 A^2 / lambda^2 (8.8e-3 m^2 at Gamma 0.35)."""
    times = np.arange(5) * 0.01
    side, r = 0.02, 2.0
    square = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0.0]]) * side / 2
    h = 0.0005  # a thin slab: its lower face looks at the radar, the upper one away
    faces = [square + [0, 0, h], square - [0, 0, h]]
    for p, q in zip(square, np.roll(square, -1, 0)):
        faces.append(np.array([[*p[:2], h], [*q[:2], h], [*q[:2], -h], [*p[:2], -h]]))
    tris = np.concatenate([np.stack([f[0], f[1], f[2]])[None] for f in faces] + [np.stack([f[0], f[2], f[3]])[None]
                                                                                   for f in faces])
    origin = np.tile([0.0, 0.0, r], (len(times), 1))
    rot = np.tile(np.eye(3), (len(times), 1, 1))
    part = Part("plate", 0, np.zeros((len(times), 0, 3)), np.arange(len(tris) * 3).reshape(-1, 3),
                slab_triangles=tris, slab_faces=faces, origin=origin, rotation=rot)
    part.mesh_vertices = part.to_radar(tris.reshape(-1, 3))
    total = _total([part], COHERENT, times)
    sigma = rcs_of_integral(side ** 2, RADAR.wavelength_m, COHERENT.skin_reflectivity)
    expected = amplitude_scale(COHERENT) * np.sqrt(sigma) / r ** 2
    assert np.abs(total) == pytest.approx(np.full(len(times), expected), rel=2e-3)


def test_broadside_cylinder_has_the_physical_optics_rcs():
    """A finger-sized cylinder (a = 8.5 mm, L = 4 cm) broadside 5 m away: sigma = 2 pi a L^2 Gamma^2 /
    lambda (stationary phase across, uniform along) at the default 6 x 1 tessellation."""
    times = np.arange(3) * 0.01
    part = _cylinder(np.array([1.0, 0, 0]), np.array([0, 0, 5.0]), times, 6, 1, 0.0, swing=False)
    total = np.abs(_total([part], COHERENT, times))
    lam = RADAR.wavelength_m
    sigma = 2 * np.pi * 0.0085 * 0.04 ** 2 * COHERENT.skin_reflectivity ** 2 / lam
    expected = amplitude_scale(COHERENT) * np.sqrt(sigma) / 5.0 ** 2
    assert total == pytest.approx(np.full(len(times), expected), rel=0.05)


def _surface_integral(part: Part, scene: Scene, times: np.ndarray, n_phi: int = 1440, n_w: int = 320) -> np.ndarray:
    """The same return by brute force: the smooth cylinder sampled every 0.25 deg and 0.125 mm."""
    cone = part.cones[0]
    pp, ww = np.meshgrid((np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi, (np.arange(n_w) + 0.5) / n_w)
    points, normals = cone.surface(pp.ravel(), ww.ravel())
    r = np.linalg.norm(points, axis=-1)
    cos = np.clip(-(normals * points).sum(-1) / r, 0.0, None)
    d_area = cone.patch_area(0.0, 2 * np.pi / n_phi, 0.0, 1.0 / n_w)
    k = group_wavenumber(RADAR)
    scale = amplitude_scale(scene) * np.sqrt(4 * np.pi) / RADAR.wavelength_m * scene.skin_reflectivity
    return (scale * cos * d_area / r ** 2 * np.exp(2j * k * r)).sum(-1)


@pytest.mark.parametrize("tilt_deg", [0.0, 8.0, 35.0])
def test_one_cylinder_returns_the_surface_integral_at_every_tessellation(tilt_deg):
    """The complex return of one finger-sized cylinder 0.3 m above the radar (near field) as it
    swings through and away from broadside, at the default 6 sides x 1 ring, turned by a quarter
    side, and at 12 x 4 (turned or not): the brute-force integral over the smooth surface within 2.5 %
    of the cylinder's broadside return, whatever the layout (tilted, where its ends dominate, too)."""
    times = np.arange(0, 0.2, 0.01)
    tilt = np.deg2rad(tilt_deg)
    axis_dir = np.array([np.cos(tilt), 0.0, np.sin(tilt)])
    centre = np.array([0.01, 0.02, 0.3])
    truth = _surface_integral(_cylinder(axis_dir, centre, times, 6, 1, 0.0), COHERENT, times)
    broadside = np.abs(_surface_integral(_cylinder(np.array([1.0, 0, 0]), centre, times, 6, 1, 0.0), COHERENT,
                                         times)).max()
    for sides, rings, turn in ((6, 1, 0.0), (6, 1, 0.25), (12, 4, 0.0), (12, 4, 0.3)):
        got = _total([_cylinder(axis_dir, centre, times, sides, rings, turn)], COHERENT, times)
        err = np.abs(got - truth).max() / broadside
        print(f"tilt {tilt_deg:4.1f} deg, {sides} x {rings} turned {turn}: largest error {err:.4f} of broadside")
        assert err < 0.025


def test_texture_and_burial_do_not_depend_on_the_facets():
    """The skin texture is drawn on the smooth surfaces: the same points at any facet layout. The
    metacarpal-like cylinder inside a palm slab is buried, a cylinder beside it is not."""
    times = np.arange(3) * 0.01
    parts = [_cylinder(np.array([1.0, 0, 0]), np.array([0, 0, 0.3]), times, 6, 1, turn) for turn in (0.0, 0.5)]
    a = skin_texture([parts[0]], Scene(), np.random.default_rng(1))
    b = skin_texture([parts[1]], Scene(), np.random.default_rng(1))
    np.testing.assert_allclose(a.points, b.points, atol=1e-12)
    # a palm slab around a thin cylinder
    pv, pf = palm_template(1.0, 0.026, 1, left=False)
    origin = np.tile([0.0, 0.0, 0.3], (len(times), 1))
    rot = np.tile(np.eye(3), (len(times), 1, 1))
    slab = Part("palm", 0, np.zeros((len(times), 0, 3)), pf, slab_triangles=pv[pf],
                slab_faces=_palm_faces(1.0, 0.026, False), origin=origin, rotation=rot)
    slab.mesh_vertices = slab.to_radar(pv)
    inner = _cylinder(np.array([0.0, 1.0, 0]), np.array([0.0, 0.05, 0.3]), times, 6, 1, 0.0, radius=0.006,
                      length=0.05)
    outer = _cylinder(np.array([0.0, 1.0, 0]), np.array([0.15, 0.05, 0.3]), times, 6, 1, 0.0, radius=0.006,
                      length=0.05)
    parts = [slab, inner, outer]
    tex = skin_texture(parts, Scene(), np.random.default_rng(2))
    hidden = buried(parts, tex.part, tex.points, np.arange(len(times)))
    assert hidden[:, tex.part == 1].all()
    assert not hidden[:, tex.part == 2].any()
    assert not hidden[:, tex.part == 0].any()
