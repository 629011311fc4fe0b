"""The Leap sensor model: clock offset, jitter, dropouts and calibration, seen through the file format."""

from __future__ import annotations

import json

import numpy as np
import pytest

from handradar.data.recording import load_recording, read_truth
from handradar.hand.leap import parse_leap_frame
from handradar.world.generate import RecordingSpec, simulate, write_recording
from tests.world.conftest import with_effects


def _lag(seen, true_at, grid: np.ndarray, lags: np.ndarray) -> float:
    """Lag L maximising the normalised cross-correlation of the velocities of seen(t) and true(t - L)."""
    v_seen = np.diff(seen)
    corr = [np.corrcoef(v_seen, np.diff(true_at(grid - lag)))[0, 1] for lag in lags]
    return float(lags[int(np.argmax(corr))])


@pytest.mark.parametrize("offset", [0.0, 0.045])
def test_clock_offset_shifts_the_leap_skeleton_in_time_by_the_set_amount(world, radar, tmp_path, offset):
    """What ingest reads at radar time t is the hand at true time t - offset (cross-correlated)."""
    w = with_effects(world, "sync_offset", sync_offset={"offset_s": offset, "spread_s": 0.0})
    spec = RecordingSpec("slide", 0, 0.0, 0)
    folder = write_recording(w, radar, spec, tmp_path / spec.name)
    rec = load_recording(folder)
    assert read_truth(folder)["sync_offset_s"] == pytest.approx(offset)
    sim = simulate(w, radar, spec)
    slot = sim.motion.slots[0]
    grid = np.arange(0.1, rec.duration_s - 0.1, 0.002)
    seen = rec.skeleton.resample(grid).positions[:, slot, 8, 0]  # index fingertip x as the reader sees it
    true_at = lambda t: sim.motion.pose(t).joints[:, slot, 8, 0]  # noqa: E731
    lag = _lag(seen, true_at, grid, np.arange(-0.1, 0.1, 0.001))
    assert lag == pytest.approx(offset, abs=0.0015)


def test_jitter_dropouts_and_calibration(world, radar, tmp_path):
    """Jitter has the set 3-D rms; dropped frames carry no hands at about the set rate; the true
    Leap-to-radar transform (truth) maps the raw Leap data onto the hands, the nominal one is off."""
    w = with_effects(world, "tracking_jitter", "dropouts", "calibration",
                     tracking_jitter={"rms_m": 0.005}, dropouts={"rate": 0.1},
                     calibration={"rotation_deg": 2.0, "translation_m": 0.004})
    spec = RecordingSpec("grasp", 1, 0.0, 0)
    folder = write_recording(w, radar, spec, tmp_path / spec.name)
    truth = read_truth(folder)
    meta = json.loads((folder / "meta.json").read_text())
    lines = (folder / "leap.jsonl").read_text().splitlines()
    parsed = [parse_leap_frame(json.loads(line), folder, i) for i, line in enumerate(lines, 1)]
    stamps = np.array([p[0] for p in parsed])
    mm = np.stack([p[1] for p in parsed])
    tracked = np.stack([p[2] for p in parsed])
    rate = 1e6 / np.median(np.diff(stamps))
    assert rate == pytest.approx(115.0, rel=0.01)
    dropped = ~tracked.any(1)
    assert 0.05 < dropped.mean() < 0.18 and dropped.sum() == truth["leap_dropped_frames"]
    sim = simulate(w, radar, spec)
    slot = sim.motion.slots[0]
    ok = tracked[:, slot]
    true = sim.motion.pose((stamps - meta["radar_start_us"]) * 1e-6).joints[ok, slot]

    def to_radar(m):
        m = np.asarray(m)
        return mm[ok, slot] @ m[:3, :3].T + m[:3, 3]

    err_true = np.linalg.norm(to_radar(truth["leap_to_radar_true"]) - true, axis=-1)
    err_nominal = np.linalg.norm(to_radar(meta["leap_to_radar"]) - true, axis=-1)
    assert np.sqrt((err_true ** 2).mean()) == pytest.approx(0.005, rel=0.15)
    # the calibration error adds a systematic offset on top of the jitter
    assert np.sqrt((err_nominal ** 2).mean()) > np.sqrt((err_true ** 2).mean()) + 0.001
