"""RadarWeightNet (Tang et al.): an LSTM over time plus three fully connected layers that turns
per-bone motion features into one positive weight per reflection point and time step.

Input: the features of handradar.sim.features (B, T, 2, 19, 5) for the 19 bones x 2 hands,
normalised by fixed physical scales (:func:`normalise_features`) and zeroed for untracked hands,
plus the two hand-mask flags: 38 x 5 + 2 = 192 values per step. Output: (B, T, 38) weights,
softplus-positive, slot = hand * 19 + bone (the simulator's slots), initialised near 1 (the
paper's plain model). Weights live at the skeleton steps; :func:`upsample_weights` takes them to
the chirp times, linearly in time, and the simulator's weighted sum goes through the shared chain.

Public API:

    normalise_features(features (..., 2, 19, 5), mask (..., 2) | None) -> (..., 2, 19, 5) float32
    RadarWeightNet(hidden=128, fc=(128, 64), num_layers=1, bidirectional=False, dropout=0.0)
        .forward(features (B, T, 2, 19, 5), mask (B, T, 2) | None) -> weights (B, T, 38) > 0
    upsample_weights(weights (B, T, 38), times (T,), chirp_times (F, L, C)) -> (B, 38, F, L, C)
    enhanced_spectrogram(net, sim, slot_profiles (B, 39, ...), features, mask, times=None)
        -> (B, doppler, columns): net -> weights -> sim.combine -> sim.spectrogram
"""

from __future__ import annotations

import math

import torch
from torch import nn

from handradar.hand.skeleton import N_BONES
from handradar.sim.features import FEATURE_NAMES, N_FEATURES
from handradar.sim.interp import upsample_to_chirps

N_SLOTS = 2 * N_BONES

# Fixed normalisation (x - offset) / scale per feature, FEATURE_NAMES order; the RCS enters as log10.
# Vertices: 0..~250 of 422 face the radar; log10 RCS of finger bones: about -7..-1; hands at
# 0.1-0.6 m; gestures reach ~1 m/s and ~30 m/s^2.
FEATURE_OFFSET = (0.0, -4.0, 0.35, 0.0, 0.0)
FEATURE_SCALE = (250.0, 2.0, 0.15, 0.5, 20.0)
assert len(FEATURE_OFFSET) == len(FEATURE_SCALE) == len(FEATURE_NAMES)


def normalise_features(features: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Per-bone features (..., 2, 19, 5) -> normalised float32 (zeros where a hand is untracked)."""
    x = torch.as_tensor(features, dtype=torch.float32)
    if x.shape[-3:] != (2, N_BONES, N_FEATURES):
        raise ValueError(f"features must end in (2, {N_BONES}, {N_FEATURES}), found {tuple(x.shape)}")
    rcs = torch.log10(x[..., 1].clamp_min(1e-12))
    x = torch.cat([x[..., :1], rcs[..., None], x[..., 2:]], dim=-1)
    off = x.new_tensor(FEATURE_OFFSET)
    scale = x.new_tensor(FEATURE_SCALE)
    x = (x - off) / scale
    if mask is not None:
        x = x * torch.as_tensor(mask, device=x.device).to(x.dtype)[..., None, None]
    return x


class RadarWeightNet(nn.Module):
    """LSTM over the skeleton steps + 3 fully connected layers -> one weight per bone slot and step."""

    def __init__(self, hidden: int = 128, fc: tuple[int, int] = (128, 64), num_layers: int = 1,
                 bidirectional: bool = False, dropout: float = 0.0) -> None:
        super().__init__()
        self.n_in = N_SLOTS * N_FEATURES + 2
        self.lstm = nn.LSTM(self.n_in, hidden, num_layers=num_layers, batch_first=True,
                            bidirectional=bidirectional, dropout=dropout if num_layers > 1 else 0.0)
        width = hidden * (2 if bidirectional else 1)
        self.fc = nn.Sequential(nn.Linear(width, fc[0]), nn.ReLU(), nn.Linear(fc[0], fc[1]), nn.ReLU(),
                                nn.Linear(fc[1], N_SLOTS))
        last = self.fc[-1]
        nn.init.normal_(last.weight, std=1e-3)
        nn.init.constant_(last.bias, math.log(math.e - 1.0))  # softplus(bias) = 1: start at the plain model

    def forward(self, features: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        b, t = features.shape[:2]
        if mask is None:
            mask = features.new_ones(b, t, 2) if features.is_floating_point() else torch.ones(b, t, 2)
        mask = torch.as_tensor(mask, device=features.device).to(torch.float32)
        x = normalise_features(features, mask).reshape(b, t, -1)
        h, _ = self.lstm(torch.cat([x, mask], dim=-1))
        return nn.functional.softplus(self.fc(h))


def upsample_weights(weights: torch.Tensor, times: torch.Tensor, chirp_times: torch.Tensor) -> torch.Tensor:
    """Weights (B, T, 38) at the skeleton times (T,) s -> (B, 38, F, L, C) at the chirp times, linear in time."""
    return upsample_to_chirps(weights, torch.as_tensor(times, dtype=torch.float64),
                              torch.as_tensor(chirp_times, dtype=torch.float64))


def enhanced_spectrogram(net: RadarWeightNet, sim, slot_profiles: torch.Tensor, features: torch.Tensor,
                         mask: torch.Tensor, times: torch.Tensor | None = None) -> torch.Tensor:
    """Modelling + RadarWeightNet: weights from the features, weighted slot sum, shared chain."""
    weights = net(features, mask)
    return sim.render(slot_profiles, weights, times=times)
