"""DCA1000 adc_data.bin: exact round trip, byte layout against a hand-built sequence, bad sizes."""

from __future__ import annotations

import struct
import warnings

import numpy as np
import pytest

from handradar.errors import FormatError
from handradar.radar.config import RadarConfig
from handradar.radar.dca1000 import encode_adc, read_adc, write_adc

# 2 RX, 1 TX, 4 samples, 2 loops, 3 frames: small enough to lay out by hand
SMALL = """\
channelCfg 3 1 0
adcCfg 2 1
profileCfg 0 77 100 6 60 0 0 30 1 4 10000 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
frameCfg 0 0 2 3 1 1 0
"""


@pytest.fixture()
def small() -> RadarConfig:
    return RadarConfig.from_cfg_text(SMALL, "small.cfg")


def _cube(cfg: RadarConfig, n_frames: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    shape = (n_frames, cfg.chirps_per_frame, cfg.n_rx, cfg.n_samples)
    i = rng.integers(-32768, 32768, size=shape)
    q = rng.integers(-32768, 32768, size=shape)
    return (i + 1j * q).astype(np.complex64)


def test_round_trip_is_exact(tmp_path, small, radar):
    for cfg, frames in ((small, 3), (radar, 2)):
        cube = _cube(cfg, frames)
        path = tmp_path / "adc_data.bin"
        write_adc(path, cube, cfg)
        assert path.stat().st_size == frames * cfg.frame_bytes()
        back = read_adc(path, cfg)
        assert back.dtype == np.complex64 and back.shape == cube.shape
        np.testing.assert_array_equal(back, cube)  # int16 values survive bit for bit, extremes included


def test_multi_rx_layout_matches_hand_built_bytes(tmp_path, small):
    """Every 4 int16 are I(n) I(n+1) Q(n) Q(n+1); within a chirp RX 0's samples, then RX 1's."""
    def value(f, c, r, n):  # unique, readable numbers
        return 1000 * f + 100 * c + 10 * r + n

    cube = np.zeros((3, 2, 2, 4), dtype=np.complex64)
    words: list[int] = []
    for f in range(3):
        for c in range(2):  # chirps in time order
            for r in range(2):  # RX-major inside a chirp
                for n in (0, 2):  # two samples per group of 4 words
                    words += [value(f, c, r, n), value(f, c, r, n + 1), -value(f, c, r, n), -value(f, c, r, n + 1)]
                for n in range(4):
                    cube[f, c, r, n] = value(f, c, r, n) - 1j * value(f, c, r, n)
    expected = struct.pack(f"<{len(words)}h", *words)
    assert encode_adc(cube, small) == expected
    path = tmp_path / "adc_data.bin"
    path.write_bytes(expected)
    np.testing.assert_array_equal(read_adc(path, small), cube)


def test_truncated_file_is_rejected_with_sizes(tmp_path, small):
    data = encode_adc(_cube(small, 3), small)
    path = tmp_path / "adc_data.bin"
    path.write_bytes(data[:-10])
    with pytest.raises(FormatError) as info:
        read_adc(path, small)
    msg = str(info.value)
    assert str(path) in msg
    assert f"size {len(data) - 10} bytes" in msg and f"expected {len(data)} bytes" in msg
    assert "3 frames x 2 chirps x 2 RX x 4 samples x 4 bytes" in msg


def test_allow_truncated_drops_partial_last_frame_with_warning(tmp_path, small):
    cube = _cube(small, 3)
    path = tmp_path / "adc_data.bin"
    path.write_bytes(encode_adc(cube, small)[:-10])
    with pytest.warns(UserWarning, match=r"last frame truncated \(54 of 64 bytes\); dropping it, keeping 2 of 3"):
        back = read_adc(path, small, allow_truncated=True)
    np.testing.assert_array_equal(back, cube[:2])


def test_allow_truncated_does_not_hide_bigger_losses(tmp_path, small):
    path = tmp_path / "adc_data.bin"
    path.write_bytes(encode_adc(_cube(small, 3), small)[: small.frame_bytes() + 8])  # 1 frame + 8 bytes of 3
    with pytest.raises(FormatError, match="expected 192 bytes"):
        read_adc(path, small, allow_truncated=True)
    path.write_bytes(encode_adc(_cube(small, 4), small))  # one frame too many
    with pytest.raises(FormatError, match="size 256 bytes does not match"):
        read_adc(path, small, allow_truncated=True)


def test_continuous_capture_takes_frames_from_the_file(tmp_path, radar):
    assert radar.n_frames == 0
    cube = _cube(radar, 2)
    path = tmp_path / "adc_data.bin"
    data = encode_adc(cube, radar)
    path.write_bytes(data)
    assert read_adc(path, radar).shape[0] == 2
    path.write_bytes(data[:-4])
    with pytest.raises(FormatError, match=r"not a whole number of frames.*found 1 frames \+ "):
        read_adc(path, radar)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert read_adc(path, radar, allow_truncated=True).shape[0] == 1
    assert any("dropping it, keeping 1 frames" in str(w.message) for w in caught)
    path.write_bytes(data[:100])
    with pytest.raises(FormatError, match="holds no complete frame"):
        read_adc(path, radar, allow_truncated=True)


def test_missing_file_and_bad_cube(tmp_path, small):
    with pytest.raises(FormatError, match="cannot read"):
        read_adc(tmp_path / "nope.bin", small)
    with pytest.raises(ValueError, match="does not match the config"):
        encode_adc(np.zeros((1, 2, 1, 4), dtype=np.complex64), small)


def test_clipping_warns(small):
    cube = np.full((3, 2, 2, 4), 40000 + 0j, dtype=np.complex64)
    with pytest.warns(UserWarning, match="clipped"):
        data = encode_adc(cube, small)
    assert set(np.frombuffer(data, "<i2")[::4].tolist()) == {32767}
