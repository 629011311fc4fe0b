"""RadarConfig: the FMCW chirp/frame set-up parsed from a TI mmWave CLI ``.cfg`` file.

Every derived figure (range resolution, maximum range, v_max, v_res, chirp times) is computed
from the parsed commands; nothing is hard-coded. Units: Hz, seconds, metres.

Command syntax follows the mmWave SDK user guide (as written by the mmWave Demo Visualizer):

- ``channelCfg <rxMask> <txMask> <cascade>``
- ``adcCfg <numADCBits> <adcOutputFmt>``  (bits 0/1/2 = 12/14/16; fmt 0 real, 1 complex1x, 2 complex2x)
- ``profileCfg <id> <startFreqGHz> <idleUs> <adcStartUs> <rampEndUs> <txOutPower> <txPhaseShifter>
  <slopeMHzPerUs> <txStartUs> <numAdcSamples> <sampleRateKsps> <hpf1> <hpf2> <rxGainDb>``
- ``chirpCfg <startIdx> <endIdx> <profileId> <startFreqVar> <slopeVar> <idleVar> <adcStartVar> <txMask>``
- ``frameCfg <chirpStartIdx> <chirpEndIdx> <numLoops> <numFrames> <periodMs> <trigger> <delayMs>``
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from handradar.errors import FormatError

SPEED_OF_LIGHT_M_S = 299_792_458.0

MANDATORY_COMMANDS = ("channelCfg", "adcCfg", "profileCfg", "chirpCfg", "frameCfg")
_ARITY = {"channelCfg": 3, "adcCfg": 2, "profileCfg": 14, "chirpCfg": 8, "frameCfg": 7}


def _bits(mask: int) -> tuple[int, ...]:
    """Indices of the set bits of ``mask``, lowest first."""
    return tuple(i for i in range(mask.bit_length()) if mask >> i & 1)


@dataclass(frozen=True)
class RadarConfig:
    """One-profile FMCW radar set-up (TDM-MIMO chirps allowed).

    Attributes are the raw command values in SI units; derived figures are properties.
    """

    start_freq_hz: float
    idle_time_s: float
    adc_start_time_s: float
    ramp_end_time_s: float
    slope_hz_per_s: float
    n_samples: int
    sample_rate_hz: float
    rx_mask: int = 1
    tx_mask: int = 1
    adc_bits: int = 16
    complex_adc: bool = True
    chirp_tx_masks: tuple[int, ...] = (1,)  # TX mask of each chirp of one loop, in time order
    n_loops: int = 128
    n_frames: int = 0  # 0: as many as the capture holds
    frame_period_s: float = 0.1
    tx_start_time_s: float = 1e-6
    rx_gain_db: float = 30.0
    source: str = field(default="<defaults>", compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "chirp_tx_masks", tuple(int(m) for m in self.chirp_tx_masks))
        problems = []
        if self.n_samples <= 0 or self.n_samples % 2:
            problems.append(f"numAdcSamples must be a positive even number, found {self.n_samples}")
        if self.sample_rate_hz <= 0:
            problems.append(f"sample rate must be positive, found {self.sample_rate_hz} Hz")
        if self.slope_hz_per_s <= 0:
            problems.append(f"frequency slope must be positive, found {self.slope_hz_per_s / 1e12} MHz/us")
        if self.start_freq_hz <= 0:
            problems.append(f"start frequency must be positive, found {self.start_freq_hz / 1e9} GHz")
        if self.idle_time_s < 0 or self.adc_start_time_s < 0:
            problems.append("idle and ADC start times must be non-negative")
        if self.n_loops <= 0:
            problems.append(f"numLoops must be positive, found {self.n_loops}")
        if self.n_frames < 0:
            problems.append(f"numFrames must be >= 0, found {self.n_frames}")
        if not self.rx_mask or not self.tx_mask:
            problems.append(f"channelCfg needs at least one RX and one TX, found rxMask {self.rx_mask} txMask {self.tx_mask}")
        if not self.chirp_tx_masks:
            problems.append("frameCfg selects no chirps")
        for m in self.chirp_tx_masks:
            if m == 0 or m & ~self.tx_mask:
                problems.append(f"chirp TX mask {m} is empty or uses a TX not enabled in channelCfg (txMask {self.tx_mask})")
        if not problems and self.sampling_time_s > self.ramp_end_time_s - self.adc_start_time_s + 1e-12:
            problems.append(
                f"ADC sampling ({self.sampling_time_s * 1e6:.2f} us) does not fit in the ramp "
                f"(rampEnd {self.ramp_end_time_s * 1e6:.2f} us - adcStart {self.adc_start_time_s * 1e6:.2f} us)"
            )
        if not problems and self.frame_active_s > self.frame_period_s + 1e-12:
            problems.append(
                f"a frame's chirps take {self.frame_active_s * 1e3:.3f} ms, longer than the frame period "
                f"{self.frame_period_s * 1e3:.3f} ms"
            )
        if problems:
            raise FormatError(self.source, "; ".join(problems))

    # ---- antenna and chirp layout -------------------------------------------------------
    @property
    def rx_indices(self) -> tuple[int, ...]:
        return _bits(self.rx_mask)

    @property
    def n_rx(self) -> int:
        return len(self.rx_indices)

    @property
    def chirps_per_loop(self) -> int:
        return len(self.chirp_tx_masks)

    @property
    def chirps_per_frame(self) -> int:
        """Chirps in one frame, loop-major then TX (TDM-MIMO order)."""
        return self.chirps_per_loop * self.n_loops

    @property
    def n_channels(self) -> int:
        """Virtual channels (chirps of a loop x RX) combined non-coherently by the chain."""
        return self.chirps_per_loop * self.n_rx

    # ---- timing --------------------------------------------------------------------------
    @property
    def chirp_period_s(self) -> float:
        """Chirp repetition time: idle + ramp end."""
        return self.idle_time_s + self.ramp_end_time_s

    @property
    def loop_period_s(self) -> float:
        """Slow-time sampling interval of one TX: all chirps of a loop."""
        return self.chirps_per_loop * self.chirp_period_s

    @property
    def frame_active_s(self) -> float:
        return self.chirps_per_frame * self.chirp_period_s

    @property
    def frame_idle_s(self) -> float:
        """Gap between the last chirp of a frame and the first of the next."""
        return self.frame_period_s - self.frame_active_s

    @property
    def sampling_time_s(self) -> float:
        return self.n_samples / self.sample_rate_hz

    def chirp_times_s(self, n_frames: int | None = None) -> np.ndarray:
        """Time of each chirp's sampling centre, shape (frames, loops, chirps_per_loop), seconds.

        Frame f starts at ``f * frame_period``; the chirps follow each other every chirp period
        and the rest of the frame period is idle, so consecutive frames have a gap between them.
        """
        n_frames = self._frames(n_frames)
        f = np.arange(n_frames)[:, None, None] * self.frame_period_s
        k = (np.arange(self.n_loops)[None, :, None] * self.chirps_per_loop
             + np.arange(self.chirps_per_loop)[None, None, :])
        return f + k * self.chirp_period_s + self.adc_start_time_s + 0.5 * self.sampling_time_s

    def _frames(self, n_frames: int | None) -> int:
        if n_frames is None:
            if self.n_frames == 0:
                raise ValueError("numFrames is 0 (continuous): pass n_frames explicitly")
            n_frames = self.n_frames
        return int(n_frames)

    # ---- RF figures -----------------------------------------------------------------------
    @property
    def carrier_hz(self) -> float:
        """Centre of the sampled part of the sweep: the frequency that sets slow-time phase."""
        return self.start_freq_hz + self.slope_hz_per_s * (self.adc_start_time_s + 0.5 * self.sampling_time_s)

    @property
    def wavelength_m(self) -> float:
        return SPEED_OF_LIGHT_M_S / self.carrier_hz

    @property
    def sweep_end_hz(self) -> float:
        return self.start_freq_hz + self.slope_hz_per_s * self.ramp_end_time_s

    @property
    def sampled_bandwidth_hz(self) -> float:
        return self.slope_hz_per_s * self.sampling_time_s

    @property
    def range_resolution_m(self) -> float:
        return SPEED_OF_LIGHT_M_S / (2.0 * self.sampled_bandwidth_hz)

    @property
    def n_range_bins(self) -> int:
        """Unambiguous range bins: all N for complex sampling, N/2 for real."""
        return self.n_samples if self.complex_adc else self.n_samples // 2

    @property
    def max_range_m(self) -> float:
        """IF bandwidth is fs for complex sampling, fs/2 for real."""
        if_bw = self.sample_rate_hz if self.complex_adc else self.sample_rate_hz / 2
        return if_bw * SPEED_OF_LIGHT_M_S / (2.0 * self.slope_hz_per_s)

    @property
    def max_velocity_m_s(self) -> float:
        return self.wavelength_m / (4.0 * self.loop_period_s)

    def velocity_resolution_m_s(self, n_slow: int | None = None) -> float:
        """Velocity resolution of a Doppler FFT over ``n_slow`` loops (default: a whole frame)."""
        n = self.n_loops if n_slow is None else n_slow
        return self.wavelength_m / (2.0 * n * self.loop_period_s)

    def beat_frequency_hz(self, range_m: float | np.ndarray) -> float | np.ndarray:
        return 2.0 * self.slope_hz_per_s * np.asarray(range_m) / SPEED_OF_LIGHT_M_S

    def range_bin_m(self, b: float | np.ndarray) -> float | np.ndarray:
        return np.asarray(b) * self.range_resolution_m

    def frame_bytes(self) -> int:
        """Bytes of one frame of DCA1000 complex int16 data."""
        return self.chirps_per_frame * self.n_rx * self.n_samples * 4

    def summary(self) -> dict[str, float]:
        """Derived figures, for logs and the README."""
        return {
            "carrier_GHz": self.carrier_hz / 1e9,
            "sweep_GHz": (self.start_freq_hz / 1e9, self.sweep_end_hz / 1e9),
            "range_resolution_m": self.range_resolution_m,
            "max_range_m": self.max_range_m,
            "max_velocity_m_s": self.max_velocity_m_s,
            "velocity_resolution_m_s": self.velocity_resolution_m_s(),
            "chirp_period_us": self.chirp_period_s * 1e6,
            "frame_idle_ms": self.frame_idle_s * 1e3,
        }

    # ---- (de)serialisation ----------------------------------------------------------------
    def to_cfg(self) -> str:
        """mmWave CLI text that parses back to this config (one chirpCfg per chirp)."""
        bits = {12: 0, 14: 1, 16: 2}[self.adc_bits]
        lines = [
            "% written by handradar",
            "sensorStop",
            "flushCfg",
            "dfeDataOutputMode 1",
            f"channelCfg {self.rx_mask} {self.tx_mask} 0",
            f"adcCfg {bits} {1 if self.complex_adc else 0}",
            "adcbufCfg -1 0 1 1 1",
            "profileCfg 0 {:g} {:g} {:g} {:g} 0 0 {:g} {:g} {:d} {:g} 0 0 {:g}".format(
                self.start_freq_hz / 1e9, self.idle_time_s * 1e6, self.adc_start_time_s * 1e6,
                self.ramp_end_time_s * 1e6, self.slope_hz_per_s / 1e12, self.tx_start_time_s * 1e6,
                self.n_samples, self.sample_rate_hz / 1e3, self.rx_gain_db),
        ]
        lines += [f"chirpCfg {i} {i} 0 0 0 0 0 {m}" for i, m in enumerate(self.chirp_tx_masks)]
        lines += [
            f"frameCfg 0 {self.chirps_per_loop - 1} {self.n_loops} {self.n_frames} {self.frame_period_s * 1e3:g} 1 0",
            "sensorStart",
        ]
        return "\n".join(lines) + "\n"

    @classmethod
    def from_cfg_text(cls, text: str, source: str | Path = "<text>") -> RadarConfig:
        return parse_cfg(text, source)

    @classmethod
    def from_file(cls, path: str | Path) -> RadarConfig:
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8", errors="strict")
        except UnicodeDecodeError as exc:
            raise FormatError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
        except OSError as exc:
            raise FormatError(path, f"cannot read: {exc.strerror}") from None
        return parse_cfg(text, path)


def _number(path: str | Path, lineno: int, cmd: str, token: str) -> float:
    try:
        value = float(token)
    except ValueError:
        raise FormatError(path, f"{cmd}: expected a number, found {token!r}", line=lineno) from None
    if not math.isfinite(value):
        raise FormatError(path, f"{cmd}: expected a finite number, found {token!r}", line=lineno)
    return value


def _integer(path: str | Path, lineno: int, cmd: str, token: str) -> int:
    value = _number(path, lineno, cmd, token)
    if value != int(value):
        raise FormatError(path, f"{cmd}: expected an integer, found {token!r}", line=lineno)
    return int(value)


def parse_cfg(text: str, source: str | Path = "<text>") -> RadarConfig:
    """Parse mmWave CLI commands. ``%`` starts a comment; unknown commands are ignored.

    Raises FormatError naming ``source`` (and the line) for a missing mandatory command, a
    wrong argument count, a non-numeric argument, more than one profile, or a frame that
    selects undefined chirps.
    """
    seen: dict[str, list[tuple[int, list[str]]]] = {}
    near_miss: dict[str, tuple[int, str]] = {}  # mandatory command -> (line, misspelt form seen)
    lower = {c.lower(): c for c in MANDATORY_COMMANDS}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("%", 1)[0].strip()
        if not line:
            continue
        cmd, *args = line.split()
        if cmd not in _ARITY:
            # unknown or irrelevant command (guiMonitor, cfarCfg, ...); remember case slips of a
            # mandatory one so that "missing profileCfg" can point at "profilecfg" on line n
            if cmd.lower() in lower:
                near_miss.setdefault(lower[cmd.lower()], (lineno, cmd))
            continue
        if len(args) < _ARITY[cmd]:
            raise FormatError(source, f"{cmd}: expected {_ARITY[cmd]} arguments, found {len(args)}", line=lineno)
        seen.setdefault(cmd, []).append((lineno, args))

    missing = [c for c in MANDATORY_COMMANDS if c not in seen]
    if missing:
        hints = "".join(f"; line {near_miss[c][0]} has {near_miss[c][1]!r} (commands are case-sensitive)"
                        for c in missing if c in near_miss)
        raise FormatError(source, f"missing mandatory command(s): {', '.join(missing)} "
                                  f"(expected all of {', '.join(MANDATORY_COMMANDS)}){hints}")
    for cmd in ("channelCfg", "adcCfg", "profileCfg", "frameCfg"):
        if len(seen[cmd]) > 1:
            raise FormatError(source, f"expected exactly one {cmd}, found {len(seen[cmd])} "
                                      f"(lines {', '.join(str(n) for n, _ in seen[cmd])})")

    n, a = seen["channelCfg"][0]
    rx_mask = _integer(source, n, "channelCfg", a[0])
    tx_mask = _integer(source, n, "channelCfg", a[1])
    if not 0 < rx_mask < 16 or not 0 < tx_mask < 8:
        raise FormatError(source, f"channelCfg: rxMask must be 1-15 and txMask 1-7, found {rx_mask} {tx_mask}", line=n)

    n, a = seen["adcCfg"][0]
    bits_code, fmt = _integer(source, n, "adcCfg", a[0]), _integer(source, n, "adcCfg", a[1])
    if bits_code not in (0, 1, 2) or fmt not in (0, 1, 2):
        raise FormatError(source, f"adcCfg: expected bits 0/1/2 and format 0/1/2, found {bits_code} {fmt}", line=n)
    if fmt == 0:
        raise FormatError(source, "adcCfg: real ADC output (format 0) is not supported; "
                                  "expected complex (format 1 or 2)", line=n)

    n, a = seen["profileCfg"][0]
    p = [_number(source, n, "profileCfg", t) for t in a[:14]]
    profile_id = int(p[0])
    n_samples = _integer(source, n, "profileCfg numAdcSamples", a[9])

    n, a = seen["frameCfg"][0]
    chirp_start = _integer(source, n, "frameCfg", a[0])
    chirp_end = _integer(source, n, "frameCfg", a[1])
    n_loops = _integer(source, n, "frameCfg", a[2])
    n_frames = _integer(source, n, "frameCfg", a[3])
    period_ms = _number(source, n, "frameCfg", a[4])
    if not 0 <= chirp_start <= chirp_end:
        raise FormatError(source, f"frameCfg: chirp indices must satisfy 0 <= start <= end, "
                                  f"found {chirp_start} {chirp_end}", line=n)
    if chirp_end - chirp_start >= 512:
        raise FormatError(source, f"frameCfg: at most 512 chirps per loop, found {chirp_end - chirp_start + 1}", line=n)

    chirp_tx: dict[int, int] = {}
    for n, a in seen["chirpCfg"]:
        c0, c1 = _integer(source, n, "chirpCfg", a[0]), _integer(source, n, "chirpCfg", a[1])
        prof = _integer(source, n, "chirpCfg", a[2])
        mask = _integer(source, n, "chirpCfg", a[7])
        if prof != profile_id:
            raise FormatError(source, f"chirpCfg uses profile {prof}, but the only profile is {profile_id}", line=n)
        if not 0 <= c0 <= c1 or c1 - c0 >= 512:
            raise FormatError(source, f"chirpCfg: bad chirp index range {c0}..{c1}", line=n)
        for c in range(c0, c1 + 1):
            chirp_tx[c] = mask
    undefined = [c for c in range(chirp_start, chirp_end + 1) if c not in chirp_tx]
    if undefined:
        raise FormatError(source, f"frameCfg uses chirps {chirp_start}..{chirp_end} but chirp(s) "
                                  f"{undefined[:8]} have no chirpCfg")

    return RadarConfig(
        start_freq_hz=p[1] * 1e9,
        idle_time_s=p[2] * 1e-6,
        adc_start_time_s=p[3] * 1e-6,
        ramp_end_time_s=p[4] * 1e-6,
        slope_hz_per_s=p[7] * 1e12,
        tx_start_time_s=p[8] * 1e-6,
        n_samples=n_samples,
        sample_rate_hz=p[10] * 1e3,
        rx_gain_db=p[13],
        rx_mask=rx_mask,
        tx_mask=tx_mask,
        adc_bits={0: 12, 1: 14, 2: 16}[bits_code],
        complex_adc=True,
        chirp_tx_masks=tuple(chirp_tx[c] for c in range(chirp_start, chirp_end + 1)),
        n_loops=n_loops,
        n_frames=n_frames,
        frame_period_s=period_ms * 1e-3,
        source=str(source),
    )
