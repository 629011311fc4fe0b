"""Console entry points (thin Hydra apps)."""
