"""The radar scene: each effect measurably does what it claims (palm, shadowing, multipath, pattern)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from handradar.radar.chain import column_times_s, gate_bins, velocity_axis_m_s
from handradar.world.config import AntennaPattern, Scene
from handradar.world.generate import RecordingSpec, simulate
from handradar.world.geometry import Surfaces, build_surfaces
from handradar.world.kinematics import Motion, Subject
from handradar.world.render import fast_profiles
from handradar.world.scattering import antenna_gain, facet_geometry, facet_rcs, pattern_exponents
from handradar.world.shadowing import visibility
from handradar.world.tracks import BOUNCE, strip_along_factor
from tests.world.conftest import range_doppler, with_effects


def profiles(world, radar, chain, spec):
    sim = simulate(world, radar, spec)
    p = fast_profiles(sim.tracks, sim.radar, chain, sim.radar.n_frames, world.effects, sim.rng_noise, sim.rng_quant,
                      sim.noise_sigma)
    return sim, p


@pytest.mark.parametrize("s", [0.0, 0.7, -2.95, 3.0, 3.01, 8.0, -30.0])
def test_strip_along_factor_against_the_integral(s):
    """integral_{-1/2}^{1/2} exp(j (s x + q x^2)) dx by quadrature, across the series/closed-form
    switch at |s| = 3 and the near-field range |q| <= 4: error within the documented third order."""
    from scipy.integrate import quad

    for q in (-4.0, -1.0, -0.25, 0.0, 0.5, 2.0, 4.0):
        re = quad(lambda x: np.cos(s * x + q * x * x), -0.5, 0.5)[0]
        im = quad(lambda x: np.sin(s * x + q * x * x), -0.5, 0.5)[0]
        got = strip_along_factor(np.array([s], np.float32), np.array([q], np.float32))[0]
        bound = abs(q) ** 3 / 2688 + (abs(q) * s ** 6 / 1658880 if abs(s) <= 3 else 0.0)
        assert abs(got - complex(re, im)) <= bound + 1e-6, (s, q)


def test_visibility_of_a_known_scene():
    """A plate between the antenna and a facet hides it; a facet beside the plate stays visible."""
    plate = np.array([[-0.05, -0.05, 0.2], [0.05, -0.05, 0.2], [0.05, 0.05, 0.2], [-0.05, 0.05, 0.2]])
    hidden = np.array([[-0.01, -0.01, 0.4], [0.01, -0.01, 0.4], [0.0, 0.01, 0.4]])
    beside = hidden + np.array([0.2, 0.0, 0.0])
    verts = np.concatenate([plate, hidden, beside])[None]
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 6, 5], [7, 9, 8]])  # all facing the antenna (-z)
    surf = Surfaces(verts, faces, np.zeros(4, int), np.zeros(4, int), ["x"])
    c, n, _ = facet_geometry(surf.triangles)
    assert (n[0, :, 2] < 0).all()
    vis = visibility(surf, c, np.ones((1, 4), bool))
    assert vis[0].tolist() == [1.0, 1.0, 0.0, 1.0]


def test_facet_return_depends_on_orientation():
    scene = Scene()
    n = np.array([0.0, 0.0, -1.0])
    rcs = [float(facet_rcs(n, 1e-4, d, d, scene)) for d in
           (np.array([0, 0, -1.0]), np.array([0, np.sin(0.5), -np.cos(0.5)]), np.array([0, 0, 1.0]))]
    # normal incidence: (rho_d + rho_s) * area; tilted: rho_d cos + rho_s cos^m; back side: nothing
    assert rcs[0] == pytest.approx(1e-4 * (scene.skin_diffuse + scene.skin_specular))
    assert rcs[1] == pytest.approx(1e-4 * (scene.skin_diffuse * np.cos(0.5) + scene.skin_specular * np.cos(0.5) ** 8))
    assert rcs[2] == 0.0


def test_antenna_pattern_half_power_beamwidths():
    p = AntennaPattern(hpbw_az_deg=60.0, hpbw_el_deg=40.0)
    n_az, n_el = pattern_exponents(p)
    az = np.array([np.sin(np.deg2rad(30)), 0.0, np.cos(np.deg2rad(30))])
    el = np.array([0.0, np.sin(np.deg2rad(20)), np.cos(np.deg2rad(20))])
    assert antenna_gain(np.array([0, 0, 0.3]), p) == pytest.approx(1.0)
    assert antenna_gain(az, p) == pytest.approx(0.5)
    assert antenna_gain(el, p) == pytest.approx(0.5)
    assert antenna_gain(np.array([0.3, 0, -0.01]), p) == pytest.approx(10 ** (p.floor_db / 10))
    assert antenna_gain(az, dataclasses.replace(p, enabled=False)) == 1.0


def test_antenna_pattern_reduces_the_return_off_boresight_as_the_pattern_says(world, radar, chain):
    """Hand at 30 deg: every surface element's and texture point's weight is scaled by G(direction)
    exactly, so the received power drops by the elements' power-weighted two-way gain (the
    random-phase expectation, -2.4 to -6.2 dB here). One recording's coherent sum strays from it by
    up to ~2.5 dB either way (its interference pattern), so the power is pooled over four."""
    expected, measured = np.zeros(2), np.zeros(2)
    for subject, rep in ((0, 0), (1, 0), (0, 1), (1, 1)):
        spec = RecordingSpec("slide", subject, 30.0, rep)
        w_on, w_off = with_effects(world, "antenna_pattern"), with_effects(world)
        on, off = simulate(w_on, radar, spec), simulate(w_off, radar, spec)
        for g_on, g_off in zip(on.tracks.surface.groups, off.tracks.surface.groups):
            assert g_on.kind == g_off.kind and g_on.weights.shape == g_off.weights.shape
            gain = antenna_gain(g_on.centres.astype(float), w_on.effects.antenna_pattern)
            lit = g_off.weights != 0
            assert lit.mean() > 0.2
            assert np.allclose(g_on.weights[lit] / g_off.weights[lit], gain[lit], rtol=1e-5)
            expected += [np.sum(np.abs(g_on.weights) ** 2), np.sum(np.abs(g_off.weights) ** 2)]
        measured += [float(profiles(w, radar, chain, spec)[1].abs().pow(2).sum()) for w in (w_on, w_off)]
    expected_db, measured_db = (10 * np.log10(x[0] / x[1]) for x in (expected, measured))
    print(f"antenna pattern, four recordings: expected {expected_db:.2f} dB, measured {measured_db:.2f} dB")
    assert -8.0 < expected_db < -3.0
    assert measured_db == pytest.approx(expected_db, abs=1.5)
    assert measured_db < -2.5


def test_palm_adds_energy_in_the_range_bins_and_doppler_of_the_palm(world, radar, chain):
    """The palm adds energy (pooled over four recordings: one palm's coherent return can cancel) and
    puts it where the palm is: its centre's range bin and radial velocity at each STFT column."""
    ratios = []
    for subject, rep in ((0, 0), (1, 0), (0, 1), (1, 1)):
        spec = RecordingSpec("slide", subject, 0.0, rep)
        on, p_on = profiles(with_effects(world, "palm"), radar, chain, spec)
        _, p_off = profiles(with_effects(world), radar, chain, spec)
        rd_on, rd_off = range_doppler(p_on, chain), range_doppler(p_off, chain)
        ratios.append((rd_on.sum(), rd_off.sum()))
        added = np.clip(rd_on - rd_off, 0, None)
        t = column_times_s(on.radar, chain, on.radar.n_frames)
        centre = lambda tt: on.motion.pose(tt).palm_centres()[:, on.motion.slots[0]]  # noqa: E731
        r = np.linalg.norm(centre(t), axis=-1)
        v = -(np.linalg.norm(centre(t + 1e-3), axis=-1) - r) / 1e-3
        b0, _ = gate_bins(radar, chain)
        bins = np.rint(r / radar.range_resolution_m).astype(int) - b0
        rows = np.abs(velocity_axis_m_s(radar, chain)[None, :] - v[:, None]).argmin(1)
        near = sum(added[max(0, b - 1):b + 2, max(0, d - 2):d + 3, k].sum() for k, (b, d) in enumerate(zip(bins, rows)))
        print(f"palm: added energy near the palm {near / added.sum():.2f}, power ratio {ratios[-1][0] / ratios[-1][1]:.2f}")
        assert near / added.sum() > 0.8
    on_total, off_total = np.sum(ratios, axis=0)
    assert on_total > 1.3 * off_total


def test_shadowing_removes_the_return_of_the_hand_hidden_behind_the_other(world, radar):
    """hand_merge ends with the right hand stacked above the left: seen from the radar below, the
    left hand hides most of it."""
    spec = RecordingSpec("hand_merge", 0, 0.0, 0)
    energy = {}
    for name, w in (("on", with_effects(world, "palm", "occlusion")), ("off", with_effects(world, "palm"))):
        sim = simulate(w, radar, spec)
        tr = sim.tracks
        end = tr.times > sim.motion.start_s + 0.8 * sim.motion.duration_s
        label = tr.label.astype(str)
        energy[name] = [float((np.abs(tr.amplitudes[end][:, np.char.startswith(label, f"{s}:")]) ** 2).sum())
                        for s in (0, 1)]
    upper = energy["on"][0] / energy["off"][0]
    lower = energy["on"][1] / energy["off"][1]
    assert upper < 0.2 < 0.5 < lower


def test_multipath_adds_a_return_at_the_image_range(world, radar, chain):
    """Hand-table-hand: the palm's bounce off the table comes back at R + (height above the table)."""
    wide = dataclasses.replace(chain, gate_m=(0.05, 1.0), clutter_removal=False)
    spec = RecordingSpec("grasp", 0, 0.0, 0)
    world = dataclasses.replace(world, scene=dataclasses.replace(world.scene, prune_db=400.0))  # no pruning
    w_on = with_effects(world, "multipath", "palm")
    on, p_on = profiles(w_on, radar, wide, spec)
    _, p_off = profiles(with_effects(world, "palm"), radar, wide, spec)
    assert (on.tracks.kind == BOUNCE).sum() == w_on.effects.multipath.n_paths
    diff = (p_on - p_off).abs().pow(2).mean(dim=(0, 1, 2)).numpy()
    palm = on.motion.pose(on.tracks.times).palm_centres()[:, on.motion.slots[0]]
    image = np.linalg.norm(palm, axis=-1).mean() + palm[:, 2].mean() + w_on.effects.multipath.table_below_m
    b0, _ = gate_bins(radar, wide)
    assert abs(int(diff.argmax()) + b0 - image / radar.range_resolution_m) <= 1.0
    # a double bounce is weaker than the direct return, but not negligible
    ratio = float((p_on - p_off).abs().pow(2).sum() / p_off.abs().pow(2).sum())
    assert 1e-4 < ratio < 0.1


def test_surfaces_follow_the_effects(world):
    """palm and forearm add their parts; facets are non-degenerate; on a palm-down hand the palm
    faces (normal towards -z) lie below the back-of-hand faces."""
    rng = np.random.default_rng(0)
    subj = Subject.sample(0, rng, world.kinematics, world.scene.finger_radius_m)
    pose = Motion("double_hand_drumming", subj, 0.0, 1.8, world.kinematics, rng).pose(np.array([0.0, 0.1]))
    full = build_surfaces(pose, world.effects, world.scene)
    bare = build_surfaces(pose, world.effects.only(), world.scene)
    assert set(full.part_names) - set(bare.part_names) == {"palm", "forearm"}
    assert set(np.unique(full.slot)) == {0, 1}
    c, n, area = facet_geometry(full.triangles)
    assert (area > 1e-8).all()
    palm = full.part == full.part_names.index("palm")
    down, up = palm & (n[0, :, 2] < -0.9), palm & (n[0, :, 2] > 0.9)
    assert down.sum() > 10 and up.sum() > 10
    assert c[0, down, 2].mean() < c[0, up, 2].mean() - 0.015


def test_facet_turn_keeps_the_shape_and_moves_the_facets(world):
    """scene.facet_turn rotates every cylinder's facets about its axis: the same surface area per
    part and the same bone axes, other facet centroids; a whole side's turn gives the same facets back."""
    rng = np.random.default_rng(0)
    subj = Subject.sample(0, rng, world.kinematics, world.scene.finger_radius_m)
    pose = Motion("grasp", subj, 0.0, 1.8, world.kinematics, rng).pose(np.array([0.0, 0.1]))

    def facets(turn):
        surf = build_surfaces(pose, world.effects, dataclasses.replace(world.scene, facet_turn=turn))
        c, _, area = facet_geometry(surf.triangles)
        return surf, c, area

    base, c0, a0 = facets(0.0)
    half, c1, a1 = facets(0.5)
    whole, c2, _ = facets(1.0)
    k = base.part == base.part_names.index("palm")  # the palm's fan apex moves: same slab, other facets
    assert a1[:, k].sum(1) == pytest.approx(a0[:, k].sum(1), rel=1e-9)
    assert np.abs(c1[:, k] - c0[:, k]).max() > 1e-3
    for name in ("index_proximal", "forearm"):
        k = base.part == base.part_names.index(name)
        assert a1[:, k].sum(1) == pytest.approx(a0[:, k].sum(1), rel=1e-9)  # the same area
        assert c1[:, k].mean(1) == pytest.approx(c0[:, k].mean(1), abs=1e-9)  # the same axis
        assert np.abs(c1[:, k] - c0[:, k]).max() > 1e-3  # other facets
        # one whole side: the same set of centroids, shifted by one facet index
        d = np.linalg.norm(c2[0, k][:, None] - c0[0, k][None], axis=-1)
        assert d.min(1).max() < 1e-9


def test_facet_turn_is_part_of_the_world_cache_key(world, radar, chain, tmp_path):
    from handradar.world.generate import dataset_path

    turned = dataclasses.replace(world, scene=dataclasses.replace(world.scene, facet_turn=0.5))
    assert dataset_path(world, radar, chain, tmp_path) != dataset_path(turned, radar, chain, tmp_path)
