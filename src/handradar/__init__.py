"""handradar: FMCW-radar hand-gesture spectrogram synthesis from 3D hand skeletons.

Implements the hybrid method of Tang, Xu, Xu and Chen ("Advancing Radar Hand Gesture
Recognition: A Hybrid Spectrum Synthetic Framework Merging Simulation with Neural Networks").
"""

__version__ = "0.1.0"
