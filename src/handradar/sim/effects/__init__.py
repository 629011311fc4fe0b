"""Effects: physics the paper's simulator leaves out, each a small nn.Module that can be fitted.

Names (configs, reports): ``occlusion``, ``palm``, ``forearm``, ``multipath``,
``antenna_pattern``, ``noise``, ``sync_offset``, ``tracking_jitter`` (docs/architecture.md, "Processing chain and simulator").
Select them with ``sim.effects=[occlusion,noise]`` and set parameters with
``sim.effect_params.noise.snr_db=15``; ``conf/sim/paper.yaml`` is the paper's model (no effects).

Contract of an effect (handradar.sim.effects.base.Effect):

- ``name`` (fixed string), ``stage`` ("skeleton" | "scatterers" | "signal": its one way into the
  signal), ``order`` (pipeline position; lower first), ``fit`` ("grad" or "grid").
- ``params``: {name_with_unit: Param(default, low, high, grid)}; the values live in scalar
  ``nn.Parameter``s of the same names, frozen (requires_grad False) unless a fitter unfreezes them;
  ``value(k)`` is the bounded value the physics uses.
- construction ``Cls(**values)``; ``values()`` -> dict; ``set_values(**values)`` (bounds checked);
  ``clamp_()`` projects into bounds after an optimiser step; ``Cls.grid(overrides=None)`` -> the
  documented grid (Cartesian product of the per-parameter grids, at most a dozen points; a
  parameter's values replaced by ``overrides[param]``); ``Cls.defaults()``.
- hooks (one overridden per effect): ``apply_skeleton(positions, mask, times)``,
  ``apply_scatterers(scatterers, ctx)``, ``apply_signal(signal, radar, chain, power_scale)``.

| name | stage | enters as | parameters (default; bounds) |
|---|---|---|---|
| tracking_jitter | skeleton | Gaussian smoothing in time of the tracked joints | sigma_s (0.01; 0-0.1) |
| sync_offset | skeleton | skeleton steps moved on the radar clock: pose at t is shown at t + offset | offset_s (0; +-0.25) |
| palm | scatterers | + one disc reflector per hand at the palm centre, normal from the palm plane | radius_m (0.02; 0.005-0.06) |
| forearm | scatterers | + a cylinder from the wrist to the source's elbow and one on to its shoulder (the motion library's arm), else to an elbow fixed over the window; n_segments points each | length_m (0.15; 0.02-0.3), radius_m (0.03; 0.015-0.05) |
| occlusion | scatterers | bone amplitude x sqrt(t + (1 - t) f), f = visible/facing vertices | transmission (0; 0-1) |
| multipath | scatterers | + bone-to-bone double bounces, hand -> table (z = -height) -> hand and hand -> hand, the n_paths strongest of each | height_m (0.01; 0-0.5), reflection_coeff (0.5; 0-1), scale (0.1; 0-4) |
| antenna_pattern | scatterers | amplitude x sqrt(G(theta_tx) G(theta_rx)), G = cos^q (0 behind the board) | q (4; 0-12) |
| noise | signal | + complex white noise at the ADC, through the same windowed range FFT, at an SNR | snr_db (20; -20-60) |

How the gap diagnosis uses this API (calibration split only):

    from handradar.sim.effects import REGISTRY
    sim = Simulator(radar, chain, effects=baseline + [name])
    eff = sim.effect(name)
    for p in REGISTRY[name].grid():            # coarse: the documented grid
        eff.set_values(**p); score(sim)        # mean SSIM against the measured spectrograms
    if eff.fit == "grad":                      # fine: gradient from the best grid point
        eff.requires_grad_(True); opt = torch.optim.Adam(eff.parameters(), lr=...)
        ... loss.backward(); opt.step(); eff.clamp_()
    report eff.values()

Caching: skeleton- and scatterer-stage effects change the per-slot profiles, so a profile cache
(handradar.sim.cache) is keyed by the effects and their values; signal-stage effects (noise) run
after the weighted sum and can reuse cached profiles (Simulator.render).
Stochastic effects (noise) draw from their own generator (``seed``); ``reset_rng()`` replays
the same draws, so that grid points are compared on the same noise.
"""

from handradar.sim.effects.antenna_pattern import AntennaPattern
from handradar.sim.effects.base import (
           REGISTRY,
           STAGES,
           Effect,
           Param,
           SimContext,
           build_effects,
)
from handradar.sim.effects.forearm import Forearm
from handradar.sim.effects.multipath import Multipath
from handradar.sim.effects.noise import Noise
from handradar.sim.effects.occlusion import Occlusion
from handradar.sim.effects.palm import Palm
from handradar.sim.effects.sync_offset import SyncOffset
from handradar.sim.effects.tracking_jitter import TrackingJitter

__all__ = ["REGISTRY", "STAGES", "AntennaPattern", "Effect", "Forearm", "Multipath", "Noise",
           "Occlusion", "Palm", "Param", "SimContext", "SyncOffset", "TrackingJitter", "build_effects"]
