"""The world built differently (``world=scatterers``): bone point scatterers with their own RCS law,
the Leap jitter floor, and cache keys of the worlds cached before them unchanged."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from handradar.config import VERSION_BASE, config_dir
from handradar.data.recording import load_recording
from handradar.gap.benchmark import benchmark_world, case_world, cases
from handradar.runs.mlflow import flatten
from handradar.world.config import BonePoints, WorldConfig, world_config
from handradar.world.generate import (
    RecordingSpec,
    dataset_path,
    fast_example,
    simulate,
    subject,
    write_recording,
)
from handradar.world.geometry import Cone, Part, build_parts, occluders_of
from handradar.world.kinematics import Motion
from handradar.world.points import bone_points, point_rcs
from handradar.world.scattering import amplitude_scale
from handradar.world.scene import point_tracks
from handradar.world.sensor import observe

LAW = BonePoints(spacing_m=1.0, rcs_per_area=1.0, exponent=4.0, isotropic=0.1)  # spacing 1 m: 4 points a ring


def _cylinder(name: str, centre: np.ndarray, half_length: float, radius: float, up: np.ndarray, slot: int = 0) -> Part:
    """A straight cylinder along x through ``centre`` (T, 3), its azimuth 0 along ``up`` (T, 3)."""
    t = len(centre)
    axis = np.broadcast_to([1.0, 0.0, 0.0], (t, 3)).copy()
    u = up - (up * axis).sum(-1, keepdims=True) * axis
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    cone = Cone(centre - half_length * axis, axis, u, np.cross(axis, u), np.zeros(t), np.full(t, 2 * half_length),
                radius, radius, 1, 1, 0.0)
    return Part(name, slot, np.zeros((t, 0, 3)), np.zeros((0, 3), np.int64), cones=[cone])


def _world(**scene: object) -> WorldConfig:
    w = WorldConfig()
    return dataclasses.replace(w, effects=w.effects.only(), scene=dataclasses.replace(w.scene, scattering="bone_points",
                                                                                     **scene))


def _compose(config: str, *overrides: str):
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        return compose(config, overrides=list(overrides))


def test_point_rcs_follows_the_stated_law():
    """sigma = dA (rho cos^q + rho_iso) in front, 0 behind; bistatic from the half-vector."""
    scene = dataclasses.replace(WorldConfig().scene, points=LAW)
    theta = np.deg2rad([0.0, 20.0, 45.0, 70.0, 89.0, 91.0, 135.0])
    u = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], -1)
    n = np.broadcast_to([0.0, 0.0, 1.0], u.shape)
    got = point_rcs(n, np.full(len(theta), 2e-4), u, u, scene)
    want = np.where(np.cos(theta) > 0, 2e-4 * (np.clip(np.cos(theta), 0, None) ** 4 + 0.1), 0.0)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)
    # bistatic: in at +30 deg, out at -30 deg is the mirror direction, so the half-vector is the normal
    a = np.deg2rad(30.0)
    s = point_rcs(n[0], np.array(1.0), np.array([np.sin(a), 0, np.cos(a)]), np.array([-np.sin(a), 0, np.cos(a)]), scene)
    assert s == pytest.approx(1.1)


def test_one_point_return_follows_cos_q_and_one_over_r_squared():
    """A thin cylinder turns about its axis while it rises from 0.2 to 0.4 m above the antenna; each of
    its four points' amplitude is K sqrt(g dA (cos^q + rho_iso)) / R^2 with the incidence and range
    computed here from the geometry, dA = 2 pi a L / 4 the closed-form quarter of the mantle, and its
    phase is constant (the renderer adds the carrier)."""
    t = 73
    alpha = np.linspace(0, 2 * np.pi, t)
    centre = np.stack([np.zeros(t), np.zeros(t), np.linspace(0.2, 0.4, t)], -1)
    up = np.stack([np.zeros(t), np.sin(alpha), np.cos(alpha)], -1)
    a, half = 0.001, 0.002
    parts = [_cylinder("rod", centre, half, a, up)]
    scene = dataclasses.replace(_world().scene, points=LAW, prune_db=300.0)
    fx = WorldConfig().effects.only()
    tracks, _ = point_tracks(parts, occluders_of(parts), fx, scene, np.random.default_rng(3), np.arange(t) * 0.01, 1)
    ps = bone_points(parts, LAW.spacing_m, np.random.default_rng(3))  # the same draw: the same points
    assert len(ps.area) == 4
    np.testing.assert_allclose(ps.area, 2 * np.pi * a * 2 * half / 4, rtol=1e-12)
    p = ps.points
    normal = p - centre[:, None, :]  # outward from the axis (the rod lies along x through the centre)
    normal[..., 0] = 0.0
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    r = np.linalg.norm(p, axis=-1)
    cos_t = (normal * -p).sum(-1) / r
    for i in range(4):
        col = np.flatnonzero(np.abs(tracks.ranges - r[:, i:i + 1]).max(0) < 1e-12)
        assert len(col) == 1
        amp = tracks.amplitudes[:, col[0]]
        sigma = ps.gain[i] * ps.area[i] * np.where(cos_t[:, i] > 0, np.clip(cos_t[:, i], 0, None) ** 4 + 0.1, 0.0)
        want = amplitude_scale(scene) * np.sqrt(sigma) / r[:, i] ** 2
        np.testing.assert_allclose(np.abs(amp), want, rtol=1e-9, atol=1e-12 * want.max())
        lit = np.abs(amp) > 0
        assert 0.3 < lit.mean() < 0.7  # half a turn in front of the antenna
        np.testing.assert_allclose(np.angle(amp[lit] * np.exp(-1j * ps.phase[i])), 0.0, atol=1e-9)


def test_a_point_behind_another_part_is_hidden_only_with_occlusion():
    """A thin rod 0.35 m up, straight behind a thick one at 0.2 m: with occlusion its points return
    nothing, without it they do; the front rod returns in both."""
    t = 6
    z = np.ones((t, 1))
    up = np.broadcast_to([0.0, 0.0, -1.0], (t, 3)).copy()
    parts = [_cylinder("front", z * [0.0, 0.0, 0.2], 0.05, 0.03, up),
             _cylinder("behind", z * [0.0, 0.0, 0.35], 0.02, 0.005, up)]
    scene = dataclasses.replace(_world().scene, points=dataclasses.replace(LAW, spacing_m=0.004))
    fx = WorldConfig().effects.only()

    def energy(occlusion: bool) -> dict[str, float]:
        tr, _ = point_tracks(parts, occluders_of(parts), fx.with_("occlusion", enabled=occlusion), scene,
                             np.random.default_rng(0), np.arange(t) * 0.01, 2)
        return {name: float((np.abs(tr.amplitudes[:, tr.label == f"0:{name}"]) ** 2).sum())
                for name in ("front", "behind")}

    on, off = energy(True), energy(False)
    assert on["behind"] == 0.0 and off["behind"] > 0.0
    assert on["front"] == pytest.approx(off["front"]) and on["front"] > 0.0


def test_points_cover_every_part_and_follow_the_palm_and_forearm_effects():
    """The points stand for each part's whole surface (their areas sum to the part's); switching the
    palm and forearm effects off removes exactly those parts' points."""
    w = _world()
    pose = Motion("double_hand_clap", subject(w, 0), 0.0, 0.5, w.kinematics, np.random.default_rng(0)).pose(
        np.arange(0.0, 0.2, 0.01))
    parts = build_parts(pose, w.effects.with_("palm", enabled=True).with_("forearm", enabled=True), w.scene)
    ps = bone_points(parts, w.scene.points.spacing_m, np.random.default_rng(0))
    for i, p in enumerate(parts):
        assert ps.area[ps.part == i].sum() == pytest.approx(p.area(), rel=1e-9), p.name
    names = {lab.split(":")[1] for lab in ps.label}
    assert {"palm", "forearm"} <= names
    bare = build_parts(pose, w.effects.only(), w.scene)
    bare_names = {lab.split(":")[1] for lab in bone_points(bare, 0.008, np.random.default_rng(0)).label}
    assert bare_names == names - {"palm", "forearm"}
    assert 0.8 < ps.gain.mean() < 1.2 and (ps.gain > 0).all()  # Exponential(1) gains over ~3000 points


def test_jitter_floor_has_the_set_rms_with_every_effect_off(world):
    """With every effect off the Leap reports the true joints exactly; the floor adds white noise of
    the set 3-D rms (within sampling error) and changes no other draw."""
    w = dataclasses.replace(world, effects=world.effects.only())
    floor = dataclasses.replace(w.leap, jitter_floor_m=0.0004)
    motion = Motion("finger_wave", subject(w, 0), 0.0, 2.4, w.kinematics, np.random.default_rng(1))
    clean = observe(motion, 2.4, w.leap, w.effects, np.random.default_rng(7))
    noisy = observe(motion, 2.4, floor, w.effects, np.random.default_rng(7))
    np.testing.assert_array_equal(clean.stamps_us, noisy.stamps_us)
    truth = motion.pose((clean.stamps_us - clean.radar_start_us) * 1e-6).joints
    present = motion.pose(np.zeros(1)).present
    np.testing.assert_allclose(clean.radar_nominal[:, present], truth[:, present], atol=1e-12)
    dev = (noisy.radar_nominal - truth)[:, present]  # (frames, hands, 21, 3)
    n = dev.shape[0] * dev.shape[1] * dev.shape[2]
    rms = math.sqrt((dev ** 2).sum(-1).mean())
    assert rms == pytest.approx(0.0004, rel=6 / math.sqrt(2 * 3 * n))  # the estimate's relative sd: 1 / sqrt(2 * 3n)
    lag1 = np.corrcoef(dev[1:].ravel(), dev[:-1].ravel())[0, 1]
    assert abs(lag1) < 0.05  # white, unlike tracking_jitter's correlated noise


def test_scatterers_world_composes_keeps_the_floor_in_every_case_and_generates(radar, chain, tmp_path):
    """world=scatterers composes (bone points, the floor, its own seed); the gap benchmark's cases keep
    the floor (it is no effect); one short recording is written end to end and the fast path runs."""
    cfg = _compose("world", "out=/tmp/unused", "world=scatterers")
    w = world_config(cfg.world)
    assert w.scene.scattering == "bone_points" and w.leap.jitter_floor_m == pytest.approx(0.0004)
    seeds = {world_config(_compose("world", "out=/tmp/unused", f"world={n}").world).seed
             for n in ("default", "heldout", "heldout2", "heldout3")}
    assert w.seed not in seeds
    bench = _compose("diagnose", "+experiment=gap_benchmark", "world=scatterers")
    for case in cases(bench.benchmark.cases):
        cw = world_config(case_world(benchmark_world(bench), case))
        assert cw.leap.jitter_floor_m == pytest.approx(0.0004) and cw.scene.scattering == "bone_points"
    small = dataclasses.replace(w, capture_frames=17, subjects=1, repetitions=1, angles_deg=(0.0,), workers=1)
    spec = RecordingSpec("double_hand_clap", 0, 0.0, 0)
    folder = write_recording(small, radar, spec, tmp_path / spec.name)
    rec = load_recording(folder)
    assert rec.n_frames == 17 and rec.meta.hands == 2
    sim = simulate(small, radar, spec)
    assert sim.tracks.surface is None and sim.truth["n_scatterers"] > 300
    row = fast_example(small, radar, chain, spec)
    assert np.isfinite(row["spectrogram"]).all() and row["spectrogram"].std() > 0.01


def test_world_presets_change_no_diagnosis_setting():
    """Under the gap benchmark, world=scatterers differs from world=default only in world settings."""
    def settings(name: str) -> dict:
        c = OmegaConf.to_container(_compose("diagnose", "+experiment=gap_benchmark", f"world={name}"), resolve=True)
        return {k: v for k, v in flatten(c).items() if not k.startswith(("world.", "data.dataset.world."))}

    assert settings("scatterers") == settings("default")


# measured on conf/world/*.yaml with the test radar and chain BEFORE scene.scattering, scene.points and
# leap.jitter_floor_m existed: regression values, the cached worlds must keep these keys
KEYS_BEFORE = {"default": "9b580ba41f4781d4", "heldout": "85b0f7d9e53a9746", "heldout2": "bc237c43ed86ac55",
               "heldout3": "48161a4d8367afac", "strong_jitter": "0b623c8b7a19b55e"}


@pytest.mark.parametrize("name", sorted(KEYS_BEFORE))
def test_cache_keys_of_the_worlds_cached_before_are_unchanged(name, radar, chain, tmp_path):
    w = world_config(_compose("world", "out=/tmp/unused", f"world={name}").world)
    assert dataset_path(w, radar, chain, tmp_path)[1] == KEYS_BEFORE[name]


def test_later_settings_enter_the_key_only_where_they_change_the_data(radar, chain, tmp_path):
    def key(w: WorldConfig) -> str:
        return dataset_path(w, radar, chain, tmp_path)[1]

    w = WorldConfig()
    other_points = dataclasses.replace(w.scene, points=dataclasses.replace(w.scene.points, spacing_m=0.01))
    assert key(dataclasses.replace(w, scene=other_points)) == key(w)  # unread by the surfaces
    pts = dataclasses.replace(w, scene=dataclasses.replace(w.scene, scattering="bone_points"))
    assert key(pts) != key(w)
    assert key(dataclasses.replace(pts, scene=dataclasses.replace(other_points, scattering="bone_points"))) != key(pts)
    assert key(dataclasses.replace(w, leap=dataclasses.replace(w.leap, jitter_floor_m=0.0004))) != key(w)
    with pytest.raises(ValueError, match="scattering"):
        world_config({"scene": {"scattering": "spheres"}})
