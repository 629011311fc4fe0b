"""The differentiable per-reflection-point simulator of Tang et al. and its effect modules.

Modules (each documents its public API, shapes and units):

- ``factory``    SimFactory: the one place simulators are built (the ``sim`` config, overrides at
                 construction).
- ``simulator``  Simulator: skeleton windows (B, T, 2, 21, 3) -> spectrograms (B, 64, 32) through
                 the shared chain; per-slot profiles for caching; weighted sum; effects; key().
- ``features``   per-bone motion features (RadarWeightNet's input) at the simulator's RCS exponent, cached.
- ``profiles``   scatterer_profiles (closed-form windowed range FFT per reflection point at the true
                 chirp times), combine_slots (weighted sum), window_chirp_times.
- ``scatterers`` Scatterers (reflection points at the skeleton steps), bone_scatterers (one per bone
                 at its midpoint), radar_amplitude (radar equation).
- ``rcs``        cylinder_rcs_m2 (Tang et al., broadside cap), disc_rcs_m2, cos_angle.
- ``interp``     linear interpolation in time (skeleton steps -> chirp times).
- ``effects``    the eight effects (occlusion, palm, forearm, multipath, antenna_pattern, noise,
                 sync_offset, tracking_jitter), their registry and the fitting API.
- ``cache``      float16 cache of the per-slot profiles (HDF5, keyed by Simulator.key(), atomic).

Typical use (RadarWeightNet in handradar.models.radar_weight_net, features in handradar.sim.features):

    sim = SimFactory.from_config(cfg.sim, radar, chain)()       # or Simulator(radar, chain, effects=["noise"])
    spec = sim(skeleton, mask)                                 # the modelling-only simulator
    prof = sim.slot_profiles(skeleton, mask)                   # network-independent: cache it
    spec = sim.render(prof, net(features, mask))               # + RadarWeightNet

Import the submodules directly (this package module imports nothing, so importing one submodule
does not load the rest).
"""
