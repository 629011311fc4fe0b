"""Hybrid synthesis: fitting RadarWeightNet on measured data, synthetic-data providers, the synth_fit job."""
