"""Recordings -> HDF5 dataset (``handradar-ingest``)."""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from handradar.atomic import atomic_write_text
from handradar.data.convention import ConventionCheck, check_row, range_mirror_db
from handradar.data.examples import Example, recording_example, skeleton_steps
from handradar.data.hdf5 import open_writer
from handradar.data.quality import (
    DuplicateIndex,
    QualityReport,
    RecordingQuality,
    adc_fingerprint,
    duplicate_findings,
    gate_capture,
    gate_window,
    leap_fingerprint,
)
from handradar.data.recording import (
    FILES,
    Recording,
    check_folder,
    load_recording,
    read_radar,
    scan,
)
from handradar.errors import FormatError, HandradarError, printable
from handradar.provenance import config_hash
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig
from handradar.runs.cli import bool_option
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
    quality: QualityReport = field(default_factory=QualityReport)  # per recording that reached the gate
    check: bool = False  # checked only: ``written`` counts the rows a dataset would hold

    def skip(self, name: str, exc: Exception) -> None:
        self.skipped.append((name, printable(str(exc))))
        path = getattr(exc, "path", None)
        self.by_file[path.name if path is not None else type(exc).__name__] += 1

    def report(self) -> str:
        did = "checked; would ingest" if self.check else "ingested"
        lines = [f"{did} {self.written} of {self.found} recordings; skipped {len(self.skipped)}"]
        if self.by_file:
            lines.append("  skipped by failing file: " + ", ".join(f"{k} {n}" for k, n in self.by_file.most_common()))
        for name, reason in self.skipped[:20]:
            lines.append(f"  skipped {name}: {reason}")
        if len(self.skipped) > 20:
            lines.append(f"  ... and {len(self.skipped) - 20} more")
        if self.written:
            lines.append(self.convention.message())
        if self.quality.rows:
            lines.append(self.quality.table())
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


def output_path(out: str | Path) -> Path:
    """``out`` as the dataset's file path; FormatError for a folder: one that exists, or a name ending in
    ``/`` (a folder by intent; no file name is invented for it)."""
    text = os.fspath(out)
    if text.endswith(("/", os.sep)):
        raise FormatError(text, f"names a folder (it ends in '/'); give the dataset's file name, such as "
                                f"{text}dataset.h5")
    if Path(text).is_dir():
        raise FormatError(text, "the output path is a directory; expected a file name such as data.h5")
    return Path(text)


def refuse_output_inside(out: Path, root: Path, folders: Iterable[Path]) -> None:
    """FormatError when ``out`` lies inside the input: under ``root`` or a recording folder (links
    resolved). Written there, the dataset could replace a recording's file (out=<rec>/adc_data.bin),
    and the next ingest of ``root`` would search it."""
    target = out.resolve()
    for place in (root, *folders):
        inside = place.resolve()
        if target == inside or inside in target.parents:
            what = "is an input file" if target.is_file() and target.name in FILES else "lies inside the input"
            raise FormatError(out, f"{what} (under {place}); write the dataset outside the recordings folder "
                                   f"{root}")


def ingest(root: str | Path, out: str | Path | None, chain: ChainConfig, *, skeleton_rate_hz: float = 100.0,
           strict: bool = False, allow_truncated: bool = False, coverage_tolerance_s: float = 0.05,
           iq_swap: bool = False, doppler_flip: bool = False, progress: bool = True,
           check: bool = False) -> IngestSummary:
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
    (``<out stem>.checks.json``); each row's range figure and the two options also into the dataset
    (group ``convention``, file attributes ``iq_swap`` and ``doppler_flip``), where a check of its rows
    alone finds them.

    Every recording passes the quality gate (handradar.data.quality): one that cannot carry a
    gesture is skipped with the measured figure, a doubtful one is kept and named; the report goes
    into the summary (a table), into the checks JSON, and as per-row fields into the dataset's
    ``quality`` group. check: run every check and report, but write nothing (``out`` unused).
    """
    strict, allow_truncated, iq_swap, doppler_flip, check = (bool_option(k, v) for k, v in (
        ("strict", strict), ("allow_truncated", allow_truncated), ("iq_swap", iq_swap),
        ("doppler_flip", doppler_flip), ("check", check)))
    out = None if check else output_path(out)  # check: nothing is written
    found = scan(root)
    meta_less = set(found.meta_less)
    folders = sorted([*found.recordings, *meta_less])
    root = Path(root)
    if out is not None:
        refuse_output_inside(out, root, folders)
    summary = IngestSummary(found=len(folders) + len(found.unreadable) + len(found.repeats), check=check,
                            convention=ConventionCheck(iq_swap=iq_swap, doppler_flip=doppler_flip))
    if not folders:
        unread = "".join(f"; cannot read {printable(str(f))}: {why}" for f, why in found.unreadable[:3])
        raise FormatError(root, f"no recordings found (no folder with a meta.json or other recording files){unread}")

    def name_of(folder: Path) -> str:
        """Recording name stored in the dataset: its path under ``root`` (unique, unlike the leaf name),
        bytes that are not UTF-8 written as \\xNN."""
        rel = folder.relative_to(root).as_posix()
        return printable(rel if rel != "." else folder.name)

    def skip(folder: Path, exc: HandradarError) -> None:
        if strict:
            raise exc
        summary.skip(name_of(folder), exc)
        log.warning("skipping %s: %s", printable(str(folder)), exc)

    for folder, reason in found.unreadable:  # it may hold recordings: reported as one skipped entry
        skip(folder, FormatError(folder, f"cannot read the folder ({reason}); the recordings in it, if any, are skipped"))
    for folder, first, n in found.repeats:  # not bad data: listed, never a strict failure
        summary.skip(name_of(folder), FormatError(folder, f"the same folder as {name_of(first)}, reached again "
                                                          f"through a symbolic link; its {n} recording(s) are "
                                                          f"ingested once, as {name_of(first)}"))
    for folder in folders:
        if printable(str(folder)) != str(folder):
            log.warning("%s: the name is not valid UTF-8; its recording is stored as %s", printable(str(folder)),
                        name_of(folder))

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

    duplicates = DuplicateIndex()
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
                quality, rec = gate_capture(rec)  # rec: its outlier frames dropped
                summary.quality.add(name_of(folder), quality)
                _raise_if_skipped(folder, quality)
                try:
                    ex = recording_example(rec, chain, skeleton_rate_hz)
                except ValueError as exc:  # a capture shorter than one spectrogram window, a gate beyond range
                    del summary.quality.rows[name_of(folder)]  # not the gate's verdict: reported as a format failure
                    raise FormatError(folder / "adc_data.bin", str(exc)) from None
                ex = gate_window(rec, ex, chain, quality)  # steps inside long Leap gaps untracked
                _raise_if_skipped(folder, quality)
                keys = adc_fingerprint(rec.adc), leap_fingerprint(rec.skeleton)
                duplicate_findings(duplicates.find(folder, *keys), quality)
            except HandradarError as exc:
                skip(folder, exc)
                continue
            duplicates.add(name_of(folder), folder, *keys)
            labels = rec.meta.labels()
            labels["recording"] = name_of(folder)
            r_by_lag, mirror_db = convention_of(rec, ex, chain)
            summary.convention.add(labels["recording"], r_by_lag, mirror_db)
            summary.written += 1
            if check:
                continue
            if writer is None:
                radar = radars[ref]
                n_steps = skeleton_steps(chain, radar, skeleton_rate_hz)
                writer = stack.enter_context(open_writer(
                    out, classes=GESTURES, radar=radar, chain=chain, skeleton_rate_hz=skeleton_rate_hz,
                    n_steps=n_steps, config_hash=config_hash(radar, chain, skeleton_rate_hz, "ingest"),
                    extra_attrs={"iq_swap": iq_swap, "doppler_flip": doppler_flip}))
            # the range figure travels with the row: a check of the dataset alone cannot measure it
            writer.append(ex.spectrogram, rec.meta.label, ex.skeleton.positions, ex.skeleton.mask,
                          ex.window_start_s, labels, quality=quality.row_fields(),
                          convention={"range_mirror_db": mirror_db})
        if check:
            return summary
        if writer is None:
            raise FormatError(root, f"none of the {len(folders)} recordings could be ingested:\n{summary.report()}")
    checks = {"convention": summary.convention.to_json(),
              "quality": summary.quality.to_json(), "skipped": dict(summary.skipped)}
    atomic_write_text(checks_path(out), json.dumps(checks, indent=1) + "\n")  # after the dataset is complete
    return summary


def _raise_if_skipped(folder: Path, quality: RecordingQuality) -> None:
    """The quality gate's first skip finding as the FormatError that skips the recording, naming its file."""
    finding = quality.first_skip()
    if finding is not None:
        raise FormatError(folder / finding.file, f"{finding.message} (quality gate: {finding.check})")


def checks_path(dataset: str | Path) -> Path:
    """The JSON of the data checks written beside a dataset file."""
    dataset = Path(dataset)
    return dataset.with_name(dataset.stem + ".checks.json")

