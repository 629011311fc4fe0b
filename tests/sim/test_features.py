"""Per-bone features against closed forms; the HDF5 cache (reuse, atomicity, resume)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import torch

import handradar.sim.features as features_mod
from handradar.hand.mesh import bone_radii, default_template
from handradar.hand.model import HandModelConfig
from handradar.hand.retarget import standard_hand
from handradar.hand.skeleton import BONE_CHILD, BONE_PARENT
from handradar.hand.visibility import visibility
from handradar.sim.features import (
    FEATURE_NAMES,
    BoneFeatures,
    bone_features,
    cached_bone_features,
)
from handradar.sim.rcs import cos_angle, cylinder_rcs_m2

WAVELENGTH = 3.8e-3
RAW = HandModelConfig(retarget=False, visibility_stride=4)


def scaled_hand(times: np.ndarray, a: float, b: float) -> np.ndarray:
    """Hand scaled about the radar: every point's range is |p0| s(t), s = 1 + a t + b t^2 / 2."""
    p0 = standard_hand() + [0.02, -0.07, 0.30]
    s = 1 + a * times + 0.5 * b * times**2
    pos = np.zeros((len(times), 2, 21, 3))
    pos[:, 0] = p0[None] * s[:, None, None]
    return pos


def test_feature_names():
    assert FEATURE_NAMES == ("visible_vertices", "rcs_m2", "distance_m", "radial_velocity_m_s",
                             "radial_acceleration_m_s2")


def test_distance_velocity_acceleration_match_closed_form():
    t = np.arange(12) / 100.0
    a, b = -0.8, 3.0
    pos = scaled_hand(t, a, b)
    mask = np.zeros((12, 2), bool)
    mask[:, 0] = True
    f = bone_features(pos, t, mask, WAVELENGTH, RAW).features
    mid0 = 0.5 * (pos[0, 0, BONE_PARENT] + pos[0, 0, BONE_CHILD])
    r0 = np.linalg.norm(mid0, axis=-1)  # (19,)
    s = 1 + a * t + 0.5 * b * t**2
    np.testing.assert_allclose(f[:, 0, :, 2], r0[None] * s[:, None], rtol=1e-5)
    # central differences are exact on a quadratic inside the window
    np.testing.assert_allclose(f[1:-1, 0, :, 3], r0[None] * (a + b * t[1:-1, None]), rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(f[2:-2, 0, :, 4], r0[None] * b * np.ones((8, 1)), rtol=1e-3)
    # radial velocity sign: receding is positive
    assert (f[1, 0, :, 3] < 0).all()
    assert (f[:, 1] == 0).all()  # untracked hand


def test_rcs_and_visibility_features_are_the_shared_definitions():
    t = np.arange(3) / 100.0
    pos = scaled_hand(t, 0.0, 0.0)
    pos[:, 1] = standard_hand(hand="left") + [0.12, -0.05, 0.36]
    mask = np.ones((3, 2), bool)
    cfg = HandModelConfig(visibility_stride=1)
    out = bone_features(pos, t, mask, WAVELENGTH, cfg)
    joints = cfg.joints(pos)
    mid = 0.5 * (joints[..., BONE_PARENT, :] + joints[..., BONE_CHILD, :])
    axis = joints[..., BONE_CHILD, :] - joints[..., BONE_PARENT, :]
    rcs = cylinder_rcs_m2(cos_angle(torch.as_tensor(mid), torch.as_tensor(axis)), torch.as_tensor(bone_radii()),
                          torch.as_tensor(np.linalg.norm(axis, axis=-1)), WAVELENGTH).numpy()
    np.testing.assert_allclose(out.features[..., 1], rcs, rtol=1e-5)
    vis = visibility(joints, mask, template=default_template(), stride=1)
    np.testing.assert_array_equal(out.features[..., 0], vis.visible)
    np.testing.assert_array_equal(out.facing, vis.facing)
    assert 0 < out.visible_fraction().mean() <= 1


def test_untracked_gap_is_zero_and_does_not_spike_the_derivatives():
    t = np.arange(20) / 100.0
    pos = scaled_hand(t, 0.5, 0.0)
    mask = np.zeros((20, 2), bool)
    mask[:, 0] = True
    mask[8:11, 0] = False
    pos[8:11, 0] = 0.0
    f = bone_features(pos, t, mask, WAVELENGTH, RAW).features
    assert (f[8:11, 0] == 0).all()
    r0 = np.linalg.norm(0.5 * (pos[0, 0, BONE_PARENT] + pos[0, 0, BONE_CHILD]), axis=-1)
    # the distance grows linearly, so bridging the gap linearly keeps the velocity exact beside it
    np.testing.assert_allclose(f[[7, 11], 0, :, 3], np.broadcast_to(0.5 * r0, (2, 19)), rtol=1e-4)


def _windows(n: int = 3, steps: int = 6):
    t = np.arange(steps) / 100.0
    pos = np.stack([scaled_hand(t, 0.3 * i, 0.0) for i in range(n)]).astype(np.float32)
    masks = np.zeros((n, steps, 2), bool)
    masks[..., 0] = True
    return pos, t, masks


def test_cache_is_reused_and_written_atomically(tmp_path, monkeypatch):
    pos, t, masks = _windows()
    first = cached_bone_features(pos, t, masks, WAVELENGTH, RAW, tmp_path)
    files = sorted(p.name for p in tmp_path.iterdir())
    assert len(files) == 2 and files[0].startswith("bone_features-") and files[0].endswith(".h5")
    assert files[1] == files[0] + ".lock"  # nothing else: no temporary or partial file is left
    direct = bone_features(pos[1], t, masks[1], WAVELENGTH, RAW)
    np.testing.assert_array_equal(first.features[1], direct.features)

    def boom(*a, **k):
        raise AssertionError("recomputed although cached")

    monkeypatch.setattr(features_mod, "bone_features", boom)
    again = cached_bone_features(pos, t, masks, WAVELENGTH, RAW, tmp_path)
    np.testing.assert_array_equal(again.features, first.features)
    # another hand model is another key
    with pytest.raises(AssertionError, match="recomputed"):
        cached_bone_features(pos, t, masks, WAVELENGTH, HandModelConfig(retarget=True, visibility_stride=4), tmp_path)


def _spy(monkeypatch, before=None) -> list[int]:
    """Patch bone_features to count its calls (and call ``before(count)`` first); the calls list."""
    calls: list[int] = []

    def counted(p, *a, **k):
        calls.append(1)
        if before is not None:
            before(len(calls))
        return bone_features(p, *a, **k)

    monkeypatch.setattr(features_mod, "bone_features", counted)
    return calls


def test_interrupted_run_leaves_no_cache_and_resumes(tmp_path, monkeypatch):
    pos, t, masks = _windows(n=4)

    def interrupt_third(count):
        if count == 3:
            raise KeyboardInterrupt

    _spy(monkeypatch, interrupt_third)
    with pytest.raises(KeyboardInterrupt):
        cached_bone_features(pos, t, masks, WAVELENGTH, RAW, tmp_path, chunk=1)
    assert not list(tmp_path.glob("*.h5"))  # no final file, only the resumable partial
    assert len(list(tmp_path.glob("*.h5.partial"))) == 1
    calls = _spy(monkeypatch)
    out = cached_bone_features(pos, t, masks, WAVELENGTH, RAW, tmp_path, chunk=1)
    assert len(calls) == 2  # rows 2 and 3 only
    assert isinstance(out, BoneFeatures) and out.features.shape == (4, 6, 2, 19, 5)
    np.testing.assert_array_equal(out.features[3], bone_features(pos[3], t, masks[3], WAVELENGTH, RAW).features)
    assert not list(tmp_path.glob("*.partial"))


def test_concurrent_builders_of_one_key_compute_once(tmp_path, monkeypatch):
    """Two jobs of a sweep asking for the same features at once: one computes, the other reads."""
    pos, t, masks = _windows(n=3)
    # each row slow enough for the other thread to arrive while this one computes
    calls = _spy(monkeypatch, lambda count: time.sleep(0.05))
    start = threading.Barrier(2)
    results, errors = [], []

    def job():
        start.wait()
        try:
            results.append(cached_bone_features(pos, t, masks, WAVELENGTH, RAW, tmp_path, chunk=1))
        except BaseException as exc:  # noqa: BLE001 - reported by the assertion below
            errors.append(exc)

    threads = [threading.Thread(target=job) for _ in range(2)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert errors == [] and len(results) == 2
    assert len(calls) == 3  # each row once, not once per job
    np.testing.assert_array_equal(results[0].features, results[1].features)
    assert not list(tmp_path.glob("*.partial"))


@pytest.mark.slow  # process start-up dominates: several seconds
def test_parallel_rows_equal_serial(tmp_path):
    pos, t, masks = _windows(n=3)
    serial = cached_bone_features(pos, t, masks, WAVELENGTH, RAW)
    parallel = cached_bone_features(pos, t, masks, WAVELENGTH, RAW, tmp_path, chunk=2, n_jobs=2)
    np.testing.assert_array_equal(parallel.features, serial.features)
