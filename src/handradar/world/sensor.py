"""The Leap Motion sensor model: what the rig's Leap reports of the true hands.

- clock: frames every 1/rate_hz (about 115 Hz) with timestamp jitter, covering the radar capture
  with a margin; meta.json's ``radar_start_us`` is the *nominal* radar start on the Leap clock,
  the true one is later by the sync offset (clock offset and tracking latency together), so the
  skeleton a reader maps to radar time t shows the hand at true time t - offset;
- calibration: the Leap sees the hands through the *true* Leap-to-radar transform, which differs
  from meta.json's nominal ``leap_to_radar`` by a small rotation and translation;
- tracking jitter: per-joint noise, first-order correlated in time, of a set 3-D rms;
- jitter floor (``leap.jitter_floor_m``, not an effect: on whatever the effects): white per-joint
  noise of a set 3-D rms in every frame, the sensor's static precision;
- dropouts: frames with no hands, in Markov bursts.

Frames are written with handradar.hand.leap (leap_frames_from_sequence / write_leap_jsonl).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from handradar.hand.leap import leap_frames_from_sequence
from handradar.hand.skeleton import HandSequence
from handradar.world.config import Effects, LeapSensor
from handradar.world.kinematics import Motion

# Nominal mounting: the Leap lies on the table beside the radar, 12 cm to the user's left, looking up.
# Leap axes: +x right, +y up, +z towards the user (who sits at radar -y).
_LEAP_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # radar = R @ leap
_LEAP_ORIGIN_M = np.array([-0.12, -0.02, -0.005])


def nominal_leap_to_radar() -> np.ndarray:
    """4x4 Leap-millimetres -> radar-metres matrix (meta.json ``leap_to_radar``)."""
    m = np.eye(4)
    m[:3, :3] = _LEAP_AXES * 1e-3
    m[:3, 3] = _LEAP_ORIGIN_M
    return m


@dataclass
class LeapObservation:
    """One recording's Leap stream: what the sensor measured, on its own clock."""

    stamps_us: np.ndarray  # (T,) int64 Leap timestamps
    radar_nominal: np.ndarray  # (T, 2, 21, 3) measured joints mapped with the nominal calibration, metres
    mask: np.ndarray  # (T, 2) tracked hands
    radar_start_us: int  # nominal (meta.json)
    sync_offset_s: float  # true radar start - nominal, seconds
    leap_to_radar_true: np.ndarray
    dropped: int

    def sequence(self) -> HandSequence:
        """The measured stream in the nominal radar frame, times on the nominal radar clock."""
        seq = HandSequence(self.radar_nominal, (self.stamps_us - self.radar_start_us) * 1e-6, self.mask,
                           source="world-leap")
        seq.positions = self.radar_nominal  # keep float64: the file must hold exactly the measured millimetres
        return seq

    def frames(self) -> list[dict]:
        """Leap frame dicts (handradar.hand.leap), ready for write_leap_jsonl."""
        return list(leap_frames_from_sequence(self.sequence(), np.linalg.inv(nominal_leap_to_radar()),
                                              self.radar_start_us))

    def as_read(self) -> HandSequence:
        """What read_leap_jsonl returns for the written file, without writing it: the writer rounds
        the millimetres to 3 decimals and the reader maps them with meta.json's matrix."""
        m = nominal_leap_to_radar()
        inv = np.linalg.inv(m)
        mm = (self.radar_nominal @ inv[:3, :3].T + inv[:3, 3]).round(3)  # as leap_frames_from_sequence writes
        mm[~self.mask] = 0.0  # untracked hands are absent from the file; the reader holds zeros
        radar = mm @ m[:3, :3].T + m[:3, 3]
        return HandSequence(radar.astype(np.float32), (self.stamps_us - float(self.radar_start_us)) * 1e-6,
                            self.mask, source="world-leap")


def _ar1(rng: np.random.Generator, shape: tuple[int, ...], dt: np.ndarray, tau: float) -> np.ndarray:
    """Unit-variance first-order Gauss-Markov noise along axis 0 with correlation time tau."""
    out = np.empty(shape)
    out[0] = rng.standard_normal(shape[1:])
    for k in range(1, shape[0]):
        a = math.exp(-dt[k - 1] / tau) if tau > 0 else 0.0
        out[k] = a * out[k - 1] + math.sqrt(1 - a * a) * rng.standard_normal(shape[1:])
    return out


def observe(motion: Motion, capture_s: float, leap: LeapSensor, effects: Effects,
            rng: np.random.Generator) -> LeapObservation:
    """Simulate the Leap stream of one recording."""
    start_us = int(rng.uniform(*leap.radar_start_us))
    so = effects.sync_offset
    offset = float(rng.normal(so.offset_s, so.spread_s)) if so.enabled else 0.0
    period_us = 1e6 / leap.rate_hz
    first = start_us - leap.lead_s * 1e6
    n = int(math.ceil((capture_s + 2 * leap.lead_s) * leap.rate_hz)) + 1
    stamps = first + np.arange(n) * period_us + rng.normal(0, leap.timestamp_jitter_us, n)
    k = np.arange(n)
    stamps = np.maximum.accumulate(np.rint(stamps).astype(np.int64) - k) + k  # strictly increasing
    t_reader = (stamps - start_us) * 1e-6  # what a reader computes from the nominal radar start
    pose = motion.pose(t_reader - offset)  # the hands the Leap saw at those instants

    nominal = nominal_leap_to_radar()
    true = nominal.copy()
    cal = effects.calibration
    if cal.enabled:
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        err = np.eye(4)
        err[:3, :3] = Rotation.from_rotvec(axis * np.deg2rad(rng.normal(0, cal.rotation_deg))).as_matrix()
        err[:3, 3] = rng.normal(0, cal.translation_m, 3)
        true = err @ nominal
    true_inv = np.linalg.inv(true)
    mm = pose.joints @ true_inv[:3, :3].T + true_inv[:3, 3]  # (T, 2, 21, 3) Leap millimetres
    tj = effects.tracking_jitter
    if tj.enabled:
        noise = _ar1(rng, mm.shape, np.diff(t_reader), tj.corr_time_s)
        mm = mm + noise * (tj.rms_m * 1e3 / math.sqrt(3))

    mask = np.broadcast_to(pose.present, (n, 2)).copy()
    dropped = 0
    dr = effects.dropouts
    if dr.enabled and dr.rate > 0:
        p_in = dr.rate / (dr.mean_burst * (1 - dr.rate))
        p_out = 1.0 / dr.mean_burst
        state = False
        u = rng.random(n)
        drop = np.zeros(n, dtype=bool)
        for k in range(n):
            state = u[k] < (1 - p_out if state else p_in)
            drop[k] = state
        drop[[0, -1]] = False  # readers need the span covered
        mask[drop] = False
        dropped = int(drop.sum())
    if leap.jitter_floor_m > 0:  # the sensor's own floor, on whatever the effects; drawn last, so 0 changes no draw
        mm = mm + rng.standard_normal(mm.shape) * (leap.jitter_floor_m * 1e3 / math.sqrt(3))
    # what the Leap measured, in the nominal radar frame (written back with the nominal inverse)
    radar_nominal = mm @ nominal[:3, :3].T + nominal[:3, 3]
    return LeapObservation(stamps, radar_nominal, mask, start_us, offset, true, dropped)
