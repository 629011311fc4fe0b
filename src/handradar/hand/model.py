"""The hand model shared by the simulator and its features: retargeting and mesh resolution.

Configured by ``conf/hand/default.yaml``; the simulator (handradar.sim) and the bone features
(handradar.sim.features) take the same instance, so both see the same hand.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from handradar.hand.retarget import retarget, standard_lengths


@dataclass(frozen=True)
class HandModelConfig:
    """The hand model shared by the features and the simulator.

    retarget: rebuild the skeleton with standard bone lengths (handradar.hand.retarget).
    hand_scale: multiplies the standard lengths.
    sections, rings: cylinder mesh resolution (vertices per bone = sections * rings + 2).
    backend: visibility backend of handradar.hand.visibility (auto: the analytic one).
    visibility_stride: ray cast every n-th skeleton step (1 = all; 2 = 50 Hz at the 100 Hz rows,
        counts interpolated in between).
    """

    retarget: bool = True
    hand_scale: float = 1.0
    sections: int = 20
    rings: int = 21
    backend: str = "auto"
    visibility_stride: int = 2

    def joints(self, positions: np.ndarray) -> np.ndarray:
        """Joints (..., 21, 3) metres as the hand model sees them (retargeted or as given)."""
        if not self.retarget:
            return np.asarray(positions, dtype=np.float64)
        pos = torch.as_tensor(np.asarray(positions, dtype=np.float64))
        return retarget(pos, standard_lengths(self.hand_scale)).numpy()

    def key(self) -> dict:
        """Fields that change the features (the backends agree within one vertex: not part of the key)."""
        return {"retarget": self.retarget, "hand_scale": self.hand_scale, "sections": self.sections,
                "rings": self.rings, "visibility_stride": self.visibility_stride}
