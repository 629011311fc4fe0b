"""The HDF5 dataset ``handradar.dataset/1`` (docs/architecture.md, "HDF5 dataset"): writer, reader, validator.

Datasets: ``spectrograms`` (N, 64, 32) float32 in [0, 1]; ``labels`` (N,) int64; ``skeletons``
(N, T, 2, 21, 3) float32 radar-frame metres resampled to a common T over the spectrogram's time
window; group ``meta`` with one (N,) array per label field. Extra datasets (not part of the
contract, read by handradar itself): ``hand_mask`` (N, T, 2) bool, ``window_start_s`` (N,); group
``quality`` (written by ingest) with one (N,) array per quality field of handradar.data.quality
(verdict, coverage, longest_gap_s, duplicate_of, ...), so that jobs can filter or weight rows; group
``convention`` (written by ingest) with ``range_mirror_db`` (N,), the hand's energy at the mirrored
range bins over that at its own (dB, NaN where not measured; handradar.data.convention), and the
file attributes ``iq_swap`` and ``doppler_flip``, the ingest options the rows were read with, so
that a check of the rows alone can tell I/Q swapped from Doppler-mirrored.
File attributes: ``format``, ``config_hash``, ``code_version``, ``classes`` (JSON list),
``radar_cfg`` (the radar.cfg text), ``chain`` (JSON), ``skeleton_rate_hz``.

Files are written through :func:`handradar.atomic.atomic_path`: an interrupted write leaves
nothing at the target path.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator, Sequence
from dataclasses import asdict
from pathlib import Path

import h5py
import numpy as np

from handradar.atomic import atomic_path
from handradar.errors import FormatError, printable
from handradar.provenance import code_version
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig

FORMAT = "handradar.dataset/1"
READ_OPTIONS = ("iq_swap", "doppler_flip")  # ingest's reading options, file attributes of the rows they read
STR = h5py.string_dtype("utf-8")


class DatasetWriter:
    """Append examples row by row into resizable datasets of a temporary file.

    Use through :func:`open_writer`, which moves the file into place only when the block ends
    without an exception (Ctrl-C included). Rows are buffered and written ``BLOCK`` at a time:
    h5py's per-call overhead (a resize and a write per dataset) cost more than the data of a row.
    """

    BLOCK = 64  # rows per write; the spectrograms' chunk
    COLUMNS = ("spectrograms", "labels", "skeletons", "hand_mask", "window_start_s")
    GROUPS = ("quality", "convention")  # optional groups of (N,) columns, each written where a row gives it

    def __init__(self, h5: h5py.File, n_steps: int, spec_shape: tuple[int, int]) -> None:
        self.h5 = h5
        self.n = 0
        self.meta: dict[str, list] = {}
        chunk = 64
        h5.create_dataset("spectrograms", (0, *spec_shape), maxshape=(None, *spec_shape), dtype="f4",
                          chunks=(chunk, *spec_shape))
        h5.create_dataset("labels", (0,), maxshape=(None,), dtype="i8", chunks=(1024,))
        h5.create_dataset("skeletons", (0, n_steps, 2, 21, 3), maxshape=(None, n_steps, 2, 21, 3), dtype="f4",
                          chunks=(8, n_steps, 2, 21, 3))
        h5.create_dataset("hand_mask", (0, n_steps, 2), maxshape=(None, n_steps, 2), dtype=bool,
                          chunks=(chunk, n_steps, 2))
        h5.create_dataset("window_start_s", (0,), maxshape=(None,), dtype="f8", chunks=(1024,))
        self._datasets = {name: h5[name] for name in self.COLUMNS}
        self._row_shapes = {name: ds.shape[1:] for name, ds in self._datasets.items()}
        self._pending: dict[str, list[np.ndarray]] = {name: [] for name in self.COLUMNS}
        self.groups: dict[str, dict[str, list]] = {g: {} for g in self.GROUPS}

    def append(self, spectrogram: np.ndarray, label: int, skeleton: np.ndarray, hand_mask: np.ndarray,
               window_start_s: float, meta: dict[str, object], *, quality: dict[str, object] | None = None,
               convention: dict[str, object] | None = None) -> None:
        if self.n and set(meta) != set(self.meta):
            raise ValueError(f"meta fields {sorted(meta)} differ from the first row's {sorted(self.meta)}")
        given = {"quality": quality or {}, "convention": convention or {}}
        for g, fields in given.items():
            if self.n and set(fields) != set(self.groups[g]):
                raise ValueError(f"{g} fields {sorted(fields)} differ from the first row's {sorted(self.groups[g])}")
        rows = []
        for name, value in zip(self.COLUMNS, (spectrogram, label, skeleton, hand_mask, window_start_s)):
            row = np.array(value)  # a copy: the caller may reuse its buffer before the block is written
            if row.shape != self._row_shapes[name]:  # fail here, not at the block's write
                row = np.array(np.broadcast_to(row, self._row_shapes[name]))
            rows.append(row)
        for name, row in zip(self.COLUMNS, rows):
            self._pending[name].append(row)
        for k, v in meta.items():
            self.meta.setdefault(k, []).append(v)
        for g, fields in given.items():
            for k, v in fields.items():
                self.groups[g].setdefault(k, []).append(v)
        self.n += 1
        if len(self._pending["labels"]) >= self.BLOCK:
            self._flush()

    def _flush(self) -> None:
        """Write the buffered rows (h5py converts them to each dataset's dtype, as row by row)."""
        k = len(self._pending["labels"])
        if not k:
            return
        for name, ds in self._datasets.items():
            lo = ds.shape[0]
            ds.resize(lo + k, axis=0)
            ds[lo:lo + k] = np.stack(self._pending[name])
            self._pending[name].clear()

    def finish(self) -> None:
        self._flush()
        _write_columns(self.h5.create_group("meta"), self.meta)
        for g, columns in self.groups.items():
            if columns:
                _write_columns(self.h5.create_group(g), columns)


def _write_columns(g: h5py.Group, columns: dict[str, list]) -> None:
    """One (N,) dataset per column: bool, int64, float64 or UTF-8 text, whichever holds every value."""
    for k, values in columns.items():
        if all(isinstance(v, (bool, np.bool_)) for v in values):
            g.create_dataset(k, data=np.asarray(values, dtype=bool))
        elif all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in values):
            g.create_dataset(k, data=np.asarray(values, dtype=np.int64))
        elif all(isinstance(v, (int, float, np.number)) and not isinstance(v, bool) for v in values):
            g.create_dataset(k, data=np.asarray(values, dtype=np.float64))
        else:
            # printable: a name that is not UTF-8 (file names may hold any bytes) must not fail the finished file
            g.create_dataset(k, data=np.asarray([printable(str(v)) for v in values], dtype=object), dtype=STR)


@contextlib.contextmanager
def open_writer(path: str | Path, *, classes: Sequence[str], radar: RadarConfig | None, chain: ChainConfig,
                skeleton_rate_hz: float, n_steps: int, config_hash: str,
                extra_attrs: dict | None = None) -> Iterator[DatasetWriter]:
    """Write a dataset atomically: nothing appears at ``path`` unless the block completes.

    ``radar`` None: no ``radar_cfg`` attribute (measured spectrograms whose radar is not fully known)."""
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as h5:
            h5.attrs["format"] = FORMAT
            h5.attrs["config_hash"] = config_hash
            h5.attrs["code_version"] = code_version()
            h5.attrs["classes"] = json.dumps(list(classes))
            if radar is not None:
                h5.attrs["radar_cfg"] = radar.to_cfg()
            h5.attrs["chain"] = json.dumps(asdict(chain))
            h5.attrs["skeleton_rate_hz"] = float(skeleton_rate_hz)
            for k, v in (extra_attrs or {}).items():
                h5.attrs[k] = v
            writer = DatasetWriter(h5, n_steps, (chain.n_doppler, chain.n_columns))
            yield writer
            writer.finish()


def read_rows(ds: h5py.Dataset, rows: np.ndarray) -> np.ndarray:
    """``ds[rows]`` for increasing ``rows``, read as contiguous runs: h5py's point selection
    (``ds[list]``) is ~15x slower on row-chunked compressed data."""
    if not len(rows):
        return np.empty((0, *ds.shape[1:]), ds.dtype)
    breaks = np.flatnonzero(np.diff(rows) != 1) + 1
    return np.concatenate([ds[int(run[0]):int(run[-1]) + 1] for run in np.split(rows, breaks)])


def read_attrs(path: str | Path) -> dict[str, object]:
    """Validated file attributes, with ``classes``/``chain`` decoded and ``radar`` parsed."""
    path = Path(path)
    try:
        h5 = h5py.File(path, "r")
    except OSError as exc:
        raise FormatError(path, f"not a readable HDF5 file ({exc})") from None
    with h5:
        attrs = dict(h5.attrs)
        if attrs.get("format") != FORMAT:
            raise FormatError(path, f"attribute 'format' must be {FORMAT!r}, found {attrs.get('format')!r}")
        missing = [k for k in ("spectrograms", "labels", "skeletons", "meta") if k not in h5]
        if missing:
            raise FormatError(path, f"missing dataset(s) {missing}")
        attrs["n"] = int(h5["labels"].shape[0])
    try:
        attrs["classes"] = json.loads(attrs["classes"]) if "classes" in attrs else None
        if "chain" in attrs:
            c = json.loads(attrs["chain"])
            c["gate_m"] = tuple(c["gate_m"])
            attrs["chain"] = ChainConfig(**c)
    except (ValueError, TypeError, KeyError) as exc:
        raise FormatError(path, f"attribute 'classes' or 'chain' is not valid ({exc})") from None
    if attrs["classes"] is not None and (not isinstance(attrs["classes"], list)
                                         or not all(isinstance(c, str) for c in attrs["classes"])):
        raise FormatError(path, f"attribute 'classes' must be a JSON list of names, found {attrs['classes']!r:.60}")
    if "radar_cfg" in attrs:
        attrs["radar"] = RadarConfig.from_cfg_text(str(attrs["radar_cfg"]), f"{path}:radar_cfg")
    return attrs


def read_meta_group(path: str | Path, group: str = "meta") -> dict[str, np.ndarray]:
    """The ``meta`` group (or another group of (N,) columns) as numpy arrays (strings decoded)."""
    with h5py.File(path, "r") as h5:
        out = {}
        for k, ds in h5[group].items():
            a = ds[()]
            out[k] = np.asarray([s.decode() if isinstance(s, bytes) else s for s in a]) if a.dtype == object else a
        return out


def read_optional_group(path: str | Path, group: str) -> dict[str, np.ndarray]:
    """An optional group of (N,) columns (``quality``, ``convention``) as numpy arrays; {} where the file has none."""
    with h5py.File(path, "r") as h5:
        if group not in h5:
            return {}
    return read_meta_group(path, group)


def read_quality_group(path: str | Path) -> dict[str, np.ndarray]:
    """The per-row ``quality`` fields that ingest writes (handradar.data.quality); {} where the file has none."""
    return read_optional_group(path, "quality")


def read_convention(path: str | Path) -> tuple[np.ndarray | None, dict[str, bool]]:
    """The rows' range figure ``convention/range_mirror_db`` ((N,) dB, NaN where not measured; None where
    the file has none) and the ingest options they were read with (``iq_swap``, ``doppler_flip``; False
    where the file does not say)."""
    figure = read_optional_group(path, "convention").get("range_mirror_db")
    with h5py.File(path, "r") as h5:
        options = {k: bool(h5.attrs.get(k, False)) for k in READ_OPTIONS}
    return (None if figure is None else np.asarray(figure, np.float64)), options


def validate(path: str | Path) -> int:
    """Check the contract of a dataset file; return N or raise FormatError naming the problem."""
    path = Path(path)
    attrs = read_attrs(path)
    n = attrs["n"]
    with h5py.File(path, "r") as h5:
        spec = h5["spectrograms"]
        if spec.ndim != 3 or spec.shape[0] != n or spec.dtype != np.float32:
            raise FormatError(path, f"spectrograms must be (N, 64, 32) float32, found {spec.shape} {spec.dtype}")
        for lo in range(0, n, 4096):
            block = spec[lo:lo + 4096]
            if not np.all(np.isfinite(block)) or block.min(initial=0) < 0 or block.max(initial=0) > 1:
                raise FormatError(path, f"spectrograms {lo}..{lo + len(block)} have values outside [0, 1]")
        labels = h5["labels"]
        if labels.dtype != np.int64 or labels.shape != (n,):
            raise FormatError(path, f"labels must be ({n},) int64, found {labels.shape} {labels.dtype}")
        classes = attrs["classes"]
        if classes is not None and n:
            lo, hi = int(labels[()].min()), int(labels[()].max())
            if lo < 0 or hi >= len(classes):
                raise FormatError(path, f"labels must index the {len(classes)} classes, found values {lo}..{hi}")
        sk = h5["skeletons"]
        if sk.ndim != 5 or sk.shape[0] != n or sk.shape[2:] != (2, 21, 3) or sk.dtype != np.float32:
            raise FormatError(path, f"skeletons must be (N, T, 2, 21, 3) float32, found {sk.shape} {sk.dtype}")
        if "hand_mask" in h5 and h5["hand_mask"].shape != (n, sk.shape[1], 2):
            raise FormatError(path, f"hand_mask must be ({n}, {sk.shape[1]}, 2), found {h5['hand_mask'].shape}")
        if not isinstance(h5["meta"], h5py.Group):
            raise FormatError(path, "'meta' must be a group of (N,) arrays")
        for k, ds in h5["meta"].items():
            if not isinstance(ds, h5py.Dataset) or ds.shape != (n,):
                raise FormatError(path, f"meta/{k} must have shape ({n},), found {getattr(ds, 'shape', 'a group')}")
        if "quality" in h5:
            _validate_quality(path, h5["quality"], n)
        if "convention" in h5:
            _validate_convention(path, h5["convention"], n)
        for k in ("config_hash", "code_version"):
            if k not in h5.attrs:
                raise FormatError(path, f"missing attribute {k!r}")
    return n


QUALITY_SHARES = ("coverage", "clipped_share", "out_of_view")  # quality fields that are shares: in [0, 1] or NaN


def _validate_quality(path: Path, group: object, n: int) -> None:
    """The optional ``quality`` group: (N,) columns, its shares within [0, 1] (NaN: not measured)."""
    if not isinstance(group, h5py.Group):
        raise FormatError(path, "'quality' must be a group of (N,) arrays")
    for k, ds in group.items():
        if not isinstance(ds, h5py.Dataset) or ds.shape != (n,):
            raise FormatError(path, f"quality/{k} must have shape ({n},), found {getattr(ds, 'shape', None)}")
        if k in QUALITY_SHARES:
            a = ds[()]
            if a.dtype.kind != "f" or np.any((a < 0) | (a > 1)):
                raise FormatError(path, f"quality/{k} must be shares in [0, 1] (float; NaN where not measured)")


def _validate_convention(path: Path, group: object, n: int) -> None:
    """The optional ``convention`` group: ``range_mirror_db``, (N,) float (NaN: not measured)."""
    figure = group.get("range_mirror_db") if isinstance(group, h5py.Group) else None
    if not isinstance(figure, h5py.Dataset) or figure.shape != (n,) or figure.dtype.kind != "f":
        raise FormatError(path, f"convention/range_mirror_db must be ({n},) float (dB; NaN where not measured), "
                                f"found {getattr(figure, 'shape', None)} {getattr(figure, 'dtype', '')}")
