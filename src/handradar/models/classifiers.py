"""Spectrogram classifiers: torchvision ResNets adapted to 1 x 64 x 32 micro-Doppler inputs.

ImageNet ResNets open with a 7x7 stride-2 convolution and a stride-2 max-pool: a 64 x 32
spectrogram would be 16 x 8 before the first block and 2 x 1 at the end. Here the stem is one
3x3 convolution over the single channel with stride ``stem_stride`` (1 by default) and no max-pool,
as for CIFAR-sized inputs, so the last block still sees 8 x 4 (Doppler x time) cells. No weights are
downloaded: the networks start from torchvision's random initialisation.
"""

from __future__ import annotations

import torch
import torchvision
from torch import nn

INPUT_SHAPE = (1, 64, 32)  # channels, Doppler bins, time columns


def _adapt(net: torchvision.models.ResNet, in_channels: int, stem_stride: int) -> torchvision.models.ResNet:
    net.conv1 = nn.Conv2d(in_channels, net.conv1.out_channels, kernel_size=3, stride=stem_stride, padding=1, bias=False)
    nn.init.kaiming_normal_(net.conv1.weight, mode="fan_out", nonlinearity="relu")
    net.maxpool = nn.Identity()
    return net


def resnet18(num_classes: int, *, in_channels: int = 1, stem_stride: int = 1) -> torchvision.models.ResNet:
    """ResNet-18 (11 M parameters) for (B, in_channels, 64, 32) inputs; logits (B, num_classes)."""
    return _adapt(torchvision.models.resnet18(weights=None, num_classes=num_classes), in_channels, stem_stride)


def resnet50(num_classes: int, *, in_channels: int = 1, stem_stride: int = 1) -> torchvision.models.ResNet:
    """ResNet-50 (23.5 M parameters), the paper's classifier, for (B, in_channels, 64, 32) inputs."""
    return _adapt(torchvision.models.resnet50(weights=None, num_classes=num_classes), in_channels, stem_stride)


def replace_head(net: nn.Module, num_classes: int) -> nn.Module:
    """A new, freshly initialised final layer with ``num_classes`` outputs (fine-tuning on other classes)."""
    if not isinstance(getattr(net, "fc", None), nn.Linear):
        raise TypeError(f"{type(net).__name__} has no linear 'fc' head to replace")
    net.fc = nn.Linear(net.fc.in_features, num_classes)
    return net


def backbone_state(net: nn.Module) -> dict[str, torch.Tensor]:
    """The state dict without the classification head (what pre-training transfers)."""
    return {k: v for k, v in net.state_dict().items() if not k.startswith("fc.")}
