"""Experiment presets (experiments/experiment/*.yaml, on Hydra's search path) and table builders."""
