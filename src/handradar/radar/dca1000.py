"""DCA1000 raw capture (``adc_data.bin``) reader and writer.

Layout (xWR16xx/18xx, 2-lane LVDS, complex, non-interleaved): little-endian int16, every 4
values are ``I(n) I(n+1) Q(n) Q(n+1)``; within a chirp all samples of the first enabled RX,
then the next RX; chirps in time order (loop-major, then TX); frames back to back.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from handradar.atomic import atomic_write_bytes
from handradar.errors import FormatError
from handradar.radar.config import RadarConfig

INT16_FULL_SCALE = 32767


def _expected_frames(cfg: RadarConfig, path: Path, size: int, allow_truncated: bool) -> int:
    fb = cfg.frame_bytes()
    whole, rest = divmod(size, fb)
    if cfg.n_frames:
        expected = cfg.n_frames * fb
        if size == expected:
            return cfg.n_frames
        if allow_truncated and rest and whole == cfg.n_frames - 1:
            warnings.warn(f"{path}: last frame truncated ({rest} of {fb} bytes); dropping it, "
                          f"keeping {whole} of {cfg.n_frames} frames", stacklevel=3)
            return whole
        raise FormatError(path, f"size {size} bytes does not match the .cfg: expected {expected} bytes "
                                f"({cfg.n_frames} frames x {cfg.chirps_per_frame} chirps x {cfg.n_rx} RX x "
                                f"{cfg.n_samples} samples x 4 bytes)")
    # numFrames 0: continuous capture, the file decides the number of frames
    if whole == 0:
        raise FormatError(path, f"size {size} bytes holds no complete frame: expected a multiple of {fb} bytes "
                                f"({cfg.chirps_per_frame} chirps x {cfg.n_rx} RX x {cfg.n_samples} samples x 4 bytes)")
    if rest:
        if not allow_truncated:
            raise FormatError(path, f"size {size} bytes is not a whole number of frames: expected a multiple of "
                                    f"{fb} bytes ({cfg.chirps_per_frame} chirps x {cfg.n_rx} RX x {cfg.n_samples} "
                                    f"samples x 4 bytes), found {whole} frames + {rest} bytes "
                                    "(pass allow_truncated=True to drop the partial last frame)")
        warnings.warn(f"{path}: last frame truncated ({rest} of {fb} bytes); dropping it, keeping {whole} frames",
                      stacklevel=3)
    return whole


def read_adc(path: str | Path, cfg: RadarConfig, *, allow_truncated: bool = False, iq_swap: bool = False) -> np.ndarray:
    """Read a capture as complex64 ADC counts, shape (frames, chirps_per_frame, rx, samples).

    iq_swap: the file holds Q where the layout says I and vice versa (some capture configurations
    deliver them so); read as I + jQ all the same."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise FormatError(path, f"cannot read: {exc.strerror}") from None
    n_frames = _expected_frames(cfg, path, size, allow_truncated)
    count = n_frames * cfg.frame_bytes() // 2
    try:
        raw = np.fromfile(path, dtype="<i2", count=count).reshape(-1, 4)  # I(n) I(n+1) Q(n) Q(n+1)
    except OSError as exc:  # e.g. a file without read permission (its size is readable all the same)
        raise FormatError(path, f"cannot read: {exc.strerror or exc}") from None
    out = np.empty(raw.shape, dtype=np.float32)  # re(n) im(n) re(n+1) im(n+1): complex64 pairs
    # one long strided copy per column: numpy's copy loop is fast along a long axis and slow
    # along a short one, so this beats a (..., 2, 2) transpose by about 4x (int16 -> float32 is exact)
    for dst, src in enumerate((2, 0, 3, 1) if iq_swap else (0, 2, 1, 3)):
        out[:, dst] = raw[:, src]
    return out.view(np.complex64).reshape(n_frames, cfg.chirps_per_frame, cfg.n_rx, cfg.n_samples)


def quantise(adc: np.ndarray) -> tuple[np.ndarray, int]:
    """Round complex ADC counts to int16 I and Q; returns (I/Q int16 pair, clipped count)."""
    parts = np.rint(np.stack([adc.real, adc.imag], axis=0))
    # int16 spans -32768..32767: -32768 is a valid count, not a clipped one
    clipped = int(np.count_nonzero((parts > INT16_FULL_SCALE) | (parts < -INT16_FULL_SCALE - 1)))
    return np.clip(parts, -INT16_FULL_SCALE - 1, INT16_FULL_SCALE).astype("<i2"), clipped


def encode_adc(adc: np.ndarray, cfg: RadarConfig) -> bytes:
    """Encode a (frames, chirps_per_frame, rx, samples) complex cube in the DCA1000 layout."""
    expected = (cfg.chirps_per_frame, cfg.n_rx, cfg.n_samples)
    if adc.ndim != 4 or adc.shape[1:] != expected:
        raise ValueError(f"ADC cube shape {adc.shape} does not match the config: expected (frames, {expected[0]}, "
                         f"{expected[1]}, {expected[2]})")
    (i, q), clipped = quantise(adc)
    if clipped:
        warnings.warn(f"{clipped} ADC values exceed int16 full scale and were clipped", stacklevel=2)
    shape = adc.shape[:-1] + (cfg.n_samples // 2, 2)
    packed = np.concatenate([i.reshape(shape), q.reshape(shape)], axis=-1)
    return packed.astype("<i2").tobytes()


def write_adc(path: str | Path, adc: np.ndarray, cfg: RadarConfig) -> None:
    """Write a complex cube (ADC counts) as ``adc_data.bin``, atomically."""
    atomic_write_bytes(path, encode_adc(adc, cfg))
