"""The data quality gate: per-recording measurements and a verdict (docs/datasets.md, "Quality gate").

Well-formed files can still hold data that cannot carry a gesture. Each check measures one figure
of a recording and compares it with a threshold chosen from a physical reason (the constants
below); the verdict is

- ``skip``: the recording cannot carry a gesture (a dead or clipped capture, tracking mostly
  missing or corrupt, the hand outside the radar's view, impossible metadata); ingest skips it
  by name with the figure;
- ``warn``: doubtful (a gap, a few outlier frames, a duplicate, metadata at odds with the data);
  kept, named in the report and flagged in the dataset's per-row ``quality`` fields;
- ``ok``.

Outlier frames (joints jumping faster than a hand moves, or leaving the plausible volume) are
dropped; each is re-interpolated from the nearest good frames of its hand where those lie at most
MAX_INTERP_GAP_S apart, and marked untracked otherwise. Skeleton steps between two Leap samples
more than MAX_INTERP_GAP_S apart are marked untracked too (resampling alone bridged any hole).
A recording without outliers or long gaps keeps its skeleton untouched.

Pure functions measure (``adc_figures``, ``find_outliers``, ``window_figures``, ...); two thin
wrappers, :func:`gate_capture` and :func:`gate_window`, run them on a loaded recording.
"""

from __future__ import annotations

import filecmp
import hashlib
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from handradar.data.examples import Example
from handradar.data.recording import Recording, RecordingMeta
from handradar.hand.leap import HAND_LENGTH_RANGE_M, MAX_HAND_DISTANCE_M
from handradar.hand.skeleton import HandSequence
from handradar.radar.chain import ChainConfig

# ---- thresholds (docs/datasets.md, "Quality gate", gives each reason at more length) ------------
# Clipping: a many-reflector IF signal is near Gaussian; cutting the 0.1 % of its samples at the rails
# leaves distortion 39 dB below the signal, 1 % leaves -27 dB, above the chain's 30 dB dynamic range.
CLIPPED_WARN_SHARE = 0.001
CLIPPED_SKIP_SHARE = 0.01
# The RX channels of one chip share the LO and their antennas' gains agree within a few dB.
DEAD_RX_DB = 20.0
# Hand and finger speeds stay below ~5 m/s in gestures (a boxer's punch reaches ~10); Leap's own
# error is ~1 mm, so 1 cm on top absorbs jitter between frames that are close in time.
MAX_JOINT_SPEED_M_S = 10.0
JUMP_TOLERANCE_M = 0.01
# Leap's own glitches are rare; a tenth of the frames impossible is a corrupt stream, not noise.
MAX_OUTLIER_SHARE = 0.10
# Two STFT columns of the default chain (50 ms each): a longer hole would invent whole columns' motion.
MAX_INTERP_GAP_S = 0.1
# Two Leap samples per 50 ms STFT column; below it the motion inside a column is interpolated, not measured.
MIN_LEAP_RATE_HZ = 40.0
# Less than half the window tracked: most of the row's columns have no measured skeleton.
MIN_COVERAGE = 0.5
# Leap dropouts (the world models 3 % of frames in short bursts) leave ~96 %; below 90 %, 3+ columns lack a hand.
WARN_COVERAGE = 0.9
# A hand counts as present when tracked over at least half the window.
HAND_PRESENT_SHARE = 0.5
# Patch antennas with a +-30 deg half-power beam: 60 deg off boresight the two-way gain is ~25 dB down.
BEAM_HALF_ANGLE_DEG = 60.0
MAX_OUT_OF_VIEW = 0.5  # "most of the window"
WARN_OUT_OF_VIEW = 0.1  # three of the 32 columns
MAX_ANGLE_DEG = 180.0  # angle_deg is a direction: -180..180
# A Leap-to-radar calibration is a rotation times a unit scale: equal singular values, determinant > 0.
CALIBRATION_SCALE_SPREAD = 0.05

THRESHOLDS = {
    "clipped_warn_share": CLIPPED_WARN_SHARE, "clipped_skip_share": CLIPPED_SKIP_SHARE, "dead_rx_db": DEAD_RX_DB,
    "max_joint_speed_m_s": MAX_JOINT_SPEED_M_S, "jump_tolerance_m": JUMP_TOLERANCE_M,
    "max_hand_distance_m": MAX_HAND_DISTANCE_M, "hand_length_range_m": list(HAND_LENGTH_RANGE_M),
    "max_outlier_share": MAX_OUTLIER_SHARE, "max_interp_gap_s": MAX_INTERP_GAP_S,
    "min_leap_rate_hz": MIN_LEAP_RATE_HZ, "min_coverage": MIN_COVERAGE, "warn_coverage": WARN_COVERAGE,
    "hand_present_share": HAND_PRESENT_SHARE, "beam_half_angle_deg": BEAM_HALF_ANGLE_DEG,
    "max_out_of_view": MAX_OUT_OF_VIEW, "warn_out_of_view": WARN_OUT_OF_VIEW, "max_angle_deg": MAX_ANGLE_DEG,
    "calibration_scale_spread": CALIBRATION_SCALE_SPREAD,
}
LEVELS = ("ok", "warn", "skip")
_SUBSAMPLE = 8  # every 8th chirp for the channel powers: a power ratio needs far fewer samples than a cube


@dataclass(frozen=True)
class Finding:
    """One check's result: ``level`` warn or skip, the recording ``file`` it concerns, a one-line message."""

    check: str
    level: str
    file: str
    message: str


@dataclass
class RecordingQuality:
    """The figures measured on one recording and the findings they led to."""

    figures: dict[str, object] = field(default_factory=dict)
    findings: list[Finding] = field(default_factory=list)

    def add(self, check: str, level: str, file: str, message: str) -> None:
        self.findings.append(Finding(check, level, file, message))

    @property
    def verdict(self) -> str:
        return max((f.level for f in self.findings), key=LEVELS.index, default="ok")

    def first_skip(self) -> Finding | None:
        return next((f for f in self.findings if f.level == "skip"), None)

    def row_fields(self) -> dict[str, object]:
        """The per-row fields stored in the dataset's ``quality`` group (NaN where not measured)."""
        f = self.figures
        return {
            "verdict": self.verdict,
            "warnings": ",".join(dict.fromkeys(x.check for x in self.findings)),
            "coverage": float(f.get("coverage", math.nan)),
            "longest_gap_s": float(f.get("longest_gap_s", math.nan)),
            "leap_rate_hz": float(f.get("leap_rate_hz", math.nan)),
            "outlier_frames": int(f.get("outlier_frames", 0)),
            "clipped_share": float(f.get("clipped_share", math.nan)),
            "out_of_view": float(f.get("out_of_view", math.nan)),
            "hands_seen": int(f.get("hands_seen", 0)),
            "duplicate_of": str(f.get("duplicate_of", "")),
        }

    def to_json(self) -> dict:
        return {"verdict": self.verdict, "figures": {k: _plain(v) for k, v in self.figures.items()},
                "findings": [{"check": x.check, "level": x.level, "file": x.file, "message": x.message}
                             for x in self.findings]}


def _plain(v: object) -> object:
    """A JSON-ready figure: numpy scalars and arrays as Python values, NaN as None."""
    if isinstance(v, np.ndarray):
        return [_plain(x) for x in v.tolist()]
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, (np.integer, np.bool_)):
        return v.item()
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    return v


# ---- ADC ---------------------------------------------------------------------------------------
def adc_figures(adc: np.ndarray, adc_bits: int = 16) -> dict[str, object]:
    """Figures of a (frames, chirps, rx, samples) complex cube of ADC counts.

    all_zero; constant_rx: the RX channels (0-based) whose I or Q never changes, with their values;
    clipped_share: share of I and Q values at the ADC's limits (|x| >= 2^(bits-1) - 1, so that a
    Doppler-mirrored cube counts its negated rails too); rx_power_db: each channel's power (its mean
    removed, every 8th chirp) against the median channel's, dB.
    """
    adc = np.ascontiguousarray(adc, dtype=np.complex64)
    values = adc.view(np.float32)  # I and Q interleaved: one contiguous pass each for min and max
    lo, hi = float(values.min()), float(values.max())
    rail = float(2 ** (adc_bits - 1) - 1)
    clipped = 0
    if hi >= rail or lo <= -rail:  # counted only where a rail is reached
        clipped = int(np.count_nonzero(np.abs(values) >= rail))
    sub = adc[:, ::_SUBSAMPLE]
    axes = (0, 1, 3)
    var_i, var_q = sub.real.var(axis=axes, dtype=np.float64), sub.imag.var(axis=axes, dtype=np.float64)
    constant = []
    for rx in np.flatnonzero((var_i == 0) | (var_q == 0)):
        ch = adc[:, :, rx]  # confirmed on the whole channel
        if ch.real.min() == ch.real.max() or ch.imag.min() == ch.imag.max():
            constant.append((int(rx), complex(ch.flat[0])))
    power = var_i + var_q  # the channel's mean removed
    med = float(np.median(power))
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = 10 * np.log10(power / med) if med > 0 else np.where(power > 0, np.inf, 0.0)
    return {"all_zero": lo == hi == 0.0, "constant_rx": constant, "clipped_share": clipped / (2 * adc.size),
            "rx_power_db": [float(x) for x in rel], "adc_min": lo, "adc_max": hi}


def _counts(z: complex) -> str:
    return f"I = {z.real:+.0f}, Q = {z.imag:+.0f}"


def adc_findings(fig: dict, q: RecordingQuality, file: str = "adc_data.bin") -> None:
    """Add the findings of :func:`adc_figures` to ``q``."""
    n_rx = len(fig["rx_power_db"])
    if fig["all_zero"]:
        q.add("adc_dead", "skip", file, "every I and Q sample is 0: the capture holds no signal")
        return
    constant = fig["constant_rx"]
    if len(constant) == n_rx:
        values = sorted({_counts(z) for _, z in constant})
        q.add("adc_dead", "skip", file, f"every RX channel is constant ({'; '.join(values)} throughout, "
                                        f"{fig['clipped_share']:.0%} of the values at the ADC limits): the capture "
                                        "holds no signal")
        return
    share = fig["clipped_share"]
    if share > CLIPPED_WARN_SHARE:
        level = "skip" if share > CLIPPED_SKIP_SHARE else "warn"
        limit = CLIPPED_SKIP_SHARE if level == "skip" else CLIPPED_WARN_SHARE
        q.add("adc_clipped", level, file, f"{share:.2%} of the I and Q values sit at the ADC limits (clipped; "
                                          f"{'skipped above' if level == 'skip' else 'warned above'} {limit:.1%}): "
                                          "lower the RX gain")
    dead = [rx for rx, _ in constant]
    dead += [rx for rx, db in enumerate(fig["rx_power_db"]) if db < -DEAD_RX_DB and rx not in dead]
    for rx in sorted(dead):
        db = fig["rx_power_db"][rx]
        q.add("adc_dead_rx", "warn", file, f"RX{rx + 1} is dead ({db:.0f} dB against the median channel; "
                                           f"threshold -{DEAD_RX_DB:.0f} dB)")


# ---- meta.json ---------------------------------------------------------------------------------
def meta_findings(meta: RecordingMeta, q: RecordingQuality, file: str = "meta.json") -> None:
    """The angle label and the calibration's geometry: impossible values skip the recording."""
    if not abs(meta.angle_deg) <= MAX_ANGLE_DEG:
        q.add("meta_angle", "skip", file, f"angle_deg {meta.angle_deg:.6g} is not a direction: expected "
                                          f"-{MAX_ANGLE_DEG:.0f}..{MAX_ANGLE_DEG:.0f} degrees")
    m = np.asarray(meta.leap_to_radar, dtype=np.float64)[:3, :3]
    det = float(np.linalg.det(m))
    s = np.linalg.svd(m, compute_uv=False)
    q.figures["calibration_det"] = det
    if det < 0:
        q.add("calibration", "skip", file, f"leap_to_radar mirrors space (its 3x3 part has determinant {det:.3g} < 0, "
                                           "which no mounting gives): one axis has the wrong sign")
    elif s[0] / s[-1] - 1 > CALIBRATION_SCALE_SPREAD:
        q.add("calibration", "skip", file, f"leap_to_radar is not a rotation times a scale: its singular values "
                                           f"differ by {s[0] / s[-1] - 1:.0%} (expected equal within "
                                           f"{CALIBRATION_SCALE_SPREAD:.0%})")


# ---- tracking ----------------------------------------------------------------------------------
def leap_rate_hz(times: np.ndarray) -> float:
    """Leap frame rate (Hz) from the median interval between frames."""
    return float(1.0 / np.median(np.diff(times)))


def _sq(v: np.ndarray) -> np.ndarray:
    """Squared length along the last axis (float64): compared with squared limits, no square root."""
    return np.einsum("...k,...k->...", v, v, dtype=np.float64)


def _volume_outliers(positions: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, float]:
    """((T, 2) tracked hands outside the plausible volume or not hand-shaped, median farthest joint of
    those hands in metres (NaN if none))."""
    p = positions[mask]  # (tracked hands, 21, 3)
    dist2 = _sq(p).max(-1)
    length2 = _sq(p - p[:, :1]).max(-1)
    lo, hi = HAND_LENGTH_RANGE_M
    bad = (dist2 > MAX_HAND_DISTANCE_M ** 2) | (length2 < lo ** 2) | (length2 > hi ** 2)
    out = np.zeros(mask.shape, dtype=bool)
    out[mask] = bad
    return out, float(np.sqrt(np.median(dist2[bad]))) if bad.any() else math.nan


def _jump_outliers(positions: np.ndarray, times: np.ndarray, good: np.ndarray) -> np.ndarray:
    """(T,) frames of one hand whose joints moved faster than MAX_JOINT_SPEED_M_S from the last good frame.

    positions (T, 21, 3) metres, good (T,) frames to consider. The walk starts at the frame nearest
    the median hand centre (most frames are good) and goes both ways, each frame judged against the
    last one kept, so that a jump out and back flags the frames out there, not the ones after it.
    """
    idx = np.flatnonzero(good)
    out = np.zeros(len(times), dtype=bool)
    if len(idx) < 2:
        return out
    step2 = _sq(np.diff(positions[idx], axis=0)).max(-1)
    if np.all(step2 <= (MAX_JOINT_SPEED_M_S * np.diff(times[idx]) + JUMP_TOLERANCE_M) ** 2):
        return out  # the common case: no jump between neighbours, no walk
    positions = positions.astype(np.float64)
    centre = positions[idx].mean(1)
    start = int(np.argmin(np.linalg.norm(centre - np.median(centre, axis=0), axis=-1)))
    for order in (idx[start + 1:], idx[:start][::-1]):
        last = idx[start]
        for k in order:
            moved = float(np.linalg.norm(positions[k] - positions[last], axis=-1).max())
            if moved > MAX_JOINT_SPEED_M_S * abs(times[k] - times[last]) + JUMP_TOLERANCE_M:
                out[k] = True
            else:
                last = k
    return out


def find_outliers(seq: HandSequence) -> tuple[np.ndarray, np.ndarray, float]:
    """((T, 2) hands outside the plausible volume, (T, 2) hands that jumped, median farthest joint of
    the volume outliers in metres (NaN if none)) of a radar-frame sequence."""
    volume, far = _volume_outliers(seq.positions, seq.mask)
    jump = np.stack([_jump_outliers(seq.positions[:, h], seq.times, seq.mask[:, h] & ~volume[:, h])
                     for h in range(2)], axis=1)
    return volume, jump, far


def drop_outliers(seq: HandSequence, outliers: np.ndarray,
                  max_gap_s: float = MAX_INTERP_GAP_S) -> tuple[HandSequence, int]:
    """(``seq`` with each outlier re-interpolated from the nearest good frames of its hand where they lie
    at most ``max_gap_s`` apart, else marked untracked; the number re-interpolated). ``seq`` itself if
    there is no outlier."""
    if not outliers.any():
        return seq, 0
    pos, mask, t = seq.positions.copy(), seq.mask.copy(), seq.times
    n_interp = 0
    for h in range(2):
        bad = np.flatnonzero(outliers[:, h])
        good = np.flatnonzero(seq.mask[:, h] & ~outliers[:, h])
        if not len(bad):
            continue
        ok = np.zeros(len(bad), dtype=bool)
        if len(good):
            nxt = np.searchsorted(good, bad)
            lo, hi = good[np.clip(nxt - 1, 0, len(good) - 1)], good[np.clip(nxt, 0, len(good) - 1)]
            ok = (nxt > 0) & (nxt < len(good)) & (t[hi] - t[lo] <= max_gap_s)
            frac = ((t[bad] - t[lo]) / np.where(ok, t[hi] - t[lo], 1.0)).astype(np.float32)[:, None, None]
            pos[bad[ok], h] = (pos[lo, h] * (1 - frac) + pos[hi, h] * frac)[ok]
        mask[bad[~ok], h] = False
        n_interp += int(ok.sum())
    return HandSequence(pos, t, mask, source=seq.source, attrs=dict(seq.attrs)), n_interp


def long_gap_steps(sample_times: np.ndarray, at: np.ndarray, max_gap_s: float = MAX_INTERP_GAP_S) -> np.ndarray:
    """(len(at),) True where the Leap samples bracketing time ``at`` lie more than ``max_gap_s`` apart.

    Brackets as :func:`handradar.hand.skeleton.interpolate` takes them (clamped at the ends; a time
    exactly on a sample is that sample's own)."""
    t = np.clip(at, sample_times[0], sample_times[-1])
    hi = np.clip(np.searchsorted(sample_times, t, side="right"), 1, len(sample_times) - 1)
    lo = hi - 1
    return (sample_times[hi] - sample_times[lo] > max_gap_s) & (t != sample_times[lo])


def longest_gap_s(seq: HandSequence, t0: float, t1: float) -> float:
    """The longest stretch of [t0, t1] (s) without a Leap sample that tracks a hand."""
    tracked = seq.times[seq.mask.any(axis=1)]
    edges = np.clip(np.concatenate(([-np.inf], tracked, [np.inf])), t0, t1)
    return float(np.diff(edges).max())


def view_outside(positions: np.ndarray, mask: np.ndarray, gate_m: tuple[float, float]) -> np.ndarray:
    """(T, 2) tracked hands whose joint centre lies more than BEAM_HALF_ANGLE_DEG off boresight (+z) or
    outside the chain's range gate: the radar does not see them."""
    centre = positions.astype(np.float64).mean(axis=2)
    r = np.linalg.norm(centre, axis=-1)
    cos = centre[..., 2] / np.maximum(r, 1e-12)
    return mask & ((cos < math.cos(math.radians(BEAM_HALF_ANGLE_DEG))) | (r < gate_m[0]) | (r > gate_m[1]))


def window_figures(seq: HandSequence, window: HandSequence, t0: float, t1: float,
                   gate_m: tuple[float, float]) -> dict[str, object]:
    """coverage (share of the window's skeleton steps with a tracked hand), longest_gap_s, per-hand
    tracked shares (right, left), hands_seen, out_of_view (share of tracked hand steps the radar does not
    see); ``seq`` the recording's cleaned skeleton, ``window`` the row's, [t0, t1) its span in seconds."""
    share = window.mask.mean(axis=0)
    out = view_outside(window.positions, window.mask, gate_m)
    n = int(window.mask.sum())
    return {"coverage": float(window.mask.any(axis=1).mean()), "longest_gap_s": longest_gap_s(seq, t0, t1),
            "hand_share": [float(x) for x in share], "hands_seen": int((share >= HAND_PRESENT_SHARE).sum()),
            "out_of_view": float(out.sum() / n) if n else math.nan}


def tracking_findings(fig: dict, meta_hands: int, q: RecordingQuality, file: str = "leap.jsonl") -> None:
    """The findings of the window figures (coverage, gaps, view, hand count)."""
    where = (f"longest gap {fig['longest_gap_s']:.2f} s, Leap rate {fig['leap_rate_hz']:.3g} Hz; "
             f"gaps over {MAX_INTERP_GAP_S:g} s count as untracked")
    cov = fig["coverage"]
    if cov < MIN_COVERAGE:
        q.add("coverage", "skip", file, f"tracked hands cover {cov:.0%} of the spectrogram window ({where}); "
                                        f"expected at least {MIN_COVERAGE:.0%}: tracking mostly missing")
    elif cov < WARN_COVERAGE:
        q.add("coverage", "warn", file, f"tracked hands cover {cov:.0%} of the spectrogram window ({where}; "
                                        f"warned below {WARN_COVERAGE:.0%})")
    if fig["longest_gap_s"] > MAX_INTERP_GAP_S and cov >= MIN_COVERAGE:
        q.add("gap", "warn", file, f"a {fig['longest_gap_s']:.3f} s gap in tracking inside the window (over the "
                                   f"{MAX_INTERP_GAP_S:g} s that interpolation bridges): untracked in the row")
    out = fig["out_of_view"]
    if out > MAX_OUT_OF_VIEW or out > WARN_OUT_OF_VIEW:
        level = "skip" if out > MAX_OUT_OF_VIEW else "warn"
        q.add("out_of_view", level, file, f"the hand is outside the radar's view for {out:.0%} of the tracked window "
                                          f"(more than {BEAM_HALF_ANGLE_DEG:.0f} deg off boresight or outside the range "
                                          f"gate; {'skipped above' if level == 'skip' else 'warned above'} "
                                          f"{MAX_OUT_OF_VIEW if level == 'skip' else WARN_OUT_OF_VIEW:.0%})")
    seen = fig["hands_seen"]
    if seen != meta_hands and cov >= MIN_COVERAGE:
        shares = ", ".join(f"{k} {s:.0%}" for k, s in zip(("right", "left"), fig["hand_share"]))
        q.add("hands", "warn", "meta.json", f"meta.json says {meta_hands} hand(s) but leap.jsonl tracks {seen} over at "
                                            f"least {HAND_PRESENT_SHARE:.0%} of the window ({shares})")


# ---- duplicates --------------------------------------------------------------------------------
def adc_fingerprint(adc: np.ndarray) -> bytes:
    """A cheap key of a capture: its shape and a hash of ~8k evenly spaced samples (equal cubes, equal
    keys; a match is confirmed on the files' bytes)."""
    flat = np.asarray(adc).reshape(-1)
    sample = np.ascontiguousarray(flat[::max(1, flat.size // 8192)])
    return hashlib.sha1(repr(adc.shape).encode() + sample.tobytes()).digest()


def leap_fingerprint(seq: HandSequence) -> bytes:
    """A hash of the tracked joints and mask: the same Leap data gives the same key."""
    h = hashlib.sha1(np.ascontiguousarray(seq.positions))
    h.update(np.ascontiguousarray(seq.mask))
    return h.digest()


@dataclass
class DuplicateIndex:
    """The content keys of the recordings kept so far, to name the first holder of each."""

    adc: dict[bytes, list[tuple[str, Path]]] = field(default_factory=dict)
    leap: dict[bytes, str] = field(default_factory=dict)

    def find(self, folder: Path, adc_key: bytes, leap_key: bytes) -> dict[str, str]:
        """{file name: first recording holding the same content} for ``folder``'s ADC and Leap data."""
        out = {}
        for name, other in self.adc.get(adc_key, []):
            if filecmp.cmp(folder / "adc_data.bin", other / "adc_data.bin", shallow=False):
                out["adc_data.bin"] = name
                break
        if leap_key in self.leap:
            out["leap.jsonl"] = self.leap[leap_key]
        return out

    def add(self, name: str, folder: Path, adc_key: bytes, leap_key: bytes) -> None:
        self.adc.setdefault(adc_key, []).append((name, folder))
        self.leap.setdefault(leap_key, name)


def duplicate_findings(same: dict[str, str], q: RecordingQuality) -> None:
    if not same:
        return
    first = sorted(set(same.values()))
    q.figures["duplicate_of"] = first[0]
    files = " and ".join(sorted(same))
    q.add("duplicate", "warn", sorted(same)[0], f"same {files} content as {', '.join(first)} (kept; copies leak across "
                                                "train/test splits: the dataset's quality/duplicate_of names the first)")


# ---- the gate on a loaded recording ----------------------------------------------------------
def gate_capture(rec: Recording) -> tuple[RecordingQuality, Recording]:
    """The checks that need no spectrogram window: ADC, metadata, Leap rate, outliers, extra hands.

    Returns the findings and the recording with its outlier frames dropped (``rec`` itself if none)."""
    q = RecordingQuality()
    fig = adc_figures(rec.adc, rec.radar.adc_bits)
    q.figures.update(clipped_share=fig["clipped_share"], rx_power_db=fig["rx_power_db"])
    adc_findings(fig, q)
    meta_findings(rec.meta, q)
    seq = rec.skeleton
    q.figures["leap_rate_hz"] = rate = leap_rate_hz(seq.times)
    if rate < MIN_LEAP_RATE_HZ:
        q.add("leap_rate", "warn", "leap.jsonl", f"Leap frames come at {rate:.3g} Hz (median interval); expected at "
                                                 f"least {MIN_LEAP_RATE_HZ:g} Hz, two per 50 ms STFT column")
    volume, jump, far = find_outliers(seq)
    outliers = volume | jump
    n_out, n_tracked = int(outliers.sum()), int(seq.mask.sum())
    cleaned, n_interp = drop_outliers(seq, outliers)
    q.figures.update(outlier_frames=n_out, outliers_interpolated=n_interp, tracked_hand_frames=n_tracked)
    if n_out:
        what = ", ".join(x for x in (
            f"{int(volume.sum())} outside the plausible volume or not hand-shaped"
            + (f" (farthest joint {far:.3g} m from the radar, median)" if math.isfinite(far) else ""),
            f"{int(jump.sum())} jumping faster than {MAX_JOINT_SPEED_M_S:g} m/s") if not x.startswith("0 "))
        share = n_out / max(n_tracked, 1)
        if share > MAX_OUTLIER_SHARE:
            q.add("outliers", "skip", "leap.jsonl", f"{n_out} of {n_tracked} tracked hand frames ({share:.0%}) are "
                                                    f"outliers: {what}; expected at most {MAX_OUTLIER_SHARE:.0%}: the "
                                                    "tracking stream is corrupt")
        else:
            q.add("outliers", "warn", "leap.jsonl", f"{n_out} outlier hand frames dropped ({what}); {n_interp} "
                                                    f"re-interpolated, {n_out - n_interp} left untracked")
    extra = int(seq.attrs.get("extra_hands", 0))
    q.figures["extra_hands"] = extra
    if extra:
        q.add("extra_hands", "warn", "leap.jsonl", f"{extra} hand(s) beyond one right and one left hand in "
                                                   f"{seq.attrs.get('extra_hand_frames', 0)} frames were dropped (only "
                                                   "the first hand of each side is kept)")
    return q, (rec if cleaned is seq else replace(rec, skeleton=cleaned))


def gate_window(rec: Recording, ex: Example, chain: ChainConfig, q: RecordingQuality) -> Example:
    """The checks of the row's window (coverage, gaps, view, hand count); returns ``ex`` with the skeleton
    steps inside long Leap gaps marked untracked (``ex`` itself if there are none). ``rec``: the recording
    as :func:`gate_capture` returned it."""
    seq, window = rec.skeleton, ex.skeleton
    long = long_gap_steps(seq.times, ex.window_start_s + window.times)
    if long.any():
        mask = window.mask & ~long[:, None]
        window = HandSequence(window.positions.copy(), window.times, mask, source=window.source, attrs=window.attrs)
        ex = replace(ex, skeleton=window)
    t1 = ex.window_start_s + chain.frames_per_window(rec.radar) * rec.radar.frame_period_s
    fig = window_figures(seq, window, ex.window_start_s, t1, chain.gate_m)
    q.figures.update(fig)
    tracking_findings(q.figures, rec.meta.hands, q)
    return ex


# ---- the report over recordings ----------------------------------------------------------------
@dataclass
class QualityReport:
    """Every gated recording's figures and findings; a console table and JSON."""

    rows: dict[str, RecordingQuality] = field(default_factory=dict)

    def add(self, name: str, q: RecordingQuality) -> None:
        self.rows[name] = q

    def counts(self) -> dict[str, int]:
        out = dict.fromkeys(LEVELS, 0)
        for q in self.rows.values():
            out[q.verdict] += 1
        return out

    def table(self, limit: int = 40) -> str:
        """A summary line, then one row per warned or skipped recording (its figures, then its findings)."""
        c = self.counts()
        lines = [f"quality gate: {c['ok']} ok, {c['warn']} kept with warnings, {c['skip']} skipped "
                 f"(of {len(self.rows)} checked)"]
        flagged = [(n, q) for n, q in self.rows.items() if q.verdict != "ok"]
        if not flagged:
            return lines[0]
        width = min(max(len(n) for n, _ in flagged), 40)
        lines.append(f"  {'recording':<{width}}  verdict  coverage  gap_s  leap_hz  outliers  clipped  checks")
        for name, q in flagged[:limit]:
            f = q.figures
            lines.append(f"  {name:<{width}}  {q.verdict:<7}  {_pct(f.get('coverage')):>8}  "
                         f"{_num(f.get('longest_gap_s'), '.2f'):>5}  {_num(f.get('leap_rate_hz'), '.3g'):>7}  "
                         f"{f.get('outlier_frames', 0):>8}  {_pct(f.get('clipped_share'), 2):>7}  "
                         f"{','.join(dict.fromkeys(x.check for x in q.findings))}")
            lines.extend(f"    {x.level}: {x.file}: {x.message}" for x in q.findings)
        if len(flagged) > limit:
            lines.append(f"  ... and {len(flagged) - limit} more (all in the dataset's .checks.json)")
        return "\n".join(lines)

    def to_json(self) -> dict:
        return {"thresholds": THRESHOLDS, "counts": self.counts(),
                "recordings": {name: q.to_json() for name, q in self.rows.items()}}


def _pct(x: object, digits: int = 0) -> str:
    return "-" if x is None or not math.isfinite(float(x)) else f"{float(x):.{digits}%}"


def _num(x: object, fmt: str) -> str:
    return "-" if x is None or not math.isfinite(float(x)) else format(float(x), fmt)
