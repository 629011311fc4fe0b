"""Does a capture follow the simulator's sign convention? Checked against the recording's own skeleton.

Every recording pairs radar with a skeleton, so the convention can be read off the data before
anything is fitted (docs/architecture.md, "Sign convention"):

- Doppler: per STFT column, the spectrogram's Doppler centroid (m/s, approaching positive) against
  the tracked joints' mean approach speed -d|r|/dt, correlated per row over the window (uncentred:
  sum c v / sqrt(sum c^2 sum v^2), so that a hand moving at constant speed still shows its sign;
  clutter removal keeps the centroid of a still scene at zero). A strongly negative median means
  the rows are mirrored against the simulator (swapped I/Q, conjugated samples, a down-chirp). The
  lag that maximises it measures a clock offset between Leap and radar.
- Range (raw ADC only: ingest measures it and writes it into the dataset, where a check of the rows
  alone reads it): the hand's energy belongs at positive range bins near the skeleton's range; the
  same energy at the mirrored bins N - b means I and Q are swapped. A swap also mirrors the Doppler,
  but the rows then hold window leakage and noise at the hand's range bins, whose r can fall anywhere
  near 0: the range figure, not r, names the swap.

Thresholds (docs/architecture.md, "Sign convention"): on independent noise one row's r spreads by
about 1 / sqrt(32 columns) = 0.18, so a median of -0.3 over several rows is no accident.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from handradar.radar.chain import ChainConfig, column_times_s, velocity_axis_m_s, window
from handradar.radar.config import RadarConfig

MIRRORED_BELOW_R = -0.3  # median Doppler-centroid r below which the rows are mirrored
MIRRORED_RANGE_DB = 6.0  # hand energy this much stronger at the mirrored range bins: I/Q swapped
LAG_REPORTED_S = 0.075  # a best lag beyond 1.5 STFT columns (50 ms each) is reported as a clock offset
MIN_SPEED_M_S = 0.02  # rows whose hand hardly moves radially (rms) carry no sign (r undefined)
LAG_MIN_R = 0.3  # a clock offset is reported only where the lagged rows agree this well
LAGS_S = np.round(np.arange(-0.3, 0.301, 0.025), 3)


def doppler_centroid(spectrogram: np.ndarray, radar: RadarConfig, chain: ChainConfig) -> np.ndarray:
    """(columns,) power-weighted mean approach speed (m/s) of a (doppler, columns) [0, 1] spectrogram."""
    power = 10.0 ** (chain.dynamic_range_db / 10.0 * (np.asarray(spectrogram, np.float64) - 1.0))
    vel = velocity_axis_m_s(radar, chain)
    return (power * vel[:, None]).sum(0) / power.sum(0)


def speed_track(positions: np.ndarray, mask: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(times, mean -d|r|/dt in m/s) of the tracked joints at the steps where a hand is tracked.

    positions (T, 2, 21, 3) metres, mask (T, 2), times (T,) seconds, increasing."""
    rng = np.linalg.norm(positions, axis=-1)  # (T, 2, 21)
    speed = -np.gradient(rng, times, axis=0)
    tracked = np.repeat(mask[:, :, None], rng.shape[-1], axis=-1)
    tracked[1:-1] &= mask[:-2, :, None] & mask[2:, :, None]  # a hand appearing or vanishing is no motion
    per_step = np.where(tracked, speed, 0.0).sum((1, 2)) / np.maximum(tracked.sum((1, 2)), 1)
    valid = tracked.any((1, 2))
    return times[valid], per_step[valid]


def approach_speed(track: tuple[np.ndarray, np.ndarray], at: np.ndarray) -> np.ndarray:
    """(len(at),) the :func:`speed_track` at times ``at`` (NaN outside it or where it has < 2 steps)."""
    t, v = track
    if len(t) < 2:
        return np.full(len(at), np.nan)
    out = np.interp(at, t, v)
    out[(at < t[0]) | (at > t[-1])] = np.nan
    return out


def lagged_correlations(centroid: np.ndarray, positions: np.ndarray, mask: np.ndarray, times: np.ndarray,
                        column_times: np.ndarray, lags_s: np.ndarray = LAGS_S) -> np.ndarray:
    """(len(lags_s),) uncentred correlation r between the Doppler centroid and the skeleton's approach
    speed ``lag`` seconds later (NaN where fewer than 8 columns overlap or the hand hardly moves)."""
    out = np.full(len(lags_s), np.nan)
    track = speed_track(positions, mask, times)  # once: every lag only interpolates it
    for i, lag in enumerate(lags_s):
        v = approach_speed(track, column_times + lag)
        ok = np.isfinite(v) & np.isfinite(centroid)
        c, v = centroid[ok], v[ok]
        if ok.sum() >= 8 and np.sqrt(np.mean(v ** 2)) >= MIN_SPEED_M_S and np.any(c != 0):
            out[i] = float((c * v).sum() / np.sqrt((c ** 2).sum() * (v ** 2).sum()))
    return out


def range_mirror_db(adc: np.ndarray, radar: RadarConfig, ranges_m: np.ndarray) -> float:
    """Moving energy at the mirrored range bins N - b over that at the bins b of the skeleton's ranges
    (dB; large and positive: I and Q swapped). adc (frames, chirps, rx, samples) complex counts."""
    spec = np.fft.fft(np.asarray(adc) * window("hann", radar.n_samples, dtype=torch.float64).numpy(), axis=-1)
    spec = spec - spec.mean(axis=(0, 1), keepdims=True)  # static clutter out: the moving hand stays
    power = (np.abs(spec) ** 2).sum(axis=(0, 1, 2))  # (samples,)
    n = radar.n_samples
    bins = np.unique(np.rint(np.asarray(ranges_m) / radar.range_resolution_m).astype(int))
    bins = np.unique(np.clip((bins[:, None] + np.arange(-1, 2)).ravel(), 1, n // 2 - 1))
    return float(10 * np.log10((power[n - bins].sum() + 1e-30) / (power[bins].sum() + 1e-30)))


UNDETERMINED = "iq_swap or doppler_flip"  # Doppler mirrored, range bins not measured: the rows cannot say which


@dataclass
class ConventionCheck:
    """Per-row figures and their summary; ``fix()`` names what to change, ``message()`` is what a user reads.

    Two findings, each on its own figure: the range figure (the hand's energy at the mirrored range
    bins, measured by ingest on the raw ADC) says whether I and Q are swapped; the Doppler r says
    whether the Doppler is mirrored. A swap mirrors both, and the rows of a swapped capture hold only
    window leakage and noise at the hand's own range bins, so their r says nothing (rows from -0.6 to
    +0.6 with receiver noise): the range finding decides wherever it is measured. ``iq_swap``, ``doppler_flip``: the
    ingest options the rows were read with (the fix turns the named one over)."""

    rows: list[str] = field(default_factory=list)
    r_by_lag: list[np.ndarray] = field(default_factory=list)  # each (len(LAGS_S),)
    mirror_db: list[float] = field(default_factory=list)  # NaN where no ADC was at hand
    iq_swap: bool = False
    doppler_flip: bool = False

    def add(self, name: str, r_by_lag: np.ndarray, mirror_db: float = math.nan) -> None:
        self.rows.append(name)
        self.r_by_lag.append(np.asarray(r_by_lag, np.float64))
        self.mirror_db.append(float(mirror_db))

    def _lag_medians(self) -> np.ndarray:
        table = np.array(self.r_by_lag).reshape(-1, len(LAGS_S))
        with np.errstate(all="ignore"):
            return np.array([np.nanmedian(c) if np.isfinite(c).any() else np.nan for c in table.T])

    def summary(self) -> dict:
        """median_r (lag 0), n_rows (rows with a defined r), best_lag_s and its median r, median mirror_db
        and n_range_rows (rows whose range figure was measured)."""
        zero = int(np.flatnonzero(LAGS_S == 0)[0])
        r0 = np.array([r[zero] for r in self.r_by_lag]) if self.r_by_lag else np.zeros(0)
        med = self._lag_medians()
        best = int(np.nanargmax(med)) if np.isfinite(med).any() else zero
        mirror = np.array(self.mirror_db)
        finite = mirror[np.isfinite(mirror)]
        return {
            "n_rows": int(np.isfinite(r0).sum()),
            "median_r": float(np.nanmedian(r0)) if np.isfinite(r0).any() else None,
            "best_lag_s": float(LAGS_S[best]),
            "median_r_at_best_lag": float(med[best]) if np.isfinite(med[best]) else None,
            "n_range_rows": int(finite.size),
            "median_range_mirror_db": float(np.median(finite)) if finite.size else None,
        }

    def to_json(self) -> dict:
        """summary(), the reading options, fix() and each row's r (lag 0) and range mirror (dB), None where
        undefined."""
        zero = int(np.flatnonzero(LAGS_S == 0)[0])
        return {**self.summary(), "iq_swap": self.iq_swap, "doppler_flip": self.doppler_flip, "fix": self.fix(),
                "rows": {name: {"r": _finite(r[zero]), "range_mirror_db": _finite(m)}
                         for name, r, m in zip(self.rows, self.r_by_lag, self.mirror_db)}}

    def mirrored(self) -> bool:
        """The Doppler r says the rows are mirrored (whatever the cause: see fix())."""
        s = self.summary()
        return s["median_r"] is not None and s["median_r"] < MIRRORED_BELOW_R

    def iq_swapped(self) -> bool:
        """The range figure says the hand sits at the mirrored range bins: I and Q swapped as read."""
        s = self.summary()
        return s["median_range_mirror_db"] is not None and s["median_range_mirror_db"] > MIRRORED_RANGE_DB

    def fix(self) -> str | None:
        """The ingest option to turn over: "iq_swap" (the hand at mirrored range bins, whatever r says),
        "doppler_flip" (Doppler mirrored, range bins measured right), UNDETERMINED (Doppler mirrored, range
        bins not measured: either may be it), None (nothing found off)."""
        if self.iq_swapped():
            return "iq_swap"
        if self.mirrored():
            return "doppler_flip" if self.summary()["median_range_mirror_db"] is not None else UNDETERMINED
        return None

    def option(self, name: str) -> str:
        """``name=value`` that turns the ingest option ``name`` over from the value the rows were read with."""
        return f"{name}={'false' if getattr(self, name) else 'true'}"

    def message(self) -> str:
        """One line of figures, each finding on its own, then one line per thing to do."""
        s = self.summary()
        doppler = ("Doppler not checked (no row whose hand moves radially)" if s["median_r"] is None else
                   f"Doppler centroid vs skeleton approach speed r = {s['median_r']:+.2f} "
                   f"(median of {s['n_rows']} rows)")
        rng = ("range bins not checked (no range figure: handradar-ingest measures it on the raw ADC)"
               if s["median_range_mirror_db"] is None else
               f"hand energy at mirrored range bins {s['median_range_mirror_db']:+.0f} dB")
        lines = [f"sign convention: {doppler}; {rng}"]
        fix = self.fix()
        if fix == "iq_swap":
            lines.append("  the hand sits at negative range bins: I and Q are swapped (or the samples conjugated), "
                         "and the rows hold leakage, not the hand; re-ingest with " + self.option("iq_swap"))
        elif fix == "doppler_flip":
            lines.append("  the rows are Doppler-mirrored against the simulator (range bins right): a down-chirp or a "
                         "conjugated carrier phase; re-ingest with " + self.option("doppler_flip"))
        elif fix == UNDETERMINED:
            lines.append("  the rows are Doppler-mirrored against the simulator, and without a range figure they "
                         f"cannot tell I/Q swapped ({self.option('iq_swap')}) from a mirrored Doppler with range "
                         f"bins right ({self.option('doppler_flip')}): ingest the recordings again "
                         "(handradar-ingest or data=recordings), whose range check says which")
        elif (s["median_r"] is not None and abs(s["best_lag_s"]) >= LAG_REPORTED_S
                and s["median_r_at_best_lag"] is not None
                and s["median_r_at_best_lag"] >= max(LAG_MIN_R, s["median_r"] + 0.05)):
            lines.append(f"  the skeleton best matches the radar {s['best_lag_s'] * 1e3:+.0f} ms later "
                         f"(r = {s['median_r_at_best_lag']:+.2f}): check radar_start_us in meta.json")
        return "\n".join(lines)


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def check_row(spectrogram: np.ndarray, positions: np.ndarray, mask: np.ndarray, times: np.ndarray,
              radar: RadarConfig, chain: ChainConfig, window_start_s: float = 0.0) -> np.ndarray:
    """r_by_lag of one row: ``times`` on the same clock as ``window_start_s`` (the window's first frame)."""
    cols = column_times_s(radar, chain, chain.frames_per_window(radar)) + window_start_s
    return lagged_correlations(doppler_centroid(spectrogram, radar, chain), positions, mask, times, cols)
