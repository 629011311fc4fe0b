"""Standard-hand retargeting: standard lengths, measured directions, wrist kept."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from handradar.hand.retarget import (
    WRIST_TO_THUMB_CMC_M,
    retarget,
    standard_hand,
    standard_lengths,
)
from handradar.hand.skeleton import BONE_CHILD, BONE_PARENT, BONES


def _lengths(j: np.ndarray) -> np.ndarray:
    return np.linalg.norm(j[..., BONE_CHILD, :] - j[..., BONE_PARENT, :], axis=-1)


def test_standard_hand_has_standard_lengths_and_is_a_fixed_point():
    h = standard_hand()
    np.testing.assert_allclose(_lengths(h), standard_lengths(), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(h[1] - h[0]), WRIST_TO_THUMB_CMC_M, atol=1e-12)
    np.testing.assert_allclose(retarget(h).numpy(), h, atol=1e-12)
    left = standard_hand(hand="left")
    np.testing.assert_allclose(left[:, 0], -h[:, 0])


def test_retarget_sets_lengths_keeps_directions_and_wrist():
    rng = np.random.default_rng(0)
    measured = standard_hand(scale=1.3) + rng.normal(scale=0.004, size=(21, 3)) + [0.1, -0.05, 0.3]
    out = retarget(measured[None]).numpy()[0]
    np.testing.assert_allclose(out[0], measured[0])  # wrist is the origin of the rebuild
    np.testing.assert_allclose(_lengths(out), standard_lengths(), rtol=1e-10)
    for (a, b) in BONES:
        d_in = (measured[b] - measured[a]) / np.linalg.norm(measured[b] - measured[a])
        d_out = (out[b] - out[a]) / np.linalg.norm(out[b] - out[a])
        np.testing.assert_allclose(d_out, d_in, atol=1e-10)


def test_scale_and_degenerate_bones():
    h = standard_hand()
    np.testing.assert_allclose(_lengths(retarget(h, standard_lengths(0.9)).numpy()), 0.9 * standard_lengths(), rtol=1e-10)
    bad = h.copy()
    bad[8] = bad[7]  # zero-length index distal bone: no direction, stays zero length
    out = retarget(bad).numpy()
    assert np.linalg.norm(out[8] - out[7]) == 0.0
    assert np.allclose(retarget(np.zeros((2, 21, 3))).numpy(), 0.0)  # untracked hands stay zero


def test_retarget_is_differentiable():
    x = torch.as_tensor(standard_hand() + [0.0, 0.0, 0.3], dtype=torch.float64).requires_grad_(True)
    torch.autograd.gradcheck(lambda p: retarget(p), (x,))


def test_rejects_bad_shapes():
    with pytest.raises(ValueError, match=r"\(21, 3\)"):
        retarget(np.zeros((20, 3)))
    with pytest.raises(ValueError, match="lengths"):
        retarget(np.zeros((21, 3)), np.ones(18))
