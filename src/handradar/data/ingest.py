"""Recordings -> HDF5 dataset (``handradar-ingest``)."""

from __future__ import annotations

import contextlib
import logging
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from tqdm.auto import tqdm

from handradar.data.examples import recording_example, skeleton_steps
from handradar.data.hdf5 import open_writer
from handradar.data.recording import find_recordings, load_recording
from handradar.errors import FormatError, HandradarError
from handradar.provenance import config_hash
from handradar.radar.chain import ChainConfig
from handradar.vocab import GESTURES

log = logging.getLogger(__name__)


@dataclass
class IngestSummary:
    """What an ingest run did: recordings found, written, and skipped with their reasons."""

    found: int = 0
    written: int = 0
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (recording, reason)
    by_file: Counter = field(default_factory=Counter)  # failing file name (radar.cfg, ...) -> count

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
        return "\n".join(lines)


def ingest(root: str | Path, out: str | Path, chain: ChainConfig, *, skeleton_rate_hz: float = 100.0,
           strict: bool = False, allow_truncated: bool = False, coverage_tolerance_s: float = 0.05,
           progress: bool = True) -> IngestSummary:
    """Write every valid recording under ``root`` to ``out``; the file appears only when complete.

    strict: raise at the first bad recording (nothing is written). Otherwise bad recordings are
    skipped and listed in the summary. All recordings must share one radar configuration.
    """
    out = Path(out)
    if out.is_dir():
        raise FormatError(out, "the output path is a directory; expected a file name such as data.h5")
    folders = find_recordings(root)
    summary = IngestSummary(found=len(folders))
    if not folders:
        raise FormatError(root, "no recordings found (no folder with a meta.json)")
    root = Path(root)

    def name_of(folder: Path) -> str:
        """Recording name stored in the dataset: its path under ``root`` (unique, unlike the leaf name)."""
        rel = folder.relative_to(root).as_posix()
        return rel if rel != "." else folder.name

    with contextlib.ExitStack() as stack:
        writer = radar = None
        for folder in tqdm(folders, desc="ingest", unit="rec", disable=not progress):
            try:
                rec = load_recording(folder, coverage_tolerance_s=coverage_tolerance_s,
                                     allow_truncated=allow_truncated)
                if radar is not None and rec.radar != radar:
                    raise FormatError(folder / "radar.cfg", "radar configuration differs from the first "
                                                            "recording's; ingest one configuration per dataset")
                try:
                    ex = recording_example(rec, chain, skeleton_rate_hz)
                except ValueError as exc:  # a capture shorter than one spectrogram window, a gate beyond range
                    raise FormatError(folder / "adc_data.bin", str(exc)) from None
            except HandradarError as exc:
                if strict:
                    raise
                summary.skip(name_of(folder), exc)
                log.warning("skipping %s: %s", folder, exc)
                continue
            if writer is None:
                radar = rec.radar
                n_steps = skeleton_steps(chain, radar, skeleton_rate_hz)
                writer = stack.enter_context(open_writer(
                    out, classes=GESTURES, radar=radar, chain=chain, skeleton_rate_hz=skeleton_rate_hz,
                    n_steps=n_steps, config_hash=config_hash(radar, chain, skeleton_rate_hz, "ingest")))
            labels = rec.meta.labels()
            labels["recording"] = name_of(folder)
            writer.append(ex.spectrogram, rec.meta.label, ex.skeleton.positions, ex.skeleton.mask,
                          ex.window_start_s, labels)
            summary.written += 1
        if writer is None:
            raise FormatError(root, f"none of the {len(folders)} recordings could be ingested:\n{summary.report()}")
    return summary
