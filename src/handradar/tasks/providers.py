"""Integration points for synthetic data: the provider contracts and their default targets.

Synthetic spectrograms enter train.py jobs through two Hydra-instantiated callables
(``synth.provider`` and ``synth.external_provider``, both ``_partial_: true``):

``provider(real_path: Path, rows: np.ndarray, mode: Literal["model", "enhanced"], *, fit_rows: np.ndarray,
seed: int, cache_dir: Path) -> Path``
    One synthetic spectrogram per requested row of the real dataset ``real_path``, simulated from
    that row's skeleton, written as a ``handradar.dataset/1`` file whose rows follow ``rows`` (same
    labels and meta order). ``mode="model"``: the modelling-only simulator; ``mode="enhanced"``:
    simulator + RadarWeightNet, which the provider may fit on the radar data of ``fit_rows`` only
    (the few-shot real rows; never the test rows). ``cache_dir`` is the provider's to cache in.

``external_provider(source_cfg, *, seed: int, cache_dir: Path) -> Path``
    Spectrograms synthesised from an external skeleton dataset (``source_cfg`` is the
    ``data.sfinge3d`` or ``data.dhg`` node: ``name``, ``root``, ...), as a ``handradar.dataset/1``
    file with the source's own labels and the class names in the attribute ``classes``.

The defaults below import the simulator lazily and say clearly when it is not part of the build.
:func:`load_synthetic` checks what a provider returned.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np

from handradar.data.provision import ArrayDataset, import_callable, load_arrays
from handradar.errors import FormatError, HandradarError

SIM_PROVIDER = "handradar.sim.provider.synthesize_rows"
SIM_EXTERNAL_PROVIDER = "handradar.sim.provider.synthesize_external"


def _import(name: str, what: str):
    try:
        return import_callable(name)
    except ImportError as exc:
        raise HandradarError(f"{what} '{name}' is not available in this build ({exc}); set synth.provider / "
                             "synth.external_provider to a callable with the contract of handradar.tasks.providers, "
                             "or drop the synthetic variants (variants=[radar_only,cgan])") from None


def simulator_provider(real_path: Path, rows: np.ndarray, mode: Literal["model", "enhanced"], *, fit_rows: np.ndarray,
                       seed: int, cache_dir: Path) -> Path:
    """Default ``synth.provider``: the skeleton simulator (+ RadarWeightNet for mode="enhanced")."""
    fn = _import(SIM_PROVIDER, "the simulator provider")
    return fn(real_path, rows, mode, fit_rows=fit_rows, seed=seed, cache_dir=cache_dir)


def simulator_external_provider(source_cfg: Any, *, seed: int, cache_dir: Path) -> Path:
    """Default ``synth.external_provider``: external skeletons through the simulator."""
    fn = _import(SIM_EXTERNAL_PROVIDER, "the external-skeleton provider")
    return fn(source_cfg, seed=seed, cache_dir=cache_dir)


def load_synthetic(path: str | Path, expected_labels: np.ndarray, shape: tuple[int, int] = (64, 32)) -> ArrayDataset:
    """A provider's output, checked against the rows it was asked for (count, labels in order, shape)."""
    data = load_arrays(path)
    expected_labels = np.asarray(expected_labels)
    if len(data) != len(expected_labels):
        raise FormatError(path, f"synthetic dataset has {len(data)} rows, the provider was asked for {len(expected_labels)}")
    if not np.array_equal(data.y, expected_labels):
        bad = int(np.flatnonzero(data.y != expected_labels)[0])
        raise FormatError(path, f"synthetic row {bad} has label {data.y[bad]}, the requested row's label is "
                                f"{expected_labels[bad]} (rows must follow the requested order)")
    if data.x.shape[1:] != tuple(shape) or not np.isfinite(data.x).all() or data.x.min(initial=0) < 0 or data.x.max(initial=0) > 1:
        raise FormatError(path, f"synthetic spectrograms must be (N, {shape[0]}, {shape[1]}) in [0, 1], found {data.x.shape} "
                                f"in [{data.x.min(initial=0):.3g}, {data.x.max(initial=0):.3g}]")
    return data
