"""Measured radar spectrogram datasets described by a manifest (docs/datasets.md, "Measured radar datasets").

A dataset of measured spectrogram images (class folders of PNG, JPG, NPY or MAT files) has no
skeletons and no raw ADC data. Its manifest (YAML, ``handradar.measured/1``) says where the rows are,
how the image axes map to Doppler and time, what is known of the radar and which motions of the
motion library (handradar.hand.motions) each class is made of. :class:`MeasuredDataset`
(``data=measured data.manifest=FILE``) turns it, once, into a cached ``handradar.dataset/1`` file:

- spectrograms (N, doppler, columns) in [0, 1], on the dataset's own grid (``grid: keep``, the
  default) or resampled to ``grid: [doppler, columns]`` (area average over time, linear over
  Doppler), with Doppler along axis 1, approaching at the high rows and zero Doppler at row
  ``doppler // 2`` (the project's convention: handradar.radar.chain);
- labels in the manifest's class order; ``meta``: ``split`` (the split's name), ``gesture`` (the
  class name), ``recording`` (the file, relative to the root);
- no skeletons: ``skeletons`` (N, 1, 2, 21, 3) zeros and ``hand_mask`` False, the file attribute
  ``skeletons`` = ``"none"``; the manifest (JSON) in the attribute ``manifest``.

Every problem is one :class:`~handradar.errors.FormatError` naming the file (the manifest, a folder,
an image) and the problem.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from handradar.atomic import file_lock
from handradar.config import read_yaml
from handradar.data.hdf5 import open_writer, read_attrs
from handradar.data.skeletons import motion_classes
from handradar.errors import FormatError
from handradar.hand.motions import DEFAULT_RANGES
from handradar.provenance import config_hash
from handradar.data.unknowns import UNKNOWN, UNKNOWNS, by_section
from handradar.radar.chain import ChainConfig, ClutterRemoval

log = logging.getLogger(__name__)

FORMAT = "handradar.measured/1"
SUFFIXES = (".png", ".jpg", ".jpeg", ".npy", ".mat")
RADAR_FIELDS = ("carrier_hz", *by_section("radar"))
PROCESSING = {  # processing.<key>: the default where a manifest leaves it out (docs/datasets.md#processing)
    "clutter_removal": "window",  # ClutterRemoval
    "mti_lag": 1,                 # loops, for clutter_removal mti
    "doppler_fft": None,          # the Doppler FFT's bins where the image keeps its central rows (None: its rows)
    "range": "sum",               # RANGE_MODES: how the range bins of range_gate_m become one image; unknown: fitted
    "range_gate_m": list(ChainConfig().gate_m),
    "quantity": "power",          # unknown: fitted (handradar.data.unknowns)
    "scale": "db",
    "normalise": "image",
    "reference_db": 0.0,          # normalise none: the power shown as 1, dB
    "cfar": None,                 # {guard: cells, training: cells, threshold_db: dB} along each column
    "threshold": None,            # pixels below this [0, 1] value set to 0
}


@dataclass
class Manifest:
    """A validated manifest; see the module docstring and docs/datasets.md for each field."""

    path: Path
    name: str
    root: Path
    layout: str                                   # glob under root with {split} and {class}
    splits: dict[str, str]                        # split name -> folder (the {split} of layout)
    train: str                                    # the split training rows come from
    test: list[str]                               # reported splits, never used for a choice
    classes: dict[str, list[str]]                 # class -> motions (label order)
    folders: dict[str, str]                       # class -> folder name (the {class} of layout)
    doppler_axis: int                             # 0: image rows are Doppler, 1: columns are
    approaching: str                              # "high" | "low" | "unknown": which end of the Doppler axis
    zero_doppler: float | None                    # index of zero Doppler along that axis; None: its centre
    grid: tuple[int, int] | None                  # None: keep the images' own grid
    values: tuple[float, float] | None            # value range mapped to [0, 1]; None: each image's min..max
    radar: dict[str, float | str]                 # RADAR_FIELDS, numbers or "unknown"
    processing: dict[str, Any]                    # PROCESSING: how the dataset's code made its images
    motion_ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    class_ranges: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)  # class -> its own ranges
    citation: str = ""
    test_fraction: float | None = None            # the split rule when the layout has no {split}
    split_seed: int = 0

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], path: Path) -> Manifest:
        """The manifest :meth:`as_dict` stored (a dataset file's attribute ``manifest``); ``path``: that file."""
        axes = d["axes"]
        return cls(path=path, name=d["name"], root=path.parent, layout=d["layout"], splits=d["splits"], train=d["train"],
                   test=d["test"], classes=d["classes"], folders=d["folders"],
                   doppler_axis=0 if axes["doppler"] == "rows" else 1, approaching=axes["approaching"],
                   zero_doppler=axes["zero_doppler"], grid=None if d["grid"] == "keep" else tuple(d["grid"]),
                   values=None if d["values"] == "per_image" else tuple(d["values"]), radar=d["radar"],
                   processing={**PROCESSING, **d.get("processing", {  # a file of before the processing section
                       "clutter_removal": ClutterRemoval.parse(d.get("clutter_removal", True)).value})},
                   motion_ranges={k: tuple(v) for k, v in d["motion_ranges"].items()},
                   class_ranges={c: {k: tuple(v) for k, v in r.items()} for c, r in d.get("class_ranges", {}).items()},
                   citation=d["citation"],
                   test_fraction=d["test_fraction"], split_seed=d["split_seed"])

    def value_of(self, unknown: str) -> object:
        """What the manifest states for ``unknown`` (handradar.data.unknowns.UNKNOWNS), UNKNOWN where it leaves it
        to the fit, as a nuisance no manifest states; a stated approaching end reads ``high``: the rows are already
        in the project's orientation."""
        key = UNKNOWNS[unknown].manifest
        if not key:
            return UNKNOWN
        section, name = key.split(".", 1)
        if section == "axes":
            return UNKNOWN if self.approaching == UNKNOWN else "high"
        return (self.radar if section == "radar" else self.processing)[name]

    def as_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, "name": self.name, "layout": self.layout, "splits": self.splits, "train": self.train,
                "test": self.test, "classes": self.classes, "folders": self.folders,
                "axes": {"doppler": ["rows", "columns"][self.doppler_axis], "approaching": self.approaching,
                         "zero_doppler": self.zero_doppler},
                "grid": "keep" if self.grid is None else list(self.grid),
                "values": "per_image" if self.values is None else list(self.values),
                "radar": self.radar, "processing": self.processing,
                "motion_ranges": {k: list(v) for k, v in self.motion_ranges.items()},
                "class_ranges": {c: {k: list(v) for k, v in r.items()} for c, r in self.class_ranges.items()},
                "citation": self.citation,
                "test_fraction": self.test_fraction, "split_seed": self.split_seed}


def _need(path: Path, d: Mapping, key: str, kind: type | tuple[type, ...], where: str = "") -> Any:
    if key not in d:
        raise FormatError(path, f"missing '{where}{key}'")
    if not isinstance(d[key], kind):
        names = " or ".join(k.__name__ for k in (kind if isinstance(kind, tuple) else (kind,)))
        raise FormatError(path, f"'{where}{key}' must be a {names}, found {d[key]!r:.60}")
    return d[key]


def _root(path: Path, raw: Any, override: str | Path | None) -> Path:
    """The data root: ``override``, else the first existing of the manifest's ``root`` (a folder or a
    list), relative entries taken from the manifest's folder."""
    if override:
        root = Path(override).expanduser()
        if not root.is_dir():
            raise FormatError(root, "no such folder (data.root: the folder holding the manifest's layout)")
        return root
    candidates = [raw] if isinstance(raw, str) else list(raw or [])
    if not candidates or not all(isinstance(c, str) for c in candidates):
        raise FormatError(path, "'root' must be a folder or a list of folders (relative to the manifest)")
    folders = [(path.parent / Path(c).expanduser()) for c in candidates]
    for f in folders:
        if f.is_dir():
            return f
    raise FormatError(folders[0], f"no such folder (the manifest's root; also tried {[str(f) for f in folders[1:]]}); "
                                  "fetch the data (docs/datasets.md) or pass data.root=DIR")


def _motion_ranges(path: Path, where: str, d: Any) -> dict[str, tuple[float, float]]:
    """``{parameter: (low, high)}`` of a manifest's motion ranges at ``where`` (handradar.hand.motions.DEFAULT_RANGES)."""
    if d is not None and not isinstance(d, dict):
        raise FormatError(path, f"'{where}' must map motion parameters to [low, high]")
    out = {}
    for k, v in (d or {}).items():
        if k not in DEFAULT_RANGES or not (isinstance(v, list) and len(v) == 2 and v[0] <= v[1]):
            raise FormatError(path, f"'{where}.{k}' must be one of {sorted(DEFAULT_RANGES)} with [low, high]")
        out[k] = (float(v[0]), float(v[1]))
    return out


def read_manifest(path: str | Path, root: str | Path | None = None) -> Manifest:
    """Read and check a manifest; ``root`` overrides its data root."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise FormatError(path, "manifest not found (data.manifest)")
    d = read_yaml(path)
    if not isinstance(d, dict):
        raise FormatError(path, "a manifest must be a YAML mapping")
    if d.get("format") != FORMAT:
        raise FormatError(path, f"'format' must be {FORMAT!r}, found {d.get('format')!r}")
    rows = _need(path, d, "rows", dict)
    layout = _need(path, rows, "layout", str, "rows.")
    if "{class}" not in layout:
        raise FormatError(path, f"'rows.layout' must contain {{class}}, found {layout!r}")
    splits = {str(k): str(v) for k, v in (rows.get("splits") or {}).items()}
    if "{split}" in layout and not splits:
        raise FormatError(path, "'rows.layout' has {split}: 'rows.splits' must map split names to folders")
    test_fraction = None
    if "{split}" not in layout:  # a split rule: a stratified share of each class is the test split
        test_fraction = rows.get("test_fraction", 0.2)
        if not isinstance(test_fraction, (int, float)) or not 0 < test_fraction < 1:
            raise FormatError(path, f"'rows.test_fraction' must lie in (0, 1), found {test_fraction!r}")
        splits = {"train": "", "test": ""}
    train = str(rows.get("train", next(iter(splits))))
    test = rows.get("test", [s for s in splits if s != train])
    test = [test] if isinstance(test, str) else [str(s) for s in test]
    for s in [train, *test]:
        if s not in splits:
            raise FormatError(path, f"split {s!r} is not one of rows.splits {sorted(splits)}")
    if not test:
        raise FormatError(path, "no test split: list one under rows.test (or add split folders)")
    raw_classes = _need(path, d, "classes", dict)
    specs = {name: {"motions": spec} if isinstance(spec, (str, list)) else spec for name, spec in raw_classes.items()}
    bad = next((name for name, spec in specs.items() if not isinstance(spec, dict)), None)
    if bad is not None:
        raise FormatError(path, f"class {bad!r}: give its motions as a list, or {{motions: [...], folder: NAME, "
                                "ranges: {...}}")
    try:
        classes = motion_classes({name: spec.get("motions") for name, spec in specs.items()})
    except ValueError as exc:  # an unknown motion, or none
        raise FormatError(path, str(exc)) from None
    folders = {str(name): str(spec.get("folder", name)) for name, spec in specs.items()}
    axes = _need(path, d, "axes", dict)
    doppler = axes.get("doppler", "rows")
    if doppler not in ("rows", "columns"):
        raise FormatError(path, f"'axes.doppler' must be rows or columns, found {doppler!r}")
    approaching = str(axes.get("approaching", UNKNOWN))
    if approaching not in ("high", "low", UNKNOWN):
        raise FormatError(path, f"'axes.approaching' must be high, low or unknown (which end of the Doppler axis), "
                                f"found {approaching!r}")
    zero = axes.get("zero_doppler")
    if zero is not None and not isinstance(zero, (int, float)):
        raise FormatError(path, f"'axes.zero_doppler' must be an index (or null: the axis centre), found {zero!r}")
    grid = d.get("grid", "keep")
    if grid != "keep" and not (isinstance(grid, list) and len(grid) == 2 and all(isinstance(g, int) and g > 1 for g in grid)):
        raise FormatError(path, f"'grid' must be keep or [doppler bins, columns], found {grid!r}")
    values = d.get("values", "per_image")
    if values != "per_image" and not (isinstance(values, list) and len(values) == 2 and values[1] > values[0]):
        raise FormatError(path, f"'values' must be per_image or [low, high], found {values!r}")
    radar_raw = d.get("radar") or {}
    if "clutter_removal" in radar_raw:
        raise FormatError(path, "'radar.clutter_removal' is now 'processing.clutter_removal' (none, window, frame or mti)")
    extra = sorted(set(radar_raw) - set(RADAR_FIELDS) - {"name"})
    if extra:
        raise FormatError(path, f"unknown radar field 'radar.{extra[0]}'; expected {list(RADAR_FIELDS)}")
    radar, unknowns = {}, by_section("radar")
    for k in RADAR_FIELDS:
        v = radar_raw.get(k, UNKNOWN)
        problem = None if v == UNKNOWN else unknowns[k].check(v) if k in unknowns else \
            (None if isinstance(v, (int, float)) and v > 0 else "must be a positive number or unknown")
        if problem:
            raise FormatError(path, f"'radar.{k}' {problem}, found {v!r}")
        radar[k] = v if v == UNKNOWN else float(v)
    processing = read_processing(path, d.get("processing") or {})
    ranges = _motion_ranges(path, "motion_ranges", d.get("motion_ranges"))
    class_ranges = {str(name): _motion_ranges(path, f"classes.{name}.ranges", spec["ranges"])
                    for name, spec in specs.items() if spec.get("ranges")}
    return Manifest(path=path, name=str(d.get("name", path.stem)), root=_root(path, d.get("root"), root), layout=layout,
                    splits=splits, train=train, test=test, classes=classes, folders=folders,
                    doppler_axis=0 if doppler == "rows" else 1, approaching=approaching,
                    zero_doppler=None if zero is None else float(zero),
                    grid=None if grid == "keep" else (int(grid[0]), int(grid[1])),
                    values=None if values == "per_image" else (float(values[0]), float(values[1])),
                    radar=radar, processing=processing, motion_ranges=ranges, class_ranges=class_ranges,
                    citation=str(d.get("citation", "")), test_fraction=test_fraction,
                    split_seed=int(rows.get("seed", 0)))


def read_processing(path: Path, raw: Any) -> dict[str, Any]:
    """The manifest's ``processing`` section checked, every key of :data:`PROCESSING` filled in."""
    if not isinstance(raw, dict):
        raise FormatError(path, "'processing' must be a mapping of the steps the dataset's code took")
    extra = sorted(set(raw) - set(PROCESSING))
    if extra:
        raise FormatError(path, f"unknown processing step 'processing.{extra[0]}'; expected {list(PROCESSING)}")
    p = {**PROCESSING, **raw}
    fitted = by_section("processing")

    def bad(key: str, what: str) -> FormatError:
        return FormatError(path, f"'processing.{key}' must be {what}, found {p[key]!r:.60}")

    for key, u in fitted.items():
        if p[key] != UNKNOWN and u.check(p[key]):
            raise bad(key, f"one of {list(u.choices)} or unknown")
    if p["clutter_removal"] not in [c.value for c in ClutterRemoval]:
        raise bad("clutter_removal", f"one of {[c.value for c in ClutterRemoval]}")
    if type(p["mti_lag"]) is not int or p["mti_lag"] < 1:
        raise bad("mti_lag", "a whole number of loops >= 1")
    if p["doppler_fft"] is not None and (type(p["doppler_fft"]) is not int or p["doppler_fft"] < 2):
        raise bad("doppler_fft", "the Doppler FFT's bins (a whole number) or null")
    gate = p["range_gate_m"]
    if not (isinstance(gate, list) and len(gate) == 2 and all(isinstance(g, (int, float)) for g in gate)
            and 0 <= gate[0] < gate[1]):
        raise bad("range_gate_m", "[near, far] in metres")
    if not isinstance(p["reference_db"], (int, float)):
        raise bad("reference_db", "a number of dB")
    cfar = p["cfar"]
    if cfar is not None:
        if not (isinstance(cfar, dict) and set(cfar) == {"guard", "training", "threshold_db"}
                and type(cfar["guard"]) is int and type(cfar["training"]) is int
                and isinstance(cfar["threshold_db"], (int, float))):
            raise bad("cfar", "{guard: cells, training: cells, threshold_db: dB} or null")
    if p["threshold"] is not None and not (isinstance(p["threshold"], (int, float)) and 0 <= p["threshold"] < 1):
        raise bad("threshold", "a value in [0, 1) or null")
    return p


def list_rows(m: Manifest) -> list[tuple[str, int, Path]]:
    """(split, label, file) of every row, sorted; a class folder that is missing or empty, or a split rule that
    leaves a class without training or test rows, is an error."""
    if m.test_fraction is not None:
        return _rule_split(m, _list_split(m, "train", ""))
    out = []
    for split, split_folder in m.splits.items():
        out += _list_split(m, split, split_folder)
    return out


def _rule_split(m: Manifest, rows: list[tuple[str, int, Path]]) -> list[tuple[str, int, Path]]:
    """Rows of a layout without split folders: ``test_fraction`` of each class (at least 1, drawn with
    ``split_seed``) become the ``test`` split."""
    labels = np.array([y for _, y, _ in rows])
    split = np.array(["train"] * len(rows), dtype=object)
    for c in np.unique(labels):
        members = np.flatnonzero(labels == c)
        k = max(1, int(round(m.test_fraction * len(members))))
        if k >= len(members):
            raise FormatError(rows[members[0]][2].parent, f"class {list(m.classes)[c]!r} has {len(members)} row(s): "
                                                          f"rows.test_fraction {m.test_fraction:g} leaves no training row")
        split[np.random.default_rng([m.split_seed, int(c)]).permutation(members)[:k]] = "test"
    return [(str(s), y, f) for s, (_, y, f) in zip(split, rows)]


def class_files(m: Manifest, split_folder: str, cls: str) -> tuple[Path, str, list[Path] | None]:
    """(folder, file glob, its files sorted by name) of class ``cls`` in ``split_folder`` under ``m.root``,
    as ``rows.layout`` places them; files None when the folder does not exist."""
    pattern = m.layout.replace("{split}", split_folder).replace("{class}", m.folders[cls])
    folder_part, _, file_glob = pattern.rpartition("/")
    folder, file_glob = m.root / folder_part, file_glob or "*"
    if not folder.is_dir():
        return folder, file_glob, None
    return folder, file_glob, sorted(f for f in folder.glob(file_glob) if f.suffix.lower() in SUFFIXES and f.is_file())


def _list_split(m: Manifest, split: str, split_folder: str) -> list[tuple[str, int, Path]]:
    """(split, label, file) of one split folder's classes, files sorted by name."""
    out = []
    for label, cls in enumerate(m.classes):
        folder, file_glob, files = class_files(m, split_folder, cls)
        if files is None:
            raise FormatError(folder, f"no such folder: class {cls!r} of split {split!r} (rows.layout {m.layout!r})")
        if not files:
            raise FormatError(folder, f"class {cls!r} of split {split!r} has no {'/'.join(SUFFIXES)} file "
                                      f"matching {file_glob!r}")
        out += [(split, label, f) for f in files]
    return out


def read_image(path: Path) -> np.ndarray:
    """One row's 2-D array: PNG/JPG (grey, or the mean of RGB), NPY, or the one 2-D array of a MAT file."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            a = np.load(path, allow_pickle=False)
        elif suffix == ".mat":
            import scipy.io

            arrays = [v for k, v in scipy.io.loadmat(path).items() if not k.startswith("__") and isinstance(v, np.ndarray)]
            if len(arrays) != 1:
                raise FormatError(path, f"a MAT row must hold one array, found {len(arrays)}")
            a = arrays[0]
        else:
            from PIL import Image

            with Image.open(path) as im:
                a = np.asarray(im.convert("L") if im.mode in ("RGB", "RGBA", "P") else im)
    except FormatError:
        raise
    except Exception as exc:  # PIL's, numpy's and scipy's many readers' errors: one line
        raise FormatError(path, f"unreadable image ({type(exc).__name__}: {' '.join(str(exc).split())[:120]})") from None
    a = np.squeeze(a)
    if a.ndim == 3 and a.shape[-1] in (3, 4):
        a = a[..., :3].mean(axis=-1)
    if a.ndim != 2 or a.dtype.kind not in "uif" or not np.isfinite(a).all():
        raise FormatError(path, f"a row must be a finite 2-D array of numbers, found shape {a.shape} {a.dtype}")
    return a


def to_unit(a: np.ndarray, m: Manifest, path: Path) -> np.ndarray:
    """An image in the project's orientation (Doppler on axis 0, approaching high, zero at the centre
    row) and values in [0, 1], resampled to ``m.grid`` when set."""
    a = a.astype(np.float64)
    if m.values is not None:
        lo, hi = m.values
        if a.min() < lo or a.max() > hi:
            raise FormatError(path, f"values {a.min():g}..{a.max():g} lie outside the manifest's values [{lo:g}, {hi:g}]")
        a = (a - lo) / (hi - lo)
    else:
        span = a.max() - a.min()
        a = (a - a.min()) / span if span > 0 else np.zeros_like(a)
    if m.doppler_axis == 1:
        a = a.T
    n = a.shape[0]
    zero = (n // 2) if m.zero_doppler is None else m.zero_doppler
    if not 0 <= zero <= n - 1:
        raise FormatError(m.path, f"'axes.zero_doppler' {zero:g} lies outside the Doppler axis of {path.name} "
                                  f"(indices 0..{n - 1})")
    if m.approaching == "low":  # flip, the zero row with it
        a, zero = a[::-1], n - 1 - zero
    a = np.roll(a, n // 2 - int(round(zero)), axis=0)  # the Doppler axis is periodic (an FFT's)
    if m.grid is not None and a.shape != m.grid:
        a = resample(a, m.grid)
    return a.astype(np.float32)


def resample(a: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(doppler, columns) -> ``shape``: columns by area averaging (or linear when upsampling), Doppler linearly."""
    import torch

    t = torch.as_tensor(np.ascontiguousarray(a))[None, None]
    out = torch.nn.functional.interpolate(t, size=shape, mode="bilinear", align_corners=False, antialias=True)
    return out[0, 0].clamp(0, 1).numpy()


def dataset_chain(m: Manifest, shape: tuple[int, int], chirps: int | None = None,
                  values: Mapping[str, Any] | None = None) -> ChainConfig:
    """The chain that reproduces the dataset's processing (``m.processing``): frame-based Doppler (one column per
    frame: the frame's ``chirps`` loops, default the FFT's bins, zero-padded to the Doppler FFT of ``doppler_fft``
    bins, or of ``shape[0]``, of which the central ``shape[0]`` rows are kept), its clutter filter, range handling,
    scaling and thresholds; ``values`` gives what the manifest leaves unknown (the dB floor: 30 dB while unknown)."""
    p, values = m.processing, dict(values or {})
    fft = int(p["doppler_fft"] or shape[0])
    if fft < shape[0]:
        raise FormatError(m.path, f"'processing.doppler_fft' {fft} is fewer than the images' {shape[0]} Doppler rows")

    def stated(key: str) -> Any:  # the manifest's value, else the fitted one; its default unset (None)
        v = p[key] if p[key] != UNKNOWN else values.get(key)
        return None if v is None or v == PROCESSING[key] else v

    dr = m.radar["dynamic_range_db"] if m.radar["dynamic_range_db"] != UNKNOWN else values.get("dynamic_range_db")
    cfar, n = p["cfar"], int(chirps or fft)
    settings = dict(stft_len=n, stft_hop=n, doppler_bins=fft, n_columns=shape[1],
                    doppler_keep=shape[0] if fft != shape[0] else None, gate_m=tuple(p["range_gate_m"]),
                    clutter_removal=p["clutter_removal"], mti_lag=p["mti_lag"] if p["clutter_removal"] == "mti" else None,
                    range_mode=stated("range"), quantity=stated("quantity"), scale=stated("scale"),
                    normalise=stated("normalise"),
                    reference_db=float(p["reference_db"]) if p["normalise"] == "none" else None,
                    cfar=None if cfar is None else (cfar["guard"], cfar["training"], float(cfar["threshold_db"])),
                    threshold=None if p["threshold"] is None else float(p["threshold"]),
                    dynamic_range_db=30.0 if dr is None else float(dr))
    try:
        return ChainConfig(**settings)
    except ValueError as exc:  # a combination the chain refuses (a CFAR wider than the rows, a lag beyond the chirps)
        raise FormatError(m.path, f"'processing': {exc}") from None


def measured_manifest(path: str | Path) -> tuple[Manifest, tuple[int, int]]:
    """The manifest a measured dataset file (:class:`MeasuredDataset`) was built from, and its (doppler, columns) grid."""
    attrs = read_attrs(path)
    if attrs.get("skeletons") != "none" or "manifest" not in attrs:
        raise FormatError(path, "not a measured dataset (data=measured data.manifest=FILE builds one)")
    return Manifest.from_dict(json.loads(attrs["manifest"]), Path(path)), (attrs["chain"].n_doppler,
                                                                           attrs["chain"].n_columns)


class MeasuredDataset:
    """``data=measured data.manifest=FILE [data.root=DIR]``: the manifest's rows as a cached dataset file."""

    def __init__(self, manifest: str | Path, cache_dir: str | Path, root: str | Path | None = None) -> None:
        self.manifest_path, self.cache_dir, self.root = Path(manifest).expanduser(), Path(cache_dir), root

    def manifest(self) -> Manifest:
        return read_manifest(self.manifest_path, self.root)

    def path(self) -> Path:
        m = self.manifest()
        rows = list_rows(m)
        listing = [(s, y, f.relative_to(m.root).as_posix(), f.stat().st_size, f.stat().st_mtime_ns) for s, y, f in rows]
        out = self.cache_dir / f"measured-{m.name}-{config_hash(m.as_dict(), listing)}.h5"
        with file_lock(out.with_name(out.name + ".lock")):
            if not out.is_file():
                write_measured(m, rows, out)
        return out.resolve()


def write_measured(m: Manifest, rows: Sequence[tuple[str, int, Path]], out: Path) -> Path:
    """Read every row, check one grid, write the dataset file atomically (nothing at ``out`` on failure)."""
    images, shape = [], None
    for i, (_, _, f) in enumerate(rows):
        a = to_unit(read_image(f), m, f)
        if shape is None:
            shape, first = a.shape, f
        elif a.shape != shape:
            raise FormatError(f, f"image is {a.shape[0]} x {a.shape[1]} (Doppler x time), {first.name} is "
                                 f"{shape[0]} x {shape[1]}: mixed sizes (set grid: [doppler, columns] to resample)")
        images.append(a)
        if (i + 1) % 1000 == 0:
            log.info("%s: read %d of %d rows", m.name, i + 1, len(rows))
    chain = dataset_chain(m, shape)
    with open_writer(out, classes=list(m.classes), radar=None, chain=chain, skeleton_rate_hz=0.0, n_steps=1,
                     config_hash=config_hash(m.as_dict()),
                     extra_attrs={"manifest": json.dumps(m.as_dict()), "skeletons": "none",
                                  "source": f"handradar.measured:{m.name}"}) as w:
        empty, no_hand = np.zeros((1, 2, 21, 3), np.float32), np.zeros((1, 2), bool)
        for (split, label, f), a in zip(rows, images):
            w.append(a, label, empty, no_hand, math.nan,
                     {"split": split, "gesture": list(m.classes)[label], "recording": f.relative_to(m.root).as_posix()})
    log.info("%s: %d rows of %d x %d, %d classes -> %s", m.name, len(rows), *shape, len(m.classes), out.name)
    return out
