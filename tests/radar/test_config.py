"""RadarConfig: the real Visualizer file, derived figures against hand computations, bad input."""

from __future__ import annotations

import math
import string
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from handradar.errors import FormatError
from handradar.radar.config import RadarConfig, parse_cfg

C = 299_792_458.0
VISUALIZER = Path(__file__).parent / "ti_cfg" / "xwr18xx_visualizer_profile.cfg"  # Clear BSD, licence beside it


@pytest.fixture(scope="module")
def vis() -> RadarConfig:
    return RadarConfig.from_file(VISUALIZER)


def test_visualizer_file_layout(vis):
    # channelCfg 15 5 0: RX 0-3, TX 0 and 2; chirpCfg 0 -> TX mask 1, chirpCfg 1 -> TX mask 4
    assert vis.rx_indices == (0, 1, 2, 3) and vis.n_rx == 4
    assert vis.tx_mask == 5
    assert vis.chirp_tx_masks == (1, 4) and vis.chirps_per_loop == 2
    assert vis.n_loops == 16 and vis.chirps_per_frame == 32
    assert vis.n_channels == 8
    assert vis.n_frames == 0  # continuous capture
    assert vis.n_samples == 256 and vis.adc_bits == 16 and vis.complex_adc


def test_visualizer_derived_figures_match_hand_computation(vis):
    # raw numbers of "profileCfg 0 77 429 7 57.14 0 0 70 1 256 5209 0 0 30" and "frameCfg 0 1 16 0 100 1 0"
    f0, idle, adc_start, ramp_end, slope = 77e9, 429e-6, 7e-6, 57.14e-6, 70e12
    n, fs, loops, period = 256, 5209e3, 16, 0.1
    t_sample = n / fs  # 49.146 us of sampling
    bandwidth = slope * t_sample  # 3.440 GHz swept while sampling
    assert vis.sampling_time_s == pytest.approx(t_sample, rel=1e-12)
    assert vis.range_resolution_m == pytest.approx(C / (2 * bandwidth), rel=1e-12)
    assert vis.range_resolution_m == pytest.approx(0.0436, abs=5e-4)  # Visualizer header: 0.044 m
    assert vis.max_range_m == pytest.approx(fs * C / (2 * slope), rel=1e-12)  # complex IF: bandwidth fs
    assert vis.max_range_m == pytest.approx(11.15, abs=0.01)
    carrier = f0 + slope * (adc_start + t_sample / 2)  # centre of the sampled sweep
    lam = C / carrier
    assert vis.carrier_hz == pytest.approx(carrier, rel=1e-12)
    tc = idle + ramp_end  # 486.14 us
    assert vis.chirp_period_s == pytest.approx(tc, rel=1e-12)
    assert vis.loop_period_s == pytest.approx(2 * tc, rel=1e-12)  # TDM: one TX repeats every 2 chirps
    assert vis.max_velocity_m_s == pytest.approx(lam / (4 * 2 * tc), rel=1e-12)
    assert vis.max_velocity_m_s == pytest.approx(0.973, abs=1e-3)  # Visualizer header: 1 m/s
    assert vis.velocity_resolution_m_s() == pytest.approx(lam / (2 * loops * 2 * tc), rel=1e-12)
    assert vis.velocity_resolution_m_s() == pytest.approx(0.1217, abs=1e-3)  # Visualizer header: 0.13 m/s
    assert vis.frame_active_s == pytest.approx(32 * tc, rel=1e-12)
    assert vis.frame_idle_s == pytest.approx(period - 32 * tc, rel=1e-12)  # 84.44 ms idle between frames
    assert vis.frame_bytes() == 32 * 4 * 256 * 4


def test_visualizer_chirp_times_include_the_idle_gap(vis):
    tc = 429e-6 + 57.14e-6
    centre = 7e-6 + 0.5 * 256 / 5209e3
    t = vis.chirp_times_s(3)
    assert t.shape == (3, 16, 2)
    # loop l, chirp c of frame f starts at f * period + (2 l + c) * tc
    f, loop, c = np.meshgrid(np.arange(3), np.arange(16), np.arange(2), indexing="ij")
    np.testing.assert_allclose(t, f * 0.1 + (2 * loop + c) * tc + centre, rtol=0, atol=1e-12)
    gap = t[1, 0, 0] - t[0, -1, -1]
    assert gap == pytest.approx(0.1 - 31 * tc, rel=1e-9)  # not one chirp period: the frame's idle time
    with pytest.raises(ValueError, match="numFrames is 0"):
        vis.chirp_times_s()


def test_default_radar_figures(radar):
    """docs/architecture.md, "Processing chain and simulator": 77-80.9 GHz, ~7.7 cm, 19.7 m, v_max ~ 2.5 m/s, v_res ~ 0.04 m/s, 390 us."""
    assert radar.chirp_period_s == pytest.approx(390e-6)
    assert radar.sweep_end_hz == pytest.approx(77e9 + 76.22e12 * 51.2e-6)
    assert radar.range_resolution_m == pytest.approx(C / (2 * 76.22e12 * 25.6e-6))
    assert radar.max_range_m == pytest.approx(10e6 * C / (2 * 76.22e12))
    assert 19.6 < radar.max_range_m < 19.8
    assert 2.4 < radar.max_velocity_m_s < 2.6
    assert 0.035 < radar.velocity_resolution_m_s() < 0.045


def test_to_cfg_round_trips(vis, radar):
    for cfg in (vis, radar):
        again = RadarConfig.from_cfg_text(cfg.to_cfg())
        assert again == cfg
        assert again.summary() == cfg.summary()
        assert RadarConfig.from_cfg_text(again.to_cfg()).to_cfg() == again.to_cfg()


# ---- bad input ----------------------------------------------------------------------------------
GOOD = """\
channelCfg 1 1 0
adcCfg 2 1
profileCfg 0 77 338.8 6 51.2 0 0 76.22 1 256 10000 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
frameCfg 0 0 128 0 100 1 0
"""


def _bad(text: str, *fragments: str) -> FormatError:
    with pytest.raises(FormatError) as info:
        parse_cfg(text, "bad.cfg")
    msg = str(info.value)
    assert msg.startswith("bad.cfg"), msg
    for frag in fragments:
        assert frag in msg, msg
    return info.value


def test_comments_and_unknown_commands_are_ignored():
    text = "% header\nguiMonitor -1 1 1 0 0 0 1\n" + GOOD.replace("adcCfg 2 1", "adcCfg 2 1 % 16-bit complex")
    assert parse_cfg(text) == parse_cfg(GOOD)


@pytest.mark.parametrize("cmd", ["channelCfg", "adcCfg", "profileCfg", "chirpCfg", "frameCfg"])
def test_missing_mandatory_command(cmd):
    text = "".join(line + "\n" for line in GOOD.splitlines() if not line.startswith(cmd))
    _bad(text, f"missing mandatory command(s): {cmd}", "expected all of")


def test_misspelt_mandatory_command_is_pointed_at():
    _bad(GOOD.replace("profileCfg", "profilecfg"), "missing mandatory command(s): profileCfg",
         "line 3 has 'profilecfg'")


def test_wrong_argument_count_names_line():
    err = _bad(GOOD.replace("profileCfg 0 77 338.8 6 51.2 0 0 76.22 1 256 10000 0 0 30", "profileCfg 0 77 338.8"),
               "profileCfg: expected 14 arguments, found 3")
    assert err.line == 3


def test_non_numeric_argument():
    _bad(GOOD.replace("256 10000", "2x6 10000"), "expected a number", "'2x6'")
    _bad(GOOD.replace("256 10000", "255.5 10000"), "expected an integer", "255.5")
    _bad(GOOD.replace("76.22", "nan"), "expected a finite number")


def test_two_profiles_rejected():
    _bad(GOOD + "profileCfg 1 77 338.8 6 51.2 0 0 76.22 1 256 10000 0 0 30\n", "expected exactly one profileCfg, found 2")


def test_frame_uses_undefined_chirp():
    _bad(GOOD.replace("frameCfg 0 0", "frameCfg 0 1"), "chirp(s) [1] have no chirpCfg")


def test_chirp_uses_disabled_tx():
    _bad(GOOD.replace("chirpCfg 0 0 0 0 0 0 0 1", "chirpCfg 0 0 0 0 0 0 0 2"), "chirp TX mask 2",
         "txMask 1")


def test_real_adc_rejected():
    _bad(GOOD.replace("adcCfg 2 1", "adcCfg 2 0"), "real ADC output", "expected complex")


def test_sampling_longer_than_ramp():
    _bad(GOOD.replace("51.2 0 0 76.22", "20 0 0 76.22"), "does not fit in the ramp")


def test_frame_longer_than_period():
    _bad(GOOD.replace("frameCfg 0 0 128 0 100", "frameCfg 0 0 128 0 40"), "longer than the frame period")


def test_unreadable_files(tmp_path):
    binary = tmp_path / "radar.cfg"
    binary.write_bytes(b"\xff\xfe\x00channelCfg")
    with pytest.raises(FormatError, match="not a text file"):
        RadarConfig.from_file(binary)
    with pytest.raises(FormatError, match="cannot read"):
        RadarConfig.from_file(tmp_path / "missing.cfg")


_TOKENS = st.one_of(
    st.sampled_from(["channelCfg", "adcCfg", "profileCfg", "chirpCfg", "frameCfg", "sensorStart", "%", "\n",
                     "0", "1", "2", "4", "15", "-1", "77", "1e309", "nan", "inf", "256", "0.5", "1e6", "-3.5"]),
    st.text(string.printable, max_size=6),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_TOKENS, max_size=80), st.data())
def test_fuzz_cfg_parser_only_raises_format_error(tokens, data):
    """Random token soups and random edits of a good file: a RadarConfig or a FormatError, nothing else."""
    text = " ".join(tokens)
    lines = GOOD.splitlines()
    i = data.draw(st.integers(0, len(lines) - 1))
    words = lines[i].split()
    j = data.draw(st.integers(0, len(words) - 1))
    words[j] = data.draw(_TOKENS)
    lines[i] = " ".join(words)
    for candidate in (text, "\n".join(lines)):
        try:
            cfg = parse_cfg(candidate, "fuzz.cfg")
        except FormatError as exc:
            assert str(exc).startswith("fuzz.cfg")
            continue
        # whatever parses must be self-consistent
        assert cfg.n_samples > 0 and cfg.sampling_time_s <= cfg.ramp_end_time_s
        assert math.isfinite(cfg.range_resolution_m) and cfg.frame_bytes() > 0
