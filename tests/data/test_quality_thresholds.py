"""Every threshold of the quality gate (handradar.data.quality) at its boundary: just on the keeping side
it keeps (or stays ok), just past it the check acts (warns or skips).

The thresholds are written here as the numbers docs/datasets.md gives, not read from the module, so
that moving a constant by a little fails a test. Figures that a check reads from a dict are put exactly
on the threshold (which also pins ``>`` against ``>=``) and one float step past it; figures measured on
constructed data (distances, angles, times, rates) a relative 1e-6 to either side, counts one to either side.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from handradar.data.quality import (
    RecordingQuality,
    _jump_outliers,
    _volume_outliers,
    adc_findings,
    drop_outliers,
    gate_capture,
    long_gap_steps,
    meta_findings,
    tracking_findings,
    view_outside,
    window_figures,
)
from handradar.data.recording import Recording, RecordingMeta
from handradar.hand.skeleton import HandSequence
from handradar.radar.config import RadarConfig

EPS = 1e-6  # relative step to either side of a geometric threshold: far above rounding, far below any real change
GATE_M = (0.08, 0.70)  # the default chain's range gate (m)


def above(x: float) -> float:
    """The next float above ``x``."""
    return math.nextafter(x, math.inf)


def below(x: float) -> float:
    """The next float below ``x``."""
    return math.nextafter(x, -math.inf)


def levels(q: RecordingQuality) -> dict[str, str]:
    """{check: level} of the findings."""
    return {f.check: f.level for f in q.findings}


def meta(angle_deg: float = 0.0, leap_to_radar: np.ndarray | None = None) -> RecordingMeta:
    """A one-hand recording's metadata; ``leap_to_radar`` (4, 4), the identity unless given."""
    m = np.eye(4) if leap_to_radar is None else leap_to_radar
    return RecordingMeta(gesture="circle", subject="s01", angle_deg=angle_deg, hands=1, occlusion=False,
                         repetition=0, radar_start_us=0.0, leap_to_radar=tuple(tuple(float(v) for v in r) for r in m))


def hand_along_z(tip_m: float, length_m: float) -> np.ndarray:
    """(21, 3) joints on the boresight from the wrist at ``tip_m - length_m`` to the farthest joint at
    ``tip_m`` (metres): the hand is ``length_m`` long and its farthest joint ``tip_m`` from the radar."""
    return np.c_[np.zeros((21, 2)), np.linspace(tip_m - length_m, tip_m, 21)]


def sequence(times: np.ndarray, tracked: np.ndarray, far: np.ndarray | None = None) -> HandSequence:
    """Slot 0 tracked where ``tracked`` (T,), a 15 cm hand resting 0.3 m out on the boresight, moved 5 m
    out (outside the plausible volume) where ``far`` (T,)."""
    pos = np.zeros((len(times), 2, 21, 3))
    pos[:, 0] = hand_along_z(0.3, 0.15)
    if far is not None:
        pos[far, 0] = hand_along_z(5.0, 0.15)
    return HandSequence(pos, times, np.c_[tracked, np.zeros(len(times), bool)])


def capture(radar: RadarConfig, skeleton: HandSequence) -> RecordingQuality:
    """gate_capture on an in-memory recording: a tiny noise cube, identity calibration, ``skeleton``."""
    rng = np.random.default_rng(0)
    shape = (2, 8, radar.n_rx, 16)
    adc = (rng.normal(0, 100, shape) + 1j * rng.normal(0, 100, shape)).astype(np.complex64)
    q, _ = gate_capture(Recording(Path("r"), radar, adc, skeleton, meta()))
    return q


# ---- ADC ---------------------------------------------------------------------------------------
@pytest.mark.parametrize(("share", "verdict"), [(0.001, "ok"), (above(0.001), "warn"),
                                                (0.01, "warn"), (above(0.01), "skip")])
def test_clipping_warns_above_a_tenth_of_a_percent_and_skips_above_one(share, verdict):
    q = RecordingQuality()
    adc_findings({"all_zero": False, "constant_rx": [], "clipped_share": share, "rx_power_db": [0.0, 0.0]}, q)
    assert levels(q) == ({} if verdict == "ok" else {"adc_clipped": verdict})


@pytest.mark.parametrize(("db", "dead"), [(-20.0, False), (below(-20.0), True)])
def test_an_rx_channel_is_dead_below_minus_20_db(db, dead):
    q = RecordingQuality()
    adc_findings({"all_zero": False, "constant_rx": [], "clipped_share": 0.0, "rx_power_db": [0.0, db, 0.0]}, q)
    assert [f.message.split(" (")[0] for f in q.findings] == (["RX2 is dead"] if dead else [])


# ---- meta.json ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("angle", "skip"), [(180.0, False), (-180.0, False), (above(180.0), True),
                                             (below(-180.0), True)])
def test_angle_is_a_direction_up_to_180_deg(angle, skip):
    q = RecordingQuality()
    meta_findings(meta(angle_deg=angle), q)
    assert levels(q) == ({"meta_angle": "skip"} if skip else {})


@pytest.mark.parametrize(("spread", "skip"), [(0.05 * (1 - EPS), False), (0.05 * (1 + EPS), True)])
def test_calibration_singular_values_agree_within_5_percent(spread, skip):
    """A rotation about a tilted axis times a stretch of one axis: singular values 1 + spread, 1, 1."""
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + math.sin(0.7) * k + (1 - math.cos(0.7)) * k @ k  # Rodrigues
    m = np.eye(4)
    m[:3, :3] = rot @ np.diag([1 + spread, 1.0, 1.0])
    q = RecordingQuality()
    meta_findings(meta(leap_to_radar=m), q)
    assert levels(q) == ({"calibration": "skip"} if skip else {})


# ---- outlier frames ----------------------------------------------------------------------------
@pytest.mark.parametrize(("tip_m", "outlier"), [(3.0 * (1 - EPS), False), (3.0 * (1 + EPS), True)])
def test_a_hand_farther_than_3_m_is_an_outlier(tip_m, outlier):
    pos = hand_along_z(tip_m, 0.15)[None, None]
    volume, _ = _volume_outliers(pos, np.ones((1, 1), bool))
    assert bool(volume[0, 0]) == outlier


@pytest.mark.parametrize(("length_m", "outlier"), [(0.03 * (1 - EPS), True), (0.03 * (1 + EPS), False),
                                                   (0.30 * (1 - EPS), False), (0.30 * (1 + EPS), True)])
def test_a_hand_shorter_than_3_cm_or_longer_than_30_cm_is_an_outlier(length_m, outlier):
    pos = hand_along_z(0.4, length_m)[None, None]
    volume, _ = _volume_outliers(pos, np.ones((1, 1), bool))
    assert bool(volume[0, 0]) == outlier


@pytest.mark.parametrize("dt", [0.001, 0.01, 0.1])
@pytest.mark.parametrize("side", [-1, 1])
def test_a_jump_over_10_m_s_plus_1_cm_is_an_outlier(dt, side):
    """Frame 2 of five, ``dt`` apart, is moved by 10 m/s x dt + 1 cm just under or over: flagged only over."""
    times = np.arange(5) * dt
    pos = np.broadcast_to(hand_along_z(0.3, 0.15), (5, 21, 3)).copy()
    pos[2, :, 0] += (10.0 * dt + 0.01) * (1 + side * EPS)
    out = _jump_outliers(pos, times, np.ones(5, bool))
    assert np.flatnonzero(out).tolist() == ([2] if side > 0 else [])


@pytest.mark.parametrize(("n_out", "verdict"), [(1000, "warn"), (1001, "skip")])
def test_a_tenth_of_the_frames_outliers_is_still_kept(radar, n_out, verdict):
    """10000 tracked frames at 100 Hz, ``n_out`` of them 5 m away: 10 % warns, 10.01 % skips."""
    times = np.arange(10000) / 100.0
    far = np.zeros(10000, bool)
    far[np.linspace(5, 9994, n_out).astype(int)] = True
    q = capture(radar, sequence(times, np.ones(10000, bool), far))
    assert q.figures["outlier_frames"] == n_out and levels(q) == {"outliers": verdict}


# ---- tracking ----------------------------------------------------------------------------------
@pytest.mark.parametrize(("rate_hz", "warn"), [(40.0 * (1 + EPS), False), (40.0 * (1 - EPS), True)])
def test_a_leap_rate_under_40_hz_warns(radar, rate_hz, warn):
    times = np.arange(200) / rate_hz
    q = capture(radar, sequence(times, np.ones(200, bool)))
    assert levels(q) == ({"leap_rate": "warn"} if warn else {})


@pytest.mark.parametrize(("gap_s", "bridged"), [(0.1 * (1 - EPS), True), (0.1 * (1 + EPS), False)])
def test_interpolation_bridges_gaps_up_to_a_tenth_of_a_second(gap_s, bridged):
    """The 0.1 s limit in the skeleton: an outlier between good frames ``gap_s`` apart is re-interpolated
    or left untracked, and a skeleton step between Leap samples ``gap_s`` apart is tracked or not."""
    seq = sequence(np.array([0.0, gap_s / 2, gap_s]), np.ones(3, bool))
    cleaned, n = drop_outliers(seq, np.array([[False, False], [True, False], [False, False]]))
    assert (n, bool(cleaned.mask[1, 0])) == ((1, True) if bridged else (0, False))
    assert long_gap_steps(np.array([0.0, gap_s]), np.array([gap_s / 2])).tolist() == [not bridged]


def window_levels(meta_hands: int = 1, **figures: object) -> dict[str, str]:
    """{check: level} of tracking_findings on a clean window's figures with ``figures`` changed."""
    fig = {"coverage": 1.0, "longest_gap_s": 0.01, "leap_rate_hz": 100.0, "out_of_view": 0.0, "hands_seen": 1,
           "hand_share": [1.0, 0.0], **figures}
    q = RecordingQuality()
    tracking_findings(fig, meta_hands, q)
    return levels(q)


@pytest.mark.parametrize(("gap_s", "warn"), [(0.1, False), (above(0.1), True)])
def test_a_gap_over_a_tenth_of_a_second_warns(gap_s, warn):
    assert window_levels(longest_gap_s=gap_s) == ({"gap": "warn"} if warn else {})


@pytest.mark.parametrize(("coverage", "expected"), [(0.9, {}), (below(0.9), {"coverage": "warn"})])
def test_coverage_under_90_percent_warns(coverage, expected):
    assert window_levels(coverage=coverage) == expected


@pytest.mark.parametrize(("coverage", "expected"), [(0.5, {"coverage": "warn", "gap": "warn", "hands": "warn"}),
                                                    (below(0.5), {"coverage": "skip"})])
def test_coverage_under_half_skips_and_judges_nothing_else(coverage, expected):
    """A 0.5 s gap and one hand where meta.json says two: judged while the row is kept, not once it is skipped."""
    assert window_levels(meta_hands=2, coverage=coverage, longest_gap_s=0.5) == expected


@pytest.mark.parametrize(("share", "expected"), [(0.1, {}), (above(0.1), {"out_of_view": "warn"}),
                                                 (0.5, {"out_of_view": "warn"}), (above(0.5), {"out_of_view": "skip"})])
def test_out_of_view_warns_over_10_percent_and_skips_over_half(share, expected):
    assert window_levels(out_of_view=share) == expected


@pytest.mark.parametrize(("deg", "outside"), [(60.0 * (1 - EPS), False), (60.0 * (1 + EPS), True),
                                              (-60.0 * (1 - EPS), False), (-60.0 * (1 + EPS), True)])
def test_a_hand_more_than_60_deg_off_boresight_is_out_of_view(deg, outside):
    a = math.radians(deg)
    pos = np.broadcast_to([0.3 * math.sin(a), 0.0, 0.3 * math.cos(a)], (1, 1, 21, 3))
    assert bool(view_outside(pos, np.ones((1, 1), bool), GATE_M)[0, 0]) == outside


@pytest.mark.parametrize(("left_steps", "seen"), [(5000, 2), (4999, 1)])
def test_a_hand_tracked_over_half_the_window_is_present(left_steps, seen):
    """10000 window steps, the right hand throughout, the left in the first ``left_steps``: 50 % counts."""
    times = np.arange(10000) / 100.0
    seq = sequence(times, np.ones(10000, bool))
    mask = seq.mask.copy()
    mask[:left_steps, 1] = True
    window = HandSequence(seq.positions, times, mask)
    fig = window_figures(window, window, 0.0, 100.0, GATE_M)
    assert fig["hands_seen"] == seen
