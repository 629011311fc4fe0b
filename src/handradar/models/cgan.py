"""Conditional GAN (Mirza and Osindero, 2014) for class-conditional 64 x 32 spectrograms in [0, 1].

As in the original, both networks are multilayer perceptrons and the class enters as a one-hot
vector concatenated to the generator's noise and to the discriminator's (flattened) input. The
generator ends in a sigmoid, so samples lie in [0, 1] like the measured spectrograms. LeakyReLU,
batch normalisation in the generator and dropout in the discriminator replace the original
maxout units (the usual modern stabilisation; the conditioning scheme is unchanged).
"""

from __future__ import annotations

from collections.abc import Sequence
from math import prod

import torch
from torch import nn
from torch.nn import functional as F


def _mlp(sizes: Sequence[int], *, batch_norm: bool, dropout: float) -> list[nn.Module]:
    layers: list[nn.Module] = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        layers.append(nn.Linear(a, b))
        if batch_norm:
            layers.append(nn.BatchNorm1d(b))
        layers.append(nn.LeakyReLU(0.2))
        if dropout:
            layers.append(nn.Dropout(dropout))
    return layers


class Generator(nn.Module):
    """(noise (B, latent_dim), labels (B,)) -> spectrograms (B, 1, 64, 32) in [0, 1].

    As in Mirza and Osindero, noise and one-hot label first pass through separate hidden layers
    (``hidden[0]`` units each), whose outputs are concatenated and mapped by the joint layers.
    """

    def __init__(self, num_classes: int, *, latent_dim: int = 64, hidden: Sequence[int] = (256, 512, 1024),
                 shape: Sequence[int] = (1, 64, 32)) -> None:
        super().__init__()
        self.num_classes, self.latent_dim, self.shape = num_classes, latent_dim, tuple(shape)
        self.z_in = nn.Sequential(*_mlp([latent_dim, hidden[0]], batch_norm=True, dropout=0.0))
        self.y_in = nn.Sequential(*_mlp([num_classes, hidden[0]], batch_norm=False, dropout=0.0))
        self.body = nn.Sequential(*_mlp([2 * hidden[0], *hidden[1:]], batch_norm=True, dropout=0.0),
                                  nn.Linear(hidden[-1], prod(self.shape)))

    def forward(self, z: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        h = torch.cat([self.z_in(z), self.y_in(F.one_hot(labels, self.num_classes).to(z.dtype))], dim=1)
        return torch.sigmoid(self.body(h)).view(-1, *self.shape)

    @torch.no_grad()
    def sample(self, labels: torch.Tensor, *, seed: int = 0) -> torch.Tensor:
        """One sample per label, reproducible for a seed (the generator is put in eval mode)."""
        was_training = self.training
        self.eval()
        g = torch.Generator(device="cpu").manual_seed(int(seed))
        z = torch.randn(len(labels), self.latent_dim, generator=g).to(next(self.parameters()).device)
        out = self(z, labels.to(z.device))
        self.train(was_training)
        return out


class Discriminator(nn.Module):
    """(spectrograms (B, 1, 64, 32), labels (B,)) -> real/fake logits (B,).

    Spectrogram and one-hot label pass through separate hidden layers (``hidden[0]`` and
    ``label_units`` units) before the joint layers, so the label is not drowned among 2048 pixels.
    """

    def __init__(self, num_classes: int, *, hidden: Sequence[int] = (512, 256), label_units: int = 64,
                 dropout: float = 0.3, shape: Sequence[int] = (1, 64, 32)) -> None:
        super().__init__()
        self.num_classes = num_classes
        self.x_in = nn.Sequential(*_mlp([prod(shape), hidden[0]], batch_norm=False, dropout=dropout))
        self.y_in = nn.Sequential(*_mlp([num_classes, label_units], batch_norm=False, dropout=0.0))
        self.body = nn.Sequential(*_mlp([hidden[0] + label_units, *hidden[1:]], batch_norm=False, dropout=dropout),
                                  nn.Linear(hidden[-1] if len(hidden) > 1 else hidden[0] + label_units, 1))

    def forward(self, x: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        h = torch.cat([self.x_in(x.flatten(1)), self.y_in(F.one_hot(labels, self.num_classes).to(x.dtype))], dim=1)
        return self.body(h).squeeze(1)
