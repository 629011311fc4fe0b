"""Effect-model changes made for the gap diagnosis (listed in docs/gap_report.md)."""

from __future__ import annotations

import numpy as np
import torch

from handradar.sim.scatterers import N_SLOTS
from handradar.sim.simulator import Simulator
from tests.gap.conftest import rows


def test_forearm_pivots_about_an_elbow_fixed_over_the_window(radar, short_chain):
    rs, _, _ = rows(radar, short_chain, 1, seed=2)
    sk = rs.skeletons.copy()
    t = rs.times
    sk[0, :, 0] += np.stack([0.2 * t, 0 * t, 0 * t], -1)[:, None, :]  # the hand slides 0.2 m/s along x
    sim = Simulator(radar, short_chain, effects=["forearm"], effect_params={"forearm": {"length_m": 0.2}})
    with torch.no_grad():
        ctx = sim.context(torch.as_tensor(sk), torch.as_tensor(rs.masks), times=torch.as_tensor(t))
        scat = sim.scatterers(ctx)
    fore = scat.tx[0, :, N_SLOTS:N_SLOTS + 4]  # the tracked hand's four segments, wrist first
    speed = (fore[-1] - fore[0]).norm(dim=-1) / float(t[-1] - t[0])
    wrist_speed = float((ctx.joints[0, -1, 0, 0] - ctx.joints[0, 0, 0, 0]).norm()) / float(t[-1] - t[0])
    # segment k sits at (k + 0.5) / 4 of the way to the still elbow: it moves at (1 - (k + 0.5) / 4) of the wrist speed
    expected = wrist_speed * (1 - (torch.arange(4) + 0.5) / 4)
    assert torch.allclose(speed, expected.to(speed.dtype), rtol=0.05)
    wrist = ctx.joints[0, :, 0, 0]
    reach = (fore[:, -1] - wrist).norm(dim=-1)  # the far segment lies 7/8 of the forearm from the wrist
    assert 0.1 < float(reach.min()) and float(reach.max()) < 0.2
