"""Recording folders in the ``handradar.recording/1`` format (docs/architecture.md, "Recording format").

A recording is a folder with ``radar.cfg``, ``adc_data.bin``, ``leap.jsonl`` and ``meta.json``.
:func:`load_recording` validates all four and returns the radar cube, the skeleton in the radar
frame on the radar clock, and the labels. The generator's ``truth`` object is never loaded here:
only evaluation code may read it, through :func:`read_truth`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from handradar.atomic import atomic_write_text
from handradar.errors import FormatError
from handradar.hand.leap import (
    check_hand_geometry,
    finite_number,
    leap_matrix,
    read_leap_jsonl,
)
from handradar.hand.skeleton import HandSequence
from handradar.radar.config import RadarConfig
from handradar.radar.dca1000 import read_adc
from handradar.radar.signal import doppler_mirror
from handradar.vocab import GESTURES

log = logging.getLogger(__name__)

FORMAT = "handradar.recording/1"
FILES = ("radar.cfg", "adc_data.bin", "leap.jsonl", "meta.json")
META_FIELDS = ("gesture", "subject", "angle_deg", "hands", "occlusion", "repetition")


@dataclass(frozen=True)
class RecordingMeta:
    """meta.json without ``truth``: labels, clock offset and calibration."""

    gesture: str
    subject: str
    angle_deg: float
    hands: int
    occlusion: bool
    repetition: int
    radar_start_us: float
    leap_to_radar: tuple[tuple[float, ...], ...]

    @property
    def label(self) -> int:
        return GESTURES.index(self.gesture)

    def labels(self) -> dict[str, object]:
        """The per-recording label fields stored in the dataset's ``meta`` group."""
        return {k: getattr(self, k) for k in META_FIELDS}

    def to_json(self, truth: dict | None = None) -> dict:
        d = {"format": FORMAT, **asdict(self)}
        d["leap_to_radar"] = [list(r) for r in self.leap_to_radar]
        if truth is not None:
            d["truth"] = truth
        return d


def _require(path: Path, obj: dict, key: str, kinds: tuple[type, ...], what: str) -> object:
    if key not in obj:
        raise FormatError(path, f"missing required field '{key}' ({what})")
    value = obj[key]
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
        raise FormatError(path, f"field '{key}' must be {what}, found {value!r:.60}")
    return value


def _require_number(path: Path, obj: dict, key: str, what: str) -> float:
    value = finite_number(_require(path, obj, key, (int, float), what))
    if value is None:
        raise FormatError(path, f"field '{key}' must be a finite number ({what}), found {obj[key]!r:.60}")
    return value


def parse_meta(obj: object, path: str | Path = "meta.json") -> RecordingMeta:
    """Validate a decoded meta.json; FormatError names the file, the field and what was expected."""
    path = Path(path)
    if not isinstance(obj, dict):
        raise FormatError(path, f"expected a JSON object, found {type(obj).__name__}")
    fmt = obj.get("format")
    if fmt != FORMAT:
        raise FormatError(path, f"'format' must be {FORMAT!r}, found {fmt!r:.60}")
    gesture = _require(path, obj, "gesture", (str,), "a gesture name")
    if gesture not in GESTURES:
        raise FormatError(path, f"unknown gesture {gesture!r:.60}; expected one of {', '.join(GESTURES)}")
    subject = _require(path, obj, "subject", (str, int), "a subject id")
    if isinstance(subject, str) and not subject.strip():
        raise FormatError(path, "field 'subject' must be a non-empty subject id, found ''")
    angle = _require_number(path, obj, "angle_deg", "degrees")
    hands = _require(path, obj, "hands", (int,), "1 or 2")
    if hands not in (1, 2):
        raise FormatError(path, f"field 'hands' must be 1 or 2, found {hands!r:.40}")
    occlusion = _require(path, obj, "occlusion", (bool,), "true or false")
    repetition = _require(path, obj, "repetition", (int,), "an integer")
    if not -2**62 < repetition < 2**62:  # stored as int64 in datasets
        raise FormatError(path, f"field 'repetition' is out of range: expected |repetition| < 2**62, found an "
                                f"integer of {repetition.bit_length()} bits")
    start = _require_number(path, obj, "radar_start_us", "microseconds on the Leap clock")
    m = leap_matrix(_require(path, obj, "leap_to_radar", (list,), "a 4x4 row-major matrix"), path)
    return RecordingMeta(gesture=str(gesture), subject=str(subject), angle_deg=angle, hands=int(hands),
                         occlusion=bool(occlusion), repetition=int(repetition), radar_start_us=start,
                         leap_to_radar=tuple(tuple(float(v) for v in row) for row in m))


def _read_json(path: Path) -> object:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise FormatError(path, f"cannot read: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise FormatError(path, "not UTF-8 text") from None
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"invalid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
    except ValueError as exc:  # e.g. an integer literal beyond Python's 4300-digit conversion limit
        raise FormatError(path, f"invalid JSON ({exc})") from None
    except RecursionError:
        raise FormatError(path, "JSON nested too deeply") from None


def read_meta(folder: str | Path) -> RecordingMeta:
    path = Path(folder) / "meta.json"
    return parse_meta(_read_json(path), path)


def read_truth(folder: str | Path) -> dict | None:
    """The generator's ``truth`` object: for evaluation code only, never for diagnosis or training."""
    obj = _read_json(Path(folder) / "meta.json")
    return obj.get("truth") if isinstance(obj, dict) else None


@dataclass
class Recording:
    """A validated recording: radar cube, skeleton on the radar clock and labels."""

    folder: Path
    radar: RadarConfig
    adc: np.ndarray  # (frames, chirps_per_frame, rx, samples) complex64 ADC counts
    skeleton: HandSequence  # radar frame, t = 0 at the start of radar frame 0
    meta: RecordingMeta

    @property
    def name(self) -> str:
        return self.folder.name

    @property
    def n_frames(self) -> int:
        return self.adc.shape[0]

    @property
    def duration_s(self) -> float:
        return self.n_frames * self.radar.frame_period_s


def check_folder(folder: str | Path) -> Path:
    folder = Path(folder)
    if not folder.is_dir():
        what = "a file" if folder.exists() else "no such directory"
        raise FormatError(folder, f"not a recording folder ({what})")
    missing = [f for f in FILES if not (folder / f).is_file()]
    if missing:
        raise FormatError(folder, f"missing file(s) {', '.join(missing)}; a recording holds {', '.join(FILES)}")
    return folder


def read_radar(folder: str | Path) -> RadarConfig:
    """A recording's radar.cfg; a recording must state its capture length (numFrames >= 1).

    numFrames 0 (continuous framing) would let adc_data.bin decide the number of frames, so a
    wrong frame layout or a longer capture could not be told from a Leap file that is too short.
    """
    path = Path(folder) / "radar.cfg"
    radar = RadarConfig.from_file(path)
    if radar.n_frames == 0:
        raise FormatError(path, "frameCfg numFrames is 0 (continuous framing); a recording's radar.cfg must give "
                                "the number of frames captured (expected >= 1), which adc_data.bin is checked against")
    return radar


def load_recording(folder: str | Path, *, coverage_tolerance_s: float = 0.05,
                   allow_truncated: bool = False, iq_swap: bool = False, doppler_flip: bool = False) -> Recording:
    """Load and validate one recording folder.

    The Leap data must cover the radar capture (first sample at most ``coverage_tolerance_s``
    after radar frame 0 starts, last at most that long before the capture ends), and the hands
    meta.json announces must be tracked somewhere in the capture. iq_swap, doppler_flip: read a
    capture that the sign-convention check (handradar.data.convention) finds mirrored.
    """
    folder = check_folder(folder)
    radar = read_radar(folder)  # first: the Leap coverage check below measures against its capture length
    meta = read_meta(folder)
    # the small files first: a bad leap.jsonl is found before megabytes of ADC are read
    skeleton = read_leap_jsonl(folder / "leap.jsonl", np.asarray(meta.leap_to_radar), meta.radar_start_us)
    check_hand_geometry(skeleton, folder / "leap.jsonl")
    adc = read_adc(folder / "adc_data.bin", radar, allow_truncated=allow_truncated, iq_swap=iq_swap)
    if doppler_flip:  # range bins right, Doppler mirrored (a down-chirp, a conjugated carrier)
        adc = doppler_mirror(adc)
    end = adc.shape[0] * radar.frame_period_s
    t0, t1 = float(skeleton.times[0]), float(skeleton.times[-1])
    if t0 > coverage_tolerance_s or t1 < end - coverage_tolerance_s:
        raise FormatError(folder / "leap.jsonl",
                          f"Leap data cover {t0:.3f}..{t1:.3f} s of the radar clock, but the capture spans "
                          f"0..{end:.3f} s ({adc.shape[0]} frames of {radar.frame_period_s * 1e3:g} ms); "
                          "check radar_start_us in meta.json")
    inside = (skeleton.times >= 0) & (skeleton.times <= end)
    n_tracked = int(skeleton.mask[inside].any(axis=0).sum())
    if n_tracked < meta.hands:
        raise FormatError(folder / "leap.jsonl", f"meta.json says {meta.hands} hand(s) but {n_tracked} "
                                                 "are tracked during the capture")
    return Recording(folder=folder, radar=radar, adc=adc, skeleton=skeleton, meta=meta)


@dataclass
class Scan:
    """What :func:`scan` found under a root: recording folders, and what it could not search."""

    recordings: list[Path]  # folders holding a meta.json, sorted
    meta_less: list[Path]  # folders holding other recording files but no meta.json, sorted
    unreadable: list[tuple[Path, str]]  # folders that could not be listed, with the OS reason
    repeats: list[tuple[Path, Path, int]]  # (a folder reached again through a symbolic link, where it was
    # first found, the recordings found there): searched once, so its recordings are not counted twice


def check_root(root: str | Path) -> Path:
    """``root`` as a Path; FormatError when it is missing or not a folder (a file says so)."""
    root = Path(root)
    if root.is_dir():
        return root
    if root.exists():
        raise FormatError(root, "is a file, not a directory; give the folder that holds the recording folders")
    raise FormatError(root, "no such directory")


def scan(root: str | Path) -> Scan:
    """Search ``root`` for recording folders, following symbolic links (each folder searched once).

    A folder reached a second time (two links to it, or a link back to a folder above: a loop) is
    not searched again; where it holds recordings and is not a loop it is listed in ``repeats``. A
    folder that cannot be listed (permissions, I/O error) is listed in ``unreadable`` with the
    reason; the search goes on. Links whose target is missing are ignored (a recording file behind
    one is reported missing by :func:`check_folder`).
    """
    root = check_root(root)
    seen: dict[tuple[int, int], Path] = {}
    found: dict[Path, set[str]] = {}
    unreadable: list[tuple[Path, str]] = []
    again: list[tuple[Path, Path]] = []
    stack = [root]
    while stack:
        folder = stack.pop()
        try:
            st = folder.stat()
            key = (st.st_dev, st.st_ino)
            if key in seen:
                again.append((folder, seen[key]))
                continue
            seen[key] = folder
            with os.scandir(folder) as it:
                entries = sorted(it, key=lambda e: e.name)
        except OSError as exc:
            if folder == root:
                raise FormatError(root, f"cannot read the folder: {exc.strerror or exc}") from None
            unreadable.append((folder, exc.strerror or str(exc)))
            continue
        subfolders, files = [], set()
        for entry in entries:
            with contextlib.suppress(OSError):  # a link that cannot be followed counts as neither
                if entry.is_dir():  # follows links
                    subfolders.append(folder / entry.name)
                elif entry.name in FILES and entry.is_file():
                    files.add(entry.name)
        if files:
            found[folder] = files
        stack.extend(reversed(subfolders))  # depth first, in name order
    repeats = []
    for folder, first in again:
        if first in folder.parents:  # a loop: the link leads back above itself
            log.warning("%s: a symbolic link back to %s, which holds it; not searched again", folder, first)
            continue
        n = sum(1 for f, names in found.items() if "meta.json" in names and (f == first or first in f.parents))
        if n:
            repeats.append((folder, first, n))
    return Scan(recordings=sorted(f for f, names in found.items() if "meta.json" in names),
                meta_less=sorted(f for f, names in found.items() if "meta.json" not in names),
                unreadable=unreadable, repeats=repeats)


def find_recordings(root: str | Path) -> list[Path]:
    """Recording folders under ``root`` (any folder holding a meta.json), sorted; links followed (:func:`scan`)."""
    return scan(root).recordings


def find_meta_less_folders(root: str | Path) -> list[Path]:
    """Folders under ``root`` holding recording files (radar.cfg, adc_data.bin, leap.jsonl) but no meta.json, sorted.

    :func:`find_recordings` does not see them; ingest reports them as skipped.
    """
    return scan(root).meta_less


def write_meta(folder: str | Path, meta: RecordingMeta, truth: dict | None = None) -> None:
    atomic_write_text(Path(folder) / "meta.json", json.dumps(meta.to_json(truth), indent=1) + "\n")
