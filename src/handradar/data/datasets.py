"""Where a job's real radar data come from, and loading a dataset file into memory.

A job's ``data.dataset`` is a Hydra-instantiated locator with ``path() -> Path``: the HDF5 dataset
file (``handradar.dataset/1``) it stands for, materialised on first use and cached:

- :class:`DatasetFile` (``data=hdf5 data.path=FILE.h5``): an existing file;
- :class:`RecordingsFolder` (``data=recordings data.root=DIR``): recordings ingested with
  :func:`handradar.data.ingest.ingest` into ``<cache_dir>/recordings-<hash>.h5``, the hash covering
  the folder, every recording file's name, size and modification time, and the chain settings;
- :class:`ReferenceWorld` (``data=world``, the default): the reference world, built by the function
  named in ``builder`` (``handradar.world.build_world_dataset(world_cfg, radar, chain, cache_dir)``).
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from handradar.atomic import file_lock
from handradar.data.hdf5 import read_attrs, read_meta_group, validate
from handradar.data.ingest import ingest
from handradar.data.recording import FILES, find_recordings
from handradar.errors import FormatError, HandradarError
from handradar.provenance import config_hash
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig
from handradar.runs.cli import bool_option

log = logging.getLogger(__name__)


def import_callable(dotted: str):
    """``package.module.name`` -> the object; ImportError (with the reason) when it is missing."""
    import importlib

    module, _, name = dotted.rpartition(".")
    try:
        obj = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise ImportError(f"{type(exc).__name__}: {exc}") from None
    if not callable(obj):
        raise ImportError(f"{dotted} is not callable")
    return obj


class DatasetFile:
    """An existing dataset file."""

    def __init__(self, path: str | Path) -> None:
        self._path = Path(path).expanduser()

    def path(self) -> Path:
        if not self._path.is_file():
            raise FormatError(self._path, "dataset file not found (data.path)")
        validate(self._path)
        return self._path.resolve()


class RecordingsFolder:
    """A folder of ``handradar.recording/1`` recordings, ingested once into a cached dataset file."""

    def __init__(self, root: str | Path, chain: ChainConfig, cache_dir: str | Path, *,
                 skeleton_rate_hz: float = 100.0, strict: bool = False, allow_truncated: bool = False,
                 iq_swap: bool = False, doppler_flip: bool = False) -> None:
        self.root = Path(root).expanduser()
        self.chain, self.cache_dir = chain, Path(cache_dir)
        self.skeleton_rate_hz, self.strict, self.allow_truncated = skeleton_rate_hz, strict, allow_truncated
        self.iq_swap, self.doppler_flip = bool_option("iq_swap", iq_swap), bool_option("doppler_flip", doppler_flip)

    def cache_key(self) -> str:
        listing = []
        for folder in find_recordings(self.root):
            for name in FILES:
                f = folder / name
                st = f.stat() if f.exists() else None
                listing.append([str(f.relative_to(self.root)), st.st_size if st else -1, st.st_mtime_ns if st else -1])
        return config_hash(str(self.root.resolve()), listing, self.chain, self.skeleton_rate_hz, self.allow_truncated,
                           self.iq_swap, self.doppler_flip, "recordings")

    def path(self) -> Path:
        if not self.root.is_dir():
            what = "is a file, not a folder" if self.root.exists() else "recordings folder not found"
            raise FormatError(self.root, f"{what} (data.root: the folder that holds the recording folders)")
        out = self.cache_dir / f"recordings-{self.cache_key()}.h5"
        # one ingest per content: a second job of a sweep waits, then reads the same file (and data hash)
        with file_lock(out.with_name(out.name + ".lock")):
            if not out.is_file():
                summary = ingest(self.root, out, self.chain, skeleton_rate_hz=self.skeleton_rate_hz, strict=self.strict,
                                 allow_truncated=self.allow_truncated, iq_swap=self.iq_swap,
                                 doppler_flip=self.doppler_flip, progress=False)
                log.info("%s", summary.report())
                if summary.convention.fix():
                    log.warning("%s", summary.convention.message())
        return out.resolve()


class ReferenceWorld:
    """The reference world (docs/architecture.md, "Reference world"), built and cached by ``builder``.

    builder: dotted name of ``build_world_dataset(world_cfg, radar, chain, cache_dir) -> Path``;
    it is imported only when the data are needed, so configs compose without it.
    """

    def __init__(self, builder: str, radar: RadarConfig, chain: ChainConfig, cache_dir: str | Path,
                 world: Any = None) -> None:
        self.builder, self.radar, self.chain, self.cache_dir, self.world = builder, radar, chain, Path(cache_dir), world

    def path(self) -> Path:
        try:
            build = import_callable(self.builder)
        except ImportError as exc:
            raise HandradarError(f"the reference-world generator '{self.builder}' is not available ({exc}); "
                                 "use data=hdf5 data.path=FILE.h5 or data=recordings data.root=DIR") from None
        out = Path(build(self.world, self.radar, self.chain, self.cache_dir))
        validate(out)
        return out.resolve()


def file_hash(path: str | Path, chunk: int = 1 << 20) -> str:
    """SHA-256 (16 hex digits) of a file's bytes: the data hash a run logs."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()[:16]


@dataclass
class ArrayDataset:
    """A dataset file in memory: spectrograms (N, 64, 32) float32, labels (N,), meta, class names."""

    path: Path
    x: np.ndarray
    y: np.ndarray
    meta: dict[str, np.ndarray]
    classes: list[str]

    def __len__(self) -> int:
        return len(self.y)


def load_arrays(path: str | Path, rows: np.ndarray | None = None) -> ArrayDataset:
    """Spectrograms, labels and meta of ``rows`` (default: all) of a validated dataset file."""
    path = Path(path)
    attrs = read_attrs(path)
    with h5py.File(path, "r") as h5:
        x = h5["spectrograms"][()]
        y = h5["labels"][()].astype(np.int64)
    meta = read_meta_group(path)
    if rows is not None:
        rows = np.asarray(rows, dtype=np.int64)
        x, y, meta = x[rows], y[rows], {k: v[rows] for k, v in meta.items()}
    n_classes = len(attrs["classes"]) if attrs["classes"] else int(y.max(initial=-1)) + 1
    if len(y) and (y.min() < 0 or y.max() >= n_classes):
        raise FormatError(path, f"labels must lie in [0, {n_classes}) for the {n_classes} classes, found {y.min()}..{y.max()}")
    classes = list(attrs["classes"]) if attrs["classes"] else [str(i) for i in range(n_classes)]
    return ArrayDataset(path, x.astype(np.float32, copy=False), y, meta, classes)
