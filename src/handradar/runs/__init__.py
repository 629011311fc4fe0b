"""Run infrastructure shared by every entry point: MLflow runs, Hydra job helpers, CLI errors.

A bottom layer: it imports nothing from handradar but :mod:`handradar.errors` and
:mod:`handradar.atomic`, so every job (training, synthesis, diagnosis) can use it.
"""
