"""sync_offset: the Leap and radar clocks disagree by a constant offset.

With offset_s = d, the pose the skeleton shows at step time t happened at radar time t - d
(a positive d means the skeleton lags the radar). The skeleton step times move by -d before the
interpolation to the chirp times; beyond the window's ends the end poses are held. The weights of
RadarWeightNet move with their steps (Simulator.step_times). Differentiable in offset_s.
"""

from __future__ import annotations

from handradar.sim.effects.base import Effect, Param, register


@register
class SyncOffset(Effect):
    name = "sync_offset"
    stage = "skeleton"
    order = 20
    params = {"offset_s": Param(0.0, -0.25, 0.25, (-0.1, -0.05, -0.02, 0.02, 0.05, 0.1),
                                "skeleton clock minus radar clock, seconds")}

    def apply_skeleton(self, positions, mask, times):
        return positions, mask, times - self.value("offset_s").to(times.dtype)
