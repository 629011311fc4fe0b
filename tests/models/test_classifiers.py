"""Classifiers for 1 x 64 x 32 spectrograms (ResNets, the compact CNN): shapes, adapted stem, the transferable
backbone, learning on separable data."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from torch import nn

from handradar.models.classifiers import (
    backbone_state,
    compact_cnn,
    replace_head,
    resnet18,
    resnet50,
)
from handradar.tasks.classify import evaluate, recompute_bn_stats
from tests.tasks.fakes import class_pattern


@pytest.mark.parametrize("factory", [resnet18, resnet50])
def test_accepts_spectrogram_batches(factory):
    net = factory(num_classes=7).eval()
    assert net.conv1.in_channels == 1 and net.conv1.stride == (1, 1)
    assert isinstance(net.maxpool, nn.Identity)
    seen = {}

    def hook(module, inputs, output) -> None:
        seen["shape"] = tuple(output.shape)

    net.layer4.register_forward_hook(hook)
    with torch.no_grad():
        out = net(torch.rand(3, 1, 64, 32))
    assert out.shape == (3, 7)
    assert seen["shape"][2:] == (8, 4)  # no early downsampling: the last block still sees 8 x 4 cells
    assert torch.isfinite(out).all()


def test_random_initialisation_differs_by_seed():
    torch.manual_seed(0)
    a = resnet18(3)
    torch.manual_seed(1)
    b = resnet18(3)
    assert not torch.equal(a.conv1.weight, b.conv1.weight)


def test_replace_head_keeps_backbone():
    net = resnet18(13)
    state = backbone_state(net)
    assert not any(k.startswith("fc.") for k in state)
    fresh = replace_head(resnet18(13), 5)
    missing, unexpected = fresh.load_state_dict(state, strict=False)
    assert set(missing) == {"fc.weight", "fc.bias"} and not unexpected
    assert fresh(torch.rand(2, 1, 64, 32)).shape == (2, 5)
    assert torch.equal(fresh.layer1[0].conv1.weight, net.layer1[0].conv1.weight)


def _separable(n_per_class: int, classes: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    y = np.repeat(np.arange(classes), n_per_class)
    return np.stack([class_pattern(int(c), rng, noise=0.2) for c in y]), y


def _train(net: nn.Module, x: np.ndarray, y: np.ndarray, steps: int, lr: float = 2e-3) -> None:
    torch.manual_seed(0)
    opt = torch.optim.AdamW(net.parameters(), lr=lr)
    xt, yt = torch.as_tensor(x)[:, None], torch.as_tensor(y)
    g = torch.Generator().manual_seed(0)
    net.train()
    for _ in range(steps):
        idx = torch.randint(len(yt), (16,), generator=g)
        loss = nn.functional.cross_entropy(net(xt[idx]), yt[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()


@pytest.fixture(scope="module")
def short_trained() -> tuple[nn.Module, float, np.ndarray, np.ndarray]:
    """ResNet-18 after 10 steps on 24 examples (stem_stride 2 keeps this CPU test short; the
    architecture is otherwise the default one), its accuracy before training, and the data."""
    torch.manual_seed(0)
    x, y = _separable(6, 4, seed=0)
    net = resnet18(4, stem_stride=2)
    tx, ty = _separable(10, 4, seed=1)
    before, _ = evaluate(net, tx, ty, 4)
    _train(net, x, y, steps=10)
    return net, before, x, y


def test_resnet18_learns_separable_classes(short_trained):
    net, before, x, _ = short_trained
    net = copy.deepcopy(net)
    tx, ty = _separable(10, 4, seed=1)
    recompute_bn_stats(net, x)
    acc, cm = evaluate(net, tx, ty, 4)
    assert before < 0.6 and acc >= 0.9, (before, acc, cm)
    assert cm.sum() == len(ty) and np.trace(cm) == round(acc * len(ty))


def test_precise_bn_replaces_lagging_running_stats(short_trained):
    """After a short training the running averages lag the weights; precise BN gives the exact
    batch statistics of the final network on the training data."""
    net, _, x, _ = short_trained
    net = copy.deepcopy(net)
    bn = net.layer4[1].bn2
    lagging = bn.running_mean.clone()
    recompute_bn_stats(net, x)
    feats = {}

    def hook(module, inputs, output) -> None:
        feats["out"] = output

    net.layer4[1].conv2.register_forward_hook(hook)
    net.train()
    with torch.no_grad():
        net(torch.as_tensor(x)[:, None])
    exact = feats["out"].mean(dim=(0, 2, 3))
    assert torch.allclose(bn.running_mean, exact, atol=1e-4)
    assert not torch.allclose(lagging, exact, atol=1e-2)


@pytest.mark.slow
def test_resnet50_learns_separable_classes():
    torch.manual_seed(0)
    x, y = _separable(6, 4, seed=0)
    tx, ty = _separable(10, 4, seed=1)
    net = resnet50(4)
    _train(net, x, y, steps=15)
    recompute_bn_stats(net, x)
    acc, _ = evaluate(net, tx, ty, 4)
    assert acc >= 0.9


@pytest.mark.parametrize("shape", [(64, 32), (64, 64), (32, 16)])
def test_compact_cnn_sizes_and_head(shape):
    """Any input of at least 2^3 a side gives (B, classes) logits; the head is ``fc`` alone, so pre-training moves
    every convolution and BatchNorm and no head (backbone_state)."""
    net = compact_cnn(5, channels=(16, 32, 64), pooled=(4, 4)).eval()
    assert net(torch.rand(3, 1, *shape)).shape == (3, 5)
    assert sum(p.numel() for p in net.parameters()) < 40_000
    state = backbone_state(net)
    fresh = compact_cnn(8)
    missing, unexpected = fresh.load_state_dict(state, strict=False)
    assert set(missing) == {"fc.weight", "fc.bias"} and not unexpected


def test_compact_cnn_learns_separable_classes():
    torch.manual_seed(0)
    x, y = _separable(6, 4, seed=0)
    net = compact_cnn(4)
    tx, ty = _separable(10, 4, seed=1)
    before, _ = evaluate(net, tx, ty, 4)
    _train(net, x, y, steps=60, lr=5e-3)
    recompute_bn_stats(net, x)
    acc, _ = evaluate(net, tx, ty, 4)
    assert before < 0.6 and acc >= 0.9, (before, acc)

