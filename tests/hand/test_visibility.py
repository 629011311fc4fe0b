"""Visible-vertex counts of known scenes against ray casting and analytic expectations; the analytic
(batched, closed-form) backend against the exact ray caster on real and random scenes."""

from __future__ import annotations

import numpy as np
import pytest

from handradar.hand.importers.sfinge3d import read_sfinge3d
from handradar.hand.mesh import bone_radii, bone_vertices, default_template
from handradar.hand.model import HandModelConfig
from handradar.hand.placement import place_in_radar
from handradar.hand.retarget import standard_hand
from handradar.hand.visibility import (
    _analytic_counts,
    _facing,
    embree_available,
    visibility,
    visibility_step,
)
from tests.sim.demo import window

THUMB_DISTAL, PINKY_DISTAL = 2, 18  # leaf bones: joints 3 -> 4 and 19 -> 20


def one_cylinder_hand(start, end, bone: int) -> np.ndarray:
    """A 'hand' whose only non-zero bone is the leaf ``bone`` from start to end (others collapse)."""
    j = np.tile(np.asarray(start, float), (21, 1))
    j[{THUMB_DISTAL: 4, PINKY_DISTAL: 20}[bone]] = end
    return j


def radii(front: float, back: float) -> np.ndarray:
    r = bone_radii()
    r[THUMB_DISTAL], r[PINKY_DISTAL] = front, back
    return r


BACKENDS = ["analytic", "triangle"] + (["embree"] if embree_available() else [])


@pytest.mark.parametrize("backend", BACKENDS)
def test_side_by_side_cylinders_show_their_whole_front_half(backend):
    scene = np.stack([one_cylinder_hand((-0.08, 0, 0.3), (-0.04, 0, 0.3), THUMB_DISTAL),
                      one_cylinder_hand((0.04, 0.01, 0.3), (0.08, 0.01, 0.3), PINKY_DISTAL)])
    vis, facing = visibility_step(scene, radii=radii(0.01, 0.01), backend=backend)
    assert vis[0, THUMB_DISTAL] == facing[0, THUMB_DISTAL] and vis[1, PINKY_DISTAL] == facing[1, PINKY_DISTAL]
    # front half: 11 of the 20 vertices of each of the 21 rings have a side face toward the radar; the
    # cap nearer to x = 0 faces the radar too, adding its centre and the 9 other vertices of its ring
    assert facing[0, THUMB_DISTAL] == 21 * 11 + 9 + 1
    assert vis.sum() == facing.sum()  # collapsed bones have no facing vertex


@pytest.mark.parametrize("backend", BACKENDS)
def test_cylinder_directly_behind_a_larger_one_is_hidden(backend):
    scene = np.stack([one_cylinder_hand((-0.05, 0, 0.25), (0.05, 0, 0.25), THUMB_DISTAL),
                      one_cylinder_hand((-0.03, 0, 0.40), (0.03, 0, 0.40), PINKY_DISTAL)])
    vis, facing = visibility_step(scene, radii=radii(0.02, 0.005), backend=backend)
    assert facing[1, PINKY_DISTAL] > 200 and vis[1, PINKY_DISTAL] == 0
    assert vis[0, THUMB_DISTAL] == facing[0, THUMB_DISTAL]
    # alone, the back cylinder is fully visible again
    v_alone, f_alone = visibility_step(scene[1:], radii=radii(0.02, 0.005), backend=backend)
    assert v_alone[0, PINKY_DISTAL] == f_alone[0, PINKY_DISTAL] == facing[1, PINKY_DISTAL]


@pytest.mark.parametrize("backend", BACKENDS)
def test_overlapping_cylinders_do_not_count_as_shadowing_each_other(backend):
    """Two side-by-side cylinders 1.2 radii apart overlap (like a flat hand's metacarpals): the vertices
    each buries inside the other are neither facing nor visible, so both stay in (nearly) full view: a
    few vertices next to the seam are in the other's true, grazing shadow."""
    r = 0.01
    scene = np.stack([one_cylinder_hand((-0.04, 0, 0.3), (0.04, 0, 0.3), THUMB_DISTAL),
                      one_cylinder_hand((-0.04, 1.2 * r, 0.3), (0.04, 1.2 * r, 0.3), PINKY_DISTAL)])
    vis, facing = visibility_step(scene, radii=radii(r, r), backend=backend)
    v_alone, f_alone = visibility_step(scene[:1], radii=radii(r, r), backend=backend)
    for h, bone in ((0, THUMB_DISTAL), (1, PINKY_DISTAL)):
        assert vis[h, bone] >= 0.95 * facing[h, bone] and facing[h, bone] > 0.5 * f_alone[0, THUMB_DISTAL]
        assert facing[h, bone] < f_alone[0, THUMB_DISTAL]  # the buried strip is left out
    # moved 2.2 radii apart they no longer touch: every facing vertex counts again
    apart = scene.copy()
    apart[1, :, 1] += 1.0 * r
    _, f_apart = visibility_step(apart, radii=radii(r, r), backend=backend)
    assert f_apart[0, THUMB_DISTAL] == f_alone[0, THUMB_DISTAL]


def test_flat_hand_is_in_full_view_from_below():
    """A flat hand seen from below hides nothing of itself: every bone > 85 % visible (the metacarpals
    were 27-65 % while overlapping cylinders counted as shadow)."""
    joints = (standard_hand() + [0.0, -0.08, 0.28])[None, None].repeat(2, 1)
    frac = visibility(joints, np.array([[True, False]])).fraction()[0, 0]
    assert frac.min() > 0.85, frac


def _analytic_hidden(points: np.ndarray, a: np.ndarray, b: np.ndarray, r: float) -> np.ndarray:
    """True where the segment from each point to the origin passes through the exact cylinder a-b of radius r."""
    axis = (b - a) / np.linalg.norm(b - a)
    length = np.linalg.norm(b - a)
    s = np.linspace(0.0, 0.999, 4000)[:, None, None] * points[None]  # samples along each segment
    rel = s - a
    along = rel @ axis
    radial = np.linalg.norm(rel - along[..., None] * axis, axis=-1)
    return ((radial < r) & (along >= 0) & (along <= length)).any(0)


def test_partial_shadow_matches_between_backends_and_the_exact_cylinder():
    front_a, front_b = np.array([-0.05, 0.0, 0.25]), np.array([0.004, 0.0, 0.25])  # end off the ring planes
    scene = np.stack([one_cylinder_hand(front_a, front_b, THUMB_DISTAL),
                      one_cylinder_hand((-0.03, 0, 0.40), (0.03, 0, 0.40), PINKY_DISTAL)])
    r = radii(0.02, 0.005)
    counts = {b: visibility_step(scene, radii=r, backend=b) for b in BACKENDS}
    vis, facing = counts[BACKENDS[0]]
    for other in BACKENDS[1:]:
        np.testing.assert_array_equal(counts[other][0], vis)
    # about half of the back cylinder lies in the shadow
    assert 0.3 * facing[1, PINKY_DISTAL] < vis[1, PINKY_DISTAL] < 0.7 * facing[1, PINKY_DISTAL]
    # analytic: the back cylinder's facing vertices (same face-based test as the ray caster) that the
    # exact front cylinder does not shadow
    verts = bone_vertices(scene[1], r)[PINKY_DISTAL]
    facing_mask = _facing(verts[None], default_template())[0]
    expected = (facing_mask & ~_analytic_hidden(verts, front_a, front_b, 0.02)).sum()
    assert facing_mask.sum() == facing[1, PINKY_DISTAL]
    # the faceted front cylinder (inscribed 20-gon) casts a slightly smaller shadow than the exact one:
    # at most a few vertices along the shadow's edge may differ
    assert 0 <= int(vis[1, PINKY_DISTAL]) - int(expected) <= 11


def test_two_hands_occlude_each_other():
    t = np.arange(3) / 100
    right = standard_hand() + [0.0, -0.08, 0.28]
    left = standard_hand(hand="left") + [0.0, -0.08, 0.42]  # right above the left one, seen from the radar
    joints = np.broadcast_to(np.stack([right, left]), (len(t), 2, 21, 3)).copy()
    both = visibility(joints, np.ones((3, 2), bool))
    alone = visibility(joints, np.array([[False, True]] * 3))
    assert both.fraction()[:, 1].mean() < 0.3 * alone.fraction()[:, 1].mean()
    assert both.fraction()[:, 0].mean() > 0.8  # the near hand barely loses anything
    assert (alone.visible[:, 0] == 0).all() and (alone.facing[:, 0] == 0).all()


def test_stride_interpolates_between_cast_steps():
    t = np.arange(7) / 100
    joints = np.zeros((7, 2, 21, 3))
    for i, ti in enumerate(t):
        joints[i, 0] = standard_hand() + [0.0, -0.08, 0.25 + ti]
        joints[i, 1] = standard_hand(hand="left") + [0.02, -0.06, 0.40]
    mask = np.ones((7, 2), bool)
    full = visibility(joints, mask, stride=1)
    strided = visibility(joints, mask, stride=3)  # casts 0, 3, 6
    for s in (0, 3, 6):
        np.testing.assert_array_equal(strided.visible[s], full.visible[s])
    lo, hi = np.minimum(full.visible[0], full.visible[3]), np.maximum(full.visible[0], full.visible[3])
    assert ((strided.visible[1] >= lo) & (strided.visible[1] <= hi)).all()


def test_rejects_bad_input():
    with pytest.raises(ValueError, match="expected joints"):
        visibility(np.zeros((3, 21, 3)), np.ones((3, 2), bool))
    with pytest.raises(ValueError, match="backend"):
        visibility_step(standard_hand()[None] + [0, 0, 0.3], backend="optix")


def test_a_lone_bone_across_the_view_faces_about_half_its_vertices():
    """A cylinder across the line of sight, its caps edge-on: the 10 of 20 side faces that face the
    radar carry 11 of the 20 vertices of each of the 21 rings, 231 of 422, all visible."""
    scene = one_cylinder_hand((-0.03, 0.0, 0.3), (0.03, 0.0, 0.3), THUMB_DISTAL)[None]
    for backend in BACKENDS:
        vis, facing = visibility_step(scene, radii=radii(0.01, 0.01), backend=backend)
        assert facing[0, THUMB_DISTAL] == 21 * 11 and vis[0, THUMB_DISTAL] == facing[0, THUMB_DISTAL]
        assert 0.45 < facing[0, THUMB_DISTAL] / 422 < 0.6


def test_batched_steps_do_not_shadow_each_other():
    """Steps batched into one analytic call are separate scenes: a bone hidden at one step by a
    larger one in front is in full view at the next step, where that one has moved aside."""
    t = 3
    joints = np.zeros((t, 2, 21, 3))
    joints[:, 1] = one_cylinder_hand((-0.03, 0, 0.40), (0.03, 0, 0.40), PINKY_DISTAL)
    joints[0, 0] = one_cylinder_hand((-0.05, 0, 0.25), (0.05, 0, 0.25), THUMB_DISTAL)  # in front
    joints[1, 0] = one_cylinder_hand((0.15, 0, 0.25), (0.25, 0, 0.25), THUMB_DISTAL)  # aside
    joints[2, 0] = joints[0, 0]
    mask = np.array([[True, True], [True, True], [False, True]])  # step 2: the front hand untracked
    r = radii(0.02, 0.005)
    vis = visibility(joints, mask, radii=r, backend="analytic")
    assert vis.facing[0, 1, PINKY_DISTAL] > 200 and vis.visible[0, 1, PINKY_DISTAL] == 0
    for step in (1, 2):
        assert vis.visible[step, 1, PINKY_DISTAL] == vis.facing[step, 1, PINKY_DISTAL] == vis.facing[0, 1, PINKY_DISTAL]
    assert (vis.facing[2, 0] == 0).all() and (vis.visible[2, 0] == 0).all()
    for step in range(t):  # the batch equals one call per step
        hands = np.flatnonzero(mask[step])
        v, f = visibility_step(joints[step, hands], radii=r, backend="analytic")
        np.testing.assert_array_equal(vis.visible[step, hands], v)
        np.testing.assert_array_equal(vis.facing[step, hands], f)


def _compare_with_ray_caster(joints: np.ndarray, mask: np.ndarray, steps) -> tuple[int, int]:
    """Analytic batch vs the exact ray caster (backend "triangle", float64 Moller-Trumbore) one step
    at a time: facing counts must be identical and visible counts within one vertex per bone; returns
    (differing bone-steps, compared bone-steps)."""
    batch = visibility(joints, mask, backend="analytic")
    differ = compared = 0
    for t in steps:
        hands = np.flatnonzero(mask[t])
        v, f = visibility_step(joints[t, hands], backend="triangle")
        np.testing.assert_array_equal(batch.facing[t, hands], f)
        d = np.abs(batch.visible[t, hands].astype(int) - v)
        assert d.max() <= 1, (t, d.max())
        differ, compared = differ + int((d > 0).sum()), compared + d.size
    return differ, compared


def test_analytic_matches_the_ray_caster_on_sfinge3d_and_two_hand_windows(sfinge3d_dir):
    """Real SFINGE3D motion (placed over the radar, 100 Hz, retargeted as the features do) and a
    two-hand demo window: the batched closed-form counts equal the per-step ray caster's, up to a
    vertex in rare bone-steps (measured on 43 windows: 24 of 6688 bone-steps, all +1, where trimesh's
    intersector counts a hit just behind the ray's start)."""
    hand = HandModelConfig()
    times = np.arange(160) / 100.0
    differ = compared = 0
    for rel in ("Dictionary/7/3.txt", "Dictionary/2/5.txt"):  # grab, two
        seq = place_in_radar(read_sfinge3d(sfinge3d_dir / rel), up_axis="y",
                             centre_m=(0.0, 0.0, 0.30))
        win = seq.resample(seq.times[0] + times)
        d, n = _compare_with_ray_caster(hand.joints(win.positions), win.mask, range(0, 160, 40))
        differ, compared = differ + d, compared + n
    pos, mask = window(times, hands=2, seed=3)
    d, n = _compare_with_ray_caster(hand.joints(pos), mask, range(0, 160, 53))
    differ, compared = differ + d, compared + n
    assert differ <= 0.02 * compared, (differ, compared)


def test_culling_keeps_every_shadow_of_random_close_hands():
    """Two flexing hands in random orientations, close enough to shadow, touch and bury each other:
    the analytic backend's conservative culling (bounding balls, depth, wedge and slab conditions)
    gives the same counts as testing every facing vertex against every other cylinder."""
    rng = np.random.default_rng(7)
    times = np.arange(6) / 20.0
    template = default_template()
    for k in range(8):
        pos, _ = window(times, hands=2, seed=k)
        for h in range(2):  # turn each hand about its wrist, then move it near the other
            q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            wrist = pos[:, h, :1]
            pos[:, h] = (pos[:, h] - wrist) @ (q * np.sign(np.linalg.det(q))).T + wrist
        pos[:, 1] += rng.uniform(-0.04, 0.04, 3) - (pos[0, 1, 0] - pos[0, 0, 0]) * 0.6
        joints = pos.reshape(-1, 21, 3).astype(np.float64)
        scene = np.repeat(np.arange(len(times)), 2)
        culled = _analytic_counts(joints, scene, bone_radii(), template)
        full = _analytic_counts(joints, scene, bone_radii(), template, cull=False)
        np.testing.assert_array_equal(culled[1], full[1])
        np.testing.assert_array_equal(culled[0], full[0])
        assert (full[0] < full[1]).any()  # some shadow to keep


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_bone_around_the_radar_hides_the_other_hand(backend):
    """The radar inside a cylinder (a hand on the antenna): every segment from outside to the radar
    crosses that cylinder's surface, so the other hand is hidden; the enclosing bone's own facing
    vertices (its inside faces none) stay 0."""
    scene = np.stack([one_cylinder_hand((-0.05, 0.0, -0.005), (0.05, 0.0, -0.005), THUMB_DISTAL),
                      one_cylinder_hand((-0.03, 0.0, 0.2), (0.03, 0.0, 0.2), PINKY_DISTAL)])
    vis, facing = visibility_step(scene, radii=radii(0.02, 0.01), backend=backend)
    assert facing[1, PINKY_DISTAL] == 21 * 11 and vis[1, PINKY_DISTAL] == 0
    assert vis[0, THUMB_DISTAL] == facing[0, THUMB_DISTAL] == 0


def test_analytic_matches_the_ray_caster_with_a_hand_on_the_radar():
    """Two hands within a few centimetres of the radar, which lies inside the index proximal bone:
    there the ray caster counts only surface crossings, so the neighbouring bones' vertices inside
    that prism too are seen; the analytic backend follows it (with "meets the prism" instead it
    would see none of them). Embree agrees with the exact intersector here and is 1000x faster."""
    rng = np.random.default_rng(1)
    for _ in range(4):  # the fourth of these random scenes
        hands = []
        for side in ("right", "left"):
            q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            hands.append(standard_hand(hand=side) @ q.T + rng.normal(scale=0.03, size=3) + [0, 0, rng.uniform(0.0, 0.12)])
    scene = np.stack(hands)
    vis, facing = visibility_step(scene, backend="analytic")
    ref_vis, ref_facing = visibility_step(scene, backend="embree" if embree_available() else "triangle")
    np.testing.assert_array_equal(facing, ref_facing)
    np.testing.assert_array_equal(vis, ref_vis)
    assert vis[1, 3] > 0 and vis[1, 5] > 0  # index metacarpal and intermediate, around the radar's bone
