"""Skeleton sources for ``handradar-synth source=sfinge3d|dhg|leap source.root=DIR``.

Each source is a function ``items(root, **options) -> Iterator[SourceItem]`` yielding sequences
already in the radar frame, with their class index, the source's class names, an item name and a
meta dict (the dataset's ``meta`` fields the source has: gesture, subject, hands, repetition,
recording, ...). :func:`iter_source` looks a source up by name.

- ``sfinge3d``: SFINGE3D Dictionary files (13 classes), placed over the radar.
- ``dhg``: DHG-14/28 (``n_classes`` 14 or 28; SHREC'17 with ``trim=False``), placed over the radar.
- ``leap``: a folder of ``handradar.recording/1`` recordings of which only ``leap.jsonl`` and
  ``meta.json`` are read; their calibration already puts them in the radar frame.
- ``motions``: procedural sequences of the motion library (handradar.hand.motions) for any class
  vocabulary, ``classes: {class: [motion, ...]}``; it reads no folder.

errors: pass a list to skip bad items (each ``(name, message)`` is appended to it) instead of
raising FormatError at the first one.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from handradar.data.recording import find_recordings, read_meta
from handradar.errors import FormatError, HandradarError
from handradar.hand.importers import dhg, sfinge3d
from handradar.hand.leap import read_leap_jsonl
from handradar.hand.motions import MOTIONS, MotionDraw, motion_sequence
from handradar.hand.placement import DEFAULT_CENTRE_M, place_in_radar
from handradar.hand.skeleton import HandSequence
from handradar.vocab import GESTURES


@dataclass
class SourceItem:
    sequence: HandSequence  # radar frame, metres; t = 0 at the item's first frame (leap: radar frame 0)
    label: int  # index into classes
    classes: tuple[str, ...]
    name: str  # unique within the source (a relative path)
    meta: dict[str, object] = field(default_factory=dict)


def _guard(errors: list | None, name: str, fn: Callable[[], SourceItem]) -> SourceItem | None:
    try:
        return fn()
    except HandradarError as exc:
        if errors is None:
            raise
        errors.append((name, str(exc)))
        return None


def require_dataset_folder(name: str, root: str | Path) -> Path:
    """``root`` as a Path; a FormatError naming it and how to get the dataset when it is not a folder."""
    root = Path(root)
    if not root.is_dir():
        fetch = {"sfinge3d": f"`make fetch-data` (or `handradar-fetch dataset=sfinge3d out={root}`)",
                 "dhg": f"`handradar-fetch dataset=dhg fetch.url=URL out={root}` (URL: the DHG2016.zip archive)"}
        raise FormatError(root, f"no such folder: the {name} skeletons are read from here; get them with "
                                f"{fetch[name]}, or point the source at a copy: "
                                f"source.root=DIR (train.py presets: data.{name}.root=DIR); see docs/datasets.md")
    return root


def sfinge3d_items(root: str | Path, *, centre_m: Sequence[float] = DEFAULT_CENTRE_M, yaw_deg: float = 0.0,
                   fps: float = sfinge3d.FPS, wrist_offset_m: float = 0.0, thumb_metacarpal_ratio: float = 1.45,
                   errors: list | None = None) -> Iterator[SourceItem]:
    """SFINGE3D Dictionary instances over the radar (palm facing it, centred at ``centre_m``)."""
    require_dataset_folder("sfinge3d", root)
    for path, label, name in sfinge3d.sfinge3d_files(root):
        def load(path=path, label=label, name=name) -> SourceItem:
            seq = sfinge3d.read_sfinge3d(path, fps=fps, wrist_offset_m=wrist_offset_m,
                                         thumb_metacarpal_ratio=thumb_metacarpal_ratio)
            seq = place_in_radar(seq, up_axis=sfinge3d.UP_AXIS, centre_m=centre_m, yaw_deg=yaw_deg)
            meta = {"gesture": sfinge3d.CLASSES[label], "hands": 1, "repetition": int(path.stem), "recording": name}
            return SourceItem(seq, label, sfinge3d.CLASSES, name, meta)

        item = _guard(errors, name, load)
        if item is not None:
            yield item


def dhg_items(root: str | Path, *, n_classes: int = 14, trim: bool = True, up_axis: str = dhg.UP_AXIS,
              mirror: bool = False, centre_m: Sequence[float] = DEFAULT_CENTRE_M, yaw_deg: float = 0.0,
              fps: float = dhg.FPS, errors: list | None = None) -> Iterator[SourceItem]:
    """DHG-14/28 sequences over the radar; ``n_classes`` 14 (gesture) or 28 (gesture x fingers)."""
    require_dataset_folder("dhg", root)
    names = dhg.classes(n_classes)
    files = dhg.dhg_files(root)
    info = dhg.load_info(root, trim)
    for path, key in files:
        def load(path=path, key=key) -> SourceItem:
            seq = dhg.read_listed(path, key, info, fps=fps, mirror=mirror)
            seq = place_in_radar(seq, up_axis=up_axis, centre_m=centre_m, yaw_deg=yaw_deg)
            label = key.label(n_classes)
            meta = {"gesture": names[label], "subject": f"s{key.subject:02d}", "hands": 1,
                    "repetition": key.essai, "fingers": key.finger, "recording": key.name}
            return SourceItem(seq, label, names, key.name, meta)

        item = _guard(errors, key.name, load)
        if item is not None:
            yield item


def leap_items(root: str | Path, *, errors: list | None = None) -> Iterator[SourceItem]:
    """Recordings under ``root``: leap.jsonl through meta.json's calibration (radar frame, radar clock)."""

    root = Path(root)
    for folder in find_recordings(root):
        name = folder.relative_to(root).as_posix() if folder != root else folder.name

        def load(folder=folder, name=name) -> SourceItem:
            meta = read_meta(folder)
            seq = read_leap_jsonl(folder / "leap.jsonl", np.asarray(meta.leap_to_radar), meta.radar_start_us)
            return SourceItem(seq, meta.label, GESTURES, name, {**meta.labels(), "recording": name})

        item = _guard(errors, name, load)
        if item is not None:
            yield item


def motion_classes(classes: Mapping[str, Sequence[str] | str]) -> dict[str, list[str]]:
    """``{class: [motion, ...]}`` checked: every class names at least one known motion (a bare name is a list of one)."""
    if not isinstance(classes, Mapping) or not classes:
        raise ValueError("the motions source needs classes: {class name: [motion, ...]}")
    out = {}
    for name, motions in classes.items():
        motions = [motions] if isinstance(motions, str) else list(motions or [])
        unknown = [m for m in motions if m not in MOTIONS]
        if not motions or unknown:
            raise ValueError(f"class {name!r}: " + (f"unknown motion {unknown[0]!r}" if unknown else "no motion")
                             + f"; choose from {list(MOTIONS)} (docs/datasets.md#motions)")
        out[str(name)] = motions
    return out


def motions_items(root: str | Path | None = None, *, classes: Mapping[str, Sequence[str] | str], per_class: int = 100,
                  seed: int = 0, duration_s: float = 3.2, rate_hz: float = 100.0,
                  ranges: Mapping[str, Sequence[float]] | None = None,
                  class_ranges: Mapping[str, Mapping[str, Sequence[float]]] | None = None,
                  errors: list | None = None) -> Iterator[SourceItem]:
    """``per_class`` sequences of each class, each of one of its motions (in turn) with a drawn :class:`MotionDraw`
    (``ranges`` over the defaults, then the class's own ``class_ranges[class]``).

    Reproducible: item i of class c depends on (seed, c, i) only. ``root`` is unused (no files).
    """
    mapping = motion_classes(classes)
    names = tuple(mapping)
    for label, (cls, motions) in enumerate(mapping.items()):
        for i in range(int(per_class)):
            rng = np.random.default_rng([int(seed), label, i])
            motion = motions[i % len(motions)]
            own = {**(ranges or {}), **(class_ranges or {}).get(cls, {})}
            draw = MotionDraw.draw(rng, {k: tuple(v) for k, v in own.items()})
            seq = motion_sequence(motion, draw, duration_s=duration_s, rate_hz=rate_hz, rng=rng)
            meta = {"gesture": cls, "motion": motion, "hands": 1, "subject": f"hand{draw.hand_scale:.2f}",
                    "repetition": i, "recording": f"{cls}/{i}"}
            yield SourceItem(seq, label, names, f"{cls}/{i}", meta)


SOURCES: dict[str, Callable[..., Iterator[SourceItem]]] = {
    "sfinge3d": sfinge3d_items,
    "dhg": dhg_items,
    "leap": leap_items,
    "motions": motions_items,
}


def source_classes(name: str, **options) -> tuple[str, ...]:
    """Class names of a source without reading it (``n_classes`` for dhg)."""

    if name == "sfinge3d":
        return sfinge3d.CLASSES
    if name == "dhg":
        return dhg.classes(options.get("n_classes", 14))
    if name == "leap":
        return GESTURES
    if name == "motions":
        return tuple(motion_classes(options.get("classes") or {}))
    raise ValueError(f"unknown skeleton source {name!r}; expected one of {sorted(SOURCES)}")


def iter_source(name: str, root: str | Path, **options) -> Iterator[SourceItem]:
    """Items of the source called ``name`` (see :data:`SOURCES`) under ``root``."""
    if name not in SOURCES:
        raise ValueError(f"unknown skeleton source {name!r}; expected one of {sorted(SOURCES)}")
    return SOURCES[name](root, **options)
