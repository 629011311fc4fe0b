"""Recordings -> HDF5 dataset (``handradar-ingest``)."""

from __future__ import annotations

import contextlib
import json
import logging
import math
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from handradar.atomic import atomic_write_text
from handradar.data.convention import ConventionCheck, check_row, range_mirror_db
from handradar.data.examples import Example, recording_example, skeleton_steps
from handradar.data.hdf5 import open_writer
from handradar.data.recording import (
    FILES,
    Recording,
    check_folder,
    find_meta_less_folders,
    find_recordings,
    load_recording,
    read_radar,
)
from handradar.errors import FormatError, HandradarError
from handradar.provenance import config_hash
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig
from handradar.vocab import GESTURES

log = logging.getLogger(__name__)


@dataclass
class IngestSummary:
    """What an ingest run did: recordings found, written, and skipped with their reasons."""

    found: int = 0
    written: int = 0
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (recording, reason)
    by_file: Counter = field(default_factory=Counter)  # failing file name (radar.cfg, ...) -> count
    convention: ConventionCheck = field(default_factory=ConventionCheck)  # per written row

    def skip(self, name: str, exc: Exception) -> None:
        self.skipped.append((name, str(exc)))
        path = getattr(exc, "path", None)
        self.by_file[path.name if path is not None else type(exc).__name__] += 1

    def report(self) -> str:
        lines = [f"ingested {self.written} of {self.found} recordings; skipped {len(self.skipped)}"]
        if self.by_file:
            lines.append("  skipped by failing file: " + ", ".join(f"{k} {n}" for k, n in self.by_file.most_common()))
        for name, reason in self.skipped[:20]:
            lines.append(f"  skipped {name}: {reason}")
        if len(self.skipped) > 20:
            lines.append(f"  ... and {len(self.skipped) - 20} more")
        if self.written:
            lines.append(self.convention.message())
        return "\n".join(lines)


# RadarConfig fields that leave the processing chain's output unchanged: the capture length (the
# window is chosen inside each capture), the transmitter's turn-on time before the ramp, and a
# constant amplitude scale (RX gain, ADC bits) that the chain's per-spectrogram peak normalisation
# removes. Every other field changes the range bins, Doppler axis, channels or timing.
NOT_PROCESSING_FIELDS = frozenset({"n_frames", "tx_start_time_s", "rx_gain_db", "adc_bits", "source"})


def processing_fields(radar: RadarConfig) -> dict[str, object]:
    """The radar settings that change the processing chain (name -> value)."""
    return {f.name: getattr(radar, f.name) for f in fields(radar) if f.name not in NOT_PROCESSING_FIELDS}


def reference_recording(radars: dict[Path, RadarConfig]) -> Path | None:
    """The recording whose processing settings are the most common; ties: the first in sorted order.

    ``radars``: each readable recording's radar.cfg. The reference is the first recording (sorted
    by path) of the most common configuration, so one odd recording never decides, wherever it sorts.
    """
    if not radars:
        return None
    keys = {folder: tuple(processing_fields(r).items()) for folder, r in radars.items()}
    counts = Counter(keys.values())
    most = max(counts.values())
    return next(folder for folder in sorted(radars) if counts[keys[folder]] == most)


def _values(a: object, b: object) -> tuple[str, str]:
    """Two differing settings as text that tells them apart (10 significant digits, else in full)."""
    if isinstance(a, float) and isinstance(b, float):
        short = f"{a:.10g}", f"{b:.10g}"
        return short if short[0] != short[1] else (repr(a), repr(b))
    return str(a), str(b)


def radar_differences(radar: RadarConfig, reference: RadarConfig, reference_name: str) -> list[str]:
    """``field: value here, value in <reference>`` for each processing setting in which ``radar`` differs."""
    mine, ref = processing_fields(radar), processing_fields(reference)
    out = []
    for k in mine:
        if mine[k] != ref[k]:
            here, there = _values(mine[k], ref[k])
            out.append(f"{k}: {here} here, {there} in {reference_name}")
    return out


@contextlib.contextmanager
def _one_torch_thread() -> Iterator[None]:
    """Run torch single-threaded inside the block, then restore the thread count.

    One recording's tensors (a 6 MB ADC cube, then kilobytes) are too small for intra-op threads
    to pay off, and where other processes share the cores every parallel step waits for a
    descheduled thread: chain + skeleton window took 57 ms per recording with 2 threads against
    7 ms with one on the loaded 2-core development machine. Results do not change: the steps torch
    splits across threads at this size (window product, range FFT, copies) compute each element
    or row alone; the reductions run on tensors below its parallel grain size.
    """
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


def convention_of(rec: Recording, ex: Example, chain: ChainConfig) -> tuple[np.ndarray, float]:
    """The sign-convention figures of one written row (handradar.data.convention): r by lag over the
    recording's whole skeleton, and the range mirror of the window's ADC (first RX, every 8th chirp:
    1/32 of the window, plenty for a power ratio)."""
    sk = rec.skeleton
    r = check_row(ex.spectrogram, sk.positions, sk.mask, sk.times, rec.radar, chain, ex.window_start_s)
    f0, n = int(round(ex.window_start_s / rec.radar.frame_period_s)), chain.frames_per_window(rec.radar)
    inside = (sk.times >= ex.window_start_s) & (sk.times < ex.window_start_s + n * rec.radar.frame_period_s)
    ranges = np.linalg.norm(sk.positions[inside][sk.mask[inside]], axis=-1)  # (tracked hand steps, 21)
    if not ranges.size:
        return r, math.nan
    return r, range_mirror_db(rec.adc[f0:f0 + n, ::8, :1], rec.radar, np.median(ranges))


def ingest(root: str | Path, out: str | Path, chain: ChainConfig, *, skeleton_rate_hz: float = 100.0,
           strict: bool = False, allow_truncated: bool = False, coverage_tolerance_s: float = 0.05,
           iq_swap: bool = False, doppler_flip: bool = False, progress: bool = True) -> IngestSummary:
    """Write every valid recording under ``root`` to ``out``; the file appears only when complete.

    strict: raise at the first bad recording (nothing is written; missing files and radar.cfg are
    checked in every recording before anything else). Otherwise bad recordings are skipped and
    listed in the summary. Folders with recording files but no meta.json count as
    found and are skipped. All recordings must share the settings that change the processing
    chain (:func:`processing_fields`): every radar.cfg is read first, the most common settings are
    the reference (ties: the first recording in sorted order), and a recording that differs is
    skipped with the fields and both values. iq_swap, doppler_flip: read captures whose I and Q are
    exchanged, or whose Doppler runs mirrored (handradar.data.convention says which). The sign-
    convention figures of every row go into the summary and, as JSON, beside ``out``
    (``<out stem>.checks.json``).
    """
    out = Path(out)
    if out.is_dir():
        raise FormatError(out, "the output path is a directory; expected a file name such as data.h5")
    meta_less = set(find_meta_less_folders(root))
    folders = sorted([*find_recordings(root), *meta_less])
    summary = IngestSummary(found=len(folders))
    if not folders:
        raise FormatError(root, "no recordings found (no folder with a meta.json or other recording files)")
    root = Path(root)

    def name_of(folder: Path) -> str:
        """Recording name stored in the dataset: its path under ``root`` (unique, unlike the leaf name)."""
        rel = folder.relative_to(root).as_posix()
        return rel if rel != "." else folder.name

    def skip(folder: Path, exc: HandradarError) -> None:
        if strict:
            raise exc
        summary.skip(name_of(folder), exc)
        log.warning("skipping %s: %s", folder, exc)

    # the radar configurations first: they choose the reference, and a bad radar.cfg is reported as such
    radars: dict[Path, RadarConfig] = {}
    for folder in folders:
        try:
            if folder in meta_less:
                present = [f for f in FILES if (folder / f).is_file()]
                raise FormatError(folder / "meta.json", f"no such file; the folder holds {', '.join(present)} but "
                                                        "no meta.json (labels, radar_start_us, leap_to_radar), so "
                                                        "it is not a recording")
            radars[folder] = read_radar(check_folder(folder))
        except HandradarError as exc:
            skip(folder, exc)
    ref = reference_recording(radars)
    if ref is not None:
        n_ref = sum(processing_fields(r) == processing_fields(radars[ref]) for r in radars.values())
        log.info("reference radar configuration: %s (%d of %d recordings)", name_of(ref), n_ref, len(radars))

    with contextlib.ExitStack() as stack:
        stack.enter_context(_one_torch_thread())
        writer = None
        for folder in tqdm(list(radars), desc="ingest", unit="rec", disable=not progress):
            try:
                diff = radar_differences(radars[folder], radars[ref], name_of(ref))
                if diff:
                    raise FormatError(folder / "radar.cfg", f"radar configuration differs from the reference "
                                                            f"recording {name_of(ref)}'s in {'; '.join(diff)} "
                                                            f"(the reference has the most common configuration, "
                                                            f"{n_ref} of {len(radars)} recordings; ties go to the "
                                                            "first in sorted order); ingest one configuration per "
                                                            "dataset")
                rec = load_recording(folder, coverage_tolerance_s=coverage_tolerance_s,
                                     allow_truncated=allow_truncated, iq_swap=iq_swap, doppler_flip=doppler_flip)
                try:
                    ex = recording_example(rec, chain, skeleton_rate_hz)
                except ValueError as exc:  # a capture shorter than one spectrogram window, a gate beyond range
                    raise FormatError(folder / "adc_data.bin", str(exc)) from None
            except HandradarError as exc:
                skip(folder, exc)
                continue
            if writer is None:
                radar = radars[ref]
                n_steps = skeleton_steps(chain, radar, skeleton_rate_hz)
                writer = stack.enter_context(open_writer(
                    out, classes=GESTURES, radar=radar, chain=chain, skeleton_rate_hz=skeleton_rate_hz,
                    n_steps=n_steps, config_hash=config_hash(radar, chain, skeleton_rate_hz, "ingest")))
            labels = rec.meta.labels()
            labels["recording"] = name_of(folder)
            writer.append(ex.spectrogram, rec.meta.label, ex.skeleton.positions, ex.skeleton.mask,
                          ex.window_start_s, labels)
            summary.convention.add(labels["recording"], *convention_of(rec, ex, chain))
            summary.written += 1
        if writer is None:
            raise FormatError(root, f"none of the {len(folders)} recordings could be ingested:\n{summary.report()}")
    checks = {"convention": {**summary.convention.to_json(), "iq_swap": iq_swap, "doppler_flip": doppler_flip}}
    atomic_write_text(checks_path(out), json.dumps(checks, indent=1) + "\n")  # after the dataset is complete
    return summary


def checks_path(dataset: str | Path) -> Path:
    """The JSON of the data checks written beside a dataset file."""
    dataset = Path(dataset)
    return dataset.with_name(dataset.stem + ".checks.json")

