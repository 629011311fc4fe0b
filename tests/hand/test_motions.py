"""The motion library (handradar.hand.motions): each motion's kinematics against its definition, and
the frame-based Doppler chain the measured datasets use, against the closed-form Doppler row."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from handradar.data.skeletons import motions_items, source_classes
from handradar.hand.motions import (
    FOREARM_M,
    MOTIONS,
    SWIPE_M,
    UPPER_ARM_M,
    MotionDraw,
    elbow_ik,
    motion_sequence,
)
from handradar.radar.chain import ChainConfig, spectrogram_from_profiles, velocity_axis_m_s
from handradar.radar.config import RadarConfig

CENTRE = [0, 5, 9, 13, 17]


def centre(name: str, **draw) -> np.ndarray:
    seq = motion_sequence(name, MotionDraw(**draw))
    return seq.positions[:, 0, CENTRE].mean(axis=1)


@pytest.mark.parametrize("name, axis, sign", [("swipe_left", 0, -1), ("swipe_right", 0, 1), ("swipe_up", 1, 1),
                                              ("swipe_down", 1, -1)])
@pytest.mark.parametrize("wrist_share", [0.0, 0.3])
def test_swipes_travel_their_length_across_the_forearm(name, axis, sign, wrist_share):
    """The hand centre's chord is the swipe's length; it runs along the swipe's axis where that crosses the forearm
    (left / right: within 3 % of the length; the wrist turns about the elbow's axis, not quite across the hand), and a vertical swipe, which has the forearm's tilt in its plane, also
    moves along the line of sight: up away from the radar, down toward it (the lopsided sweep)."""
    c = centre(name, amplitude=1.2, wrist_share=wrist_share, forearm_deg=70.0, azimuth_deg=0.0)
    travel = c[-1] - c[0]
    assert np.linalg.norm(travel) == pytest.approx(SWIPE_M * 1.2, abs=1e-4)
    assert sign * travel[axis] > 0.5 * SWIPE_M * 1.2
    if axis == 0:
        assert np.abs(travel[1:]).max() < 0.03 * SWIPE_M * 1.2
    else:
        assert sign * travel[2] > 0.1 * SWIPE_M * 1.2 and abs(travel[0]) < 0.03 * SWIPE_M * 1.2


def test_an_elbow_out_to_the_side_turns_horizontal_swipes_lopsided():
    """A right elbow turned out to the right: the forearm swings the hand left and away from the radar, right and
    toward it, by the same range change; with the elbow behind the hand (0 deg) the range ends where it began."""
    def range_change(name: str, out_deg: float) -> float:
        c = centre(name, elbow_out_deg=out_deg, forearm_deg=75.0, azimuth_deg=0.0, distance_m=0.2)
        return float(np.linalg.norm(c[-1]) - np.linalg.norm(c[0]))
    left, right = range_change("swipe_left", 30.0), range_change("swipe_right", 30.0)
    assert left > 0.03 and right == pytest.approx(-left, abs=1e-4)
    assert abs(range_change("swipe_left", 0.0)) < 0.01


def test_a_swipe_swings_the_hand_about_a_fixed_elbow():
    """wrist_share 0: every joint keeps its distance from the elbow (a rigid swing), the elbow and shoulder stay, and
    the forearm and upper arm keep their lengths; the palm faces the radar mid-swing and turns away toward the ends."""
    draw = MotionDraw(hand_scale=1.1, forearm_deg=80.0, azimuth_deg=0.0)
    seq = motion_sequence("swipe_right", draw)
    elbow, shoulder = seq.arm[:, 0, 0], seq.arm[:, 0, 1]
    assert np.ptp(elbow, axis=0).max() < 1e-6 and np.ptp(shoulder, axis=0).max() < 1e-6
    reach = np.linalg.norm(seq.positions[:, 0] - elbow[:, None], axis=-1)
    assert np.ptp(reach, axis=0).max() < 1e-5
    assert reach[0, 0] == pytest.approx(FOREARM_M * 1.1, rel=1e-5)
    assert np.linalg.norm(shoulder[0] - elbow[0]) == pytest.approx(UPPER_ARM_M * 1.1, rel=1e-5)
    j = seq.positions[:, 0].astype(np.float64)
    normal = np.cross(j[:, 5] - j[:, 0], j[:, 17] - j[:, 0])
    facing = np.abs((normal * j[:, 0]).sum(-1)) / np.linalg.norm(normal, axis=-1) / np.linalg.norm(j[:, 0], axis=-1)
    mid = int(round(draw.onset * len(facing)))
    assert facing[mid] > 0.97 and facing[0] < facing[mid] - 0.05 and facing[-1] < facing[mid] - 0.05


def test_the_elbow_follows_the_hand_by_two_link_inverse_kinematics():
    """Motions that move the hand itself (a push, a circle): the shoulder stays, the upper arm and the forearm keep
    their lengths while the wrist is within reach, and the elbow stays on the side of its rest pose."""
    for name in ("push", "pull", "circle_cw"):
        seq = motion_sequence(name, MotionDraw(forearm_deg=70.0))
        wrist, elbow, shoulder = seq.positions[:, 0, 0], seq.arm[:, 0, 0], seq.arm[:, 0, 1]
        assert np.ptp(shoulder, axis=0).max() < 1e-6
        assert np.allclose(np.linalg.norm(elbow - shoulder, axis=-1), UPPER_ARM_M, atol=1e-5)
        assert np.allclose(np.linalg.norm(wrist - elbow, axis=-1), FOREARM_M, atol=1e-5)
        assert np.ptp(elbow, axis=0).max() > 0.01  # the elbow moves with the hand
    wrist = np.array([[0.0, 0.0, 1.0]])  # beyond reach: the arm points straight at it
    e = elbow_ik(wrist, np.zeros(3), 0.3, 0.26, np.array([0.0, 1.0, 0.0]))
    assert e[0] == pytest.approx([0.0, 0.0, 0.3], abs=1e-6)


def test_push_and_pull_move_along_the_line_of_sight():
    for name, sign in (("push", -1), ("pull", 1)):
        c = centre(name, distance_m=0.3, azimuth_deg=30.0)
        r = np.linalg.norm(c, axis=1)
        assert r[-1] - r[0] == pytest.approx(sign * SWIPE_M, abs=1e-3)
        direction = c[-1] - c[0]
        sight = np.array([np.sin(np.radians(30)), 0, np.cos(np.radians(30))])
        assert abs(direction @ sight) == pytest.approx(np.linalg.norm(direction), rel=1e-5)


def test_minimum_jerk_timing_follows_speed():
    """A swipe lasts 0.5 s / speed: 99 % of its travel happens inside that span around its middle."""
    for speed in (0.5, 1.0, 2.0):
        seq = motion_sequence("swipe_right", MotionDraw(speed=speed, onset=0.5), duration_s=3.0)
        x = seq.positions[:, 0, 0, 0]
        moving = np.flatnonzero(np.abs(np.diff(x)) > 1e-9)
        span = (moving[-1] - moving[0] + 1) / 100.0
        assert span == pytest.approx(0.5 / speed, abs=0.02)


def test_taps_flex_the_index_toward_the_radar_and_keep_bone_lengths():
    for name, dips in (("tap", 1), ("double_tap", 2)):
        seq = motion_sequence(name, MotionDraw(azimuth_deg=0.0))
        tip_z = seq.positions[:, 0, 8, 2]
        assert tip_z.min() < tip_z[0] - 0.02            # toward the radar (below the hand, -z)
        minima = np.flatnonzero((tip_z[1:-1] < tip_z[:-2]) & (tip_z[1:-1] <= tip_z[2:]) & (tip_z[1:-1] < tip_z[0] - 0.01))
        assert len(minima) == dips
        lengths = seq.bone_lengths()[:, 0]
        assert np.ptp(lengths, axis=0).max() < 1e-5     # a rigid skeleton: only joint angles change
        assert np.ptp(seq.positions[:, 0, 0], axis=0).max() < 1e-7  # the wrist stays


def test_pinch_closes_thumb_and_index():
    seq = motion_sequence("pinch", MotionDraw())
    gap = np.linalg.norm(seq.positions[:, 0, 4] - seq.positions[:, 0, 8], axis=-1)
    assert gap.min() < 0.5 * gap[0] and gap[-1] == pytest.approx(gap[0], abs=1e-6)


@pytest.mark.parametrize("hold_s", [0.0, 0.4])
def test_a_pinch_holds_closed_for_hold_s_between_closing_and_opening(hold_s):
    """hold_s: the tips stay closed (their gap unchanged) for hold_s, between a closing and an opening of 0.3 s /
    speed each, centred on the onset: the whole pinch lasts 0.6 s / speed + hold_s."""
    speed = 0.75
    seq = motion_sequence("pinch", MotionDraw(speed=speed, hold_s=hold_s, onset=0.5), duration_s=3.0)
    gap = np.linalg.norm(seq.positions[:, 0, 4] - seq.positions[:, 0, 8], axis=-1).astype(np.float64)
    closed = np.flatnonzero(gap < gap.min() + 1e-6)
    assert (closed[-1] - closed[0]) / 100.0 == pytest.approx(hold_s, abs=0.03)
    moving = np.flatnonzero(np.abs(np.diff(gap)) > 1e-7)
    assert (moving[-1] - moving[0] + 1) / 100.0 == pytest.approx(0.6 / speed + hold_s, abs=0.03)
    assert (moving[-1] + moving[0] + 1) / 2 / 100.0 == pytest.approx(1.5, abs=0.02)


@pytest.mark.parametrize("name, taps", [("tap", 1), ("double_tap", 2), ("pinch", 1)])
def test_wrist_flexion_turns_the_hand_rigidly_about_the_wrist(name, taps):
    """wrist_flex_deg: the hand turns about the wrist as a rigid body, palm-ward (the fingers toward the radar, -z),
    by that angle at the finger's peak; the middle fingertip (which no tap or pinch moves) then runs on a circle of
    radius L about the wrist, and its peak speed is the closed form of a 1 - cos bump of angle theta over T
    seconds: omega_max L = theta pi L / T (T = 0.3 s a tap at speed 1, 0.6 s a pinch)."""
    theta, speed = 20.0, 0.8
    still = motion_sequence(name, MotionDraw(azimuth_deg=0.0, speed=speed)).positions[:, 0].astype(np.float64)
    bent = motion_sequence(name, MotionDraw(azimuth_deg=0.0, speed=speed, wrist_flex_deg=theta)).positions[:, 0]
    bent = bent.astype(np.float64)
    wrist = bent[:, 0]
    assert np.abs(wrist - still[:, 0]).max() < 1e-6                        # the wrist stays where it was
    dist = np.linalg.norm(bent - wrist[:, None], axis=-1) - np.linalg.norm(still - still[:, :1], axis=-1)
    assert np.abs(dist).max() < 1e-5                                       # every joint keeps its distance
    rest, tip = still[:, 12] - still[:, :1][:, 0], bent[:, 12] - wrist
    turned = np.degrees(np.arccos(np.clip((rest * tip).sum(-1) / np.linalg.norm(rest, axis=-1)
                                          / np.linalg.norm(tip, axis=-1), -1, 1)))
    assert turned.max() == pytest.approx(theta, abs=0.05)
    assert bent[:, 12, 2].min() < still[:, 12, 2].min() - 0.01             # toward the radar
    length = np.linalg.norm(rest[0])
    period = (0.3 if name != "pinch" else 0.6) / speed
    tip_speed = np.linalg.norm(np.diff(bent[:, 12], axis=0), axis=-1) * 100.0  # 100 Hz steps
    assert tip_speed.max() == pytest.approx(np.deg2rad(theta) * np.pi * length / period, rel=0.02)
    peaks = np.flatnonzero((turned[1:-1] > turned[:-2]) & (turned[1:-1] >= turned[2:]) & (turned[1:-1] > theta / 2))
    assert len(peaks) == taps


def test_circles_turn_opposite_ways():
    """circle_ccw turns counter-clockwise in the (x, z) plane (x right, z up): its velocity turns left, the
    cross product of consecutive velocities is positive wherever it moves; circle_cw the opposite."""
    def turning(name: str) -> np.ndarray:
        c = centre(name, azimuth_deg=0.0)
        v = np.diff(c[:, [0, 2]], axis=0)
        cross = v[:-1, 0] * v[1:, 1] - v[:-1, 1] * v[1:, 0]
        return cross[np.linalg.norm(v[:-1], axis=1) > 1e-5]
    ccw, cw = turning("circle_ccw"), turning("circle_cw")  # float32 joints: a step may read exactly 0
    assert np.all(ccw >= 0) and np.mean(ccw > 0) > 0.95 and np.all(cw <= 0) and np.mean(cw < 0) > 0.95


def test_tremor_rides_on_any_motion():
    """tremor_mm: the motion plus, on each axis, a sinusoid of that amplitude (mm) at 8-12 Hz."""
    still = centre("push")
    shaky = centre("push", tremor_mm=0.5)
    d = (shaky - still).astype(np.float64)
    assert np.abs(d).max() == pytest.approx(0.5e-3, rel=0.02)
    spectrum = np.abs(np.fft.rfft(d, axis=0))
    peak_hz = np.fft.rfftfreq(len(d), 1 / 100.0)[spectrum.argmax(axis=0)]
    assert np.all((peak_hz >= 7.7) & (peak_hz <= 12.3))  # 8-12 Hz within the 0.31 Hz resolution of 3.2 s


def test_a_single_value_range_draws_nothing():
    """A field added to the draws later (tremor_mm) leaves every existing draw as it was while its range is one value."""
    one = MotionDraw.draw(np.random.default_rng(3))
    two = MotionDraw.draw(np.random.default_rng(3), {"tremor_mm": (0.5, 0.5)})
    assert one.tremor_mm == 0.0 and two.tremor_mm == 0.5
    assert {**vars(one), "tremor_mm": None} == {**vars(two), "tremor_mm": None}
    three = MotionDraw.draw(np.random.default_rng(3), {"tremor_mm": (0.2, 1.0)})
    assert 0.2 <= three.tremor_mm <= 1.0


def test_idle_is_still_and_random_moves_a_little():
    idle = centre("idle")
    assert np.ptp(idle, axis=0).max() < 0.003
    wander = np.ptp(centre("random"), axis=0).max()
    assert 0.005 < wander < 0.1


def test_every_motion_is_a_valid_sequence_and_draws_are_reproducible():
    rng = np.random.default_rng(0)
    for name in MOTIONS:
        seq = motion_sequence(name, MotionDraw.draw(rng), duration_s=1.0, rate_hz=50.0)
        assert seq.positions.shape == (50, 2, 21, 3) and seq.mask[:, 0].all() and not seq.mask[:, 1].any()
        assert seq.arm.shape == (50, 2, 2, 3) and not seq.arm[:, 1].any()
        window = seq.resample(seq.times[:10] + 0.01)  # halfway between steps: the arm travels with the skeleton
        assert np.allclose(window.arm[:, 0], 0.5 * (seq.arm[:10, 0] + seq.arm[1:11, 0]), atol=1e-6)
    with pytest.raises(ValueError, match="unknown motion 'wave'"):
        motion_sequence("wave", MotionDraw())
    with pytest.raises(ValueError, match="unknown motion parameter 'size'"):
        MotionDraw.draw(rng, {"size": (1, 2)})
    classes = {"a": ["push", "pull"], "b": "tap"}
    one = [it.sequence.positions for it in motions_items(classes=classes, per_class=3, seed=5)]
    two = [it.sequence.positions for it in motions_items(classes=classes, per_class=3, seed=5)]
    assert all(np.array_equal(p, q) for p, q in zip(one, two))
    assert source_classes("motions", classes=classes) == ("a", "b")
    items = list(motions_items(classes=classes, per_class=4, seed=5))
    assert [it.meta["motion"] for it in items[:4]] == ["push", "pull", "push", "pull"]  # each of a class's motions in turn


@pytest.mark.parametrize("v_share", [0.25, -0.5, 0.75])
def test_frame_based_doppler_row_is_the_closed_form(v_share):
    """Frame-based Doppler (stft_len = stft_hop = loops per frame, one column a frame): a reflector at radial speed
    v (approaching > 0) has IF slow-time phase -4 pi v t / lambda (docs/architecture.md, sign convention), so its
    row is n/2 + (2 v / lambda) n T_loop = n/2 + (v / v_max) n / 2 (TI SWRA553: v_max = lambda / (4 T_loop))."""
    radar = RadarConfig(start_freq_hz=77e9, idle_time_s=400e-6, adc_start_time_s=6e-6, ramp_end_time_s=51.2e-6,
                        slope_hz_per_s=76.22e12, n_samples=256, sample_rate_hz=10e6, n_loops=32, frame_period_s=0.05)
    chain = ChainConfig(stft_len=32, stft_hop=32, n_columns=8, clutter_removal=False)
    v = v_share * radar.max_velocity_m_s
    t = radar.chirp_times_s(8)[:, :, 0]                                  # (frames, loops)
    phase = -4 * np.pi * v * t / radar.wavelength_m
    profiles = torch.as_tensor(np.exp(1j * phase))[:, :, None, None]    # (frames, loops, 1 channel, 1 bin)
    spec = spectrogram_from_profiles(profiles, chain).numpy()
    assert spec.shape == (32, 8)
    expected = 32 // 2 + v_share * 32 / 2
    assert np.all(np.argmax(spec, axis=0) == round(expected))
    assert velocity_axis_m_s(radar, chain)[round(expected)] == pytest.approx(v, abs=1e-9)
