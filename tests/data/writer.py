"""An independent writer of ``handradar.recording/1`` folders, for tests.

It follows docs/architecture.md, "Recording format" literally and uses none of handradar's own writers or signal models:
radar.cfg as text, adc_data.bin mixed from the transmitted chirp and its echo and packed by hand
(I(n) I(n+1) Q(n) Q(n+1), RX-major), leap.jsonl
lines and meta.json with the json module. The scene is a rigid right hand, palm down over the
radar, whose centre moves straight along boresight at a known velocity; the radar sees one point
reflector at the hand centre. The hand holds still, moves at constant velocity for 1.6 s (one
spectrogram window), then holds still again.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tests.hand.template import TEMPLATE_RIGHT, rotation

C = 299_792_458.0
# the default radar of docs/architecture.md, "Processing chain and simulator", with a finite number of frames
F0_HZ, IDLE_S, ADC_START_S, RAMP_END_S, SLOPE_HZ_S = 77e9, 338.8e-6, 6e-6, 51.2e-6, 76.22e12
N_SAMPLES, FS_HZ, N_LOOPS, PERIOD_S = 256, 10e6, 128, 0.1


def cfg_text(n_frames: int, n_rx: int = 1) -> str:
    return ("% written by the test's independent writer\n"
            "sensorStop\nflushCfg\ndfeDataOutputMode 1\n"
            f"channelCfg {(1 << n_rx) - 1} 1 0\n"
            "adcCfg 2 1\n"
            "adcbufCfg -1 0 1 1 1\n"
            "profileCfg 0 77 338.8 6 51.2 0 0 76.22 1 256 10000 0 0 30\n"
            "chirpCfg 0 0 0 0 0 0 0 1\n"
            f"frameCfg 0 0 128 {n_frames} 100 1 0\n"
            "guiMonitor -1 1 1 0 0 0 1\n"
            "sensorStart\n")


def chirp_times(n_frames: int) -> np.ndarray:
    """(frames, loops) sampling-centre time of every chirp, from the raw numbers."""
    f = np.arange(n_frames)[:, None]
    k = np.arange(N_LOOPS)[None, :]
    return f * PERIOD_S + k * (IDLE_S + RAMP_END_S) + ADC_START_S + N_SAMPLES / FS_HZ / 2


def wavelength() -> float:
    """Wavelength at the centre of the sampled sweep: the Doppler scale after the range FFT."""
    return C / (F0_HZ + SLOPE_HZ_S * (ADC_START_S + N_SAMPLES / FS_HZ / 2))


def tx_phase_cycles(t: np.ndarray) -> np.ndarray:
    """Phase (cycles) of the transmitted chirp t seconds after its ramp starts: f0 t + S t^2 / 2."""
    return F0_HZ * t + 0.5 * SLOPE_HZ_S * t ** 2


def if_signal(ranges_m: np.ndarray, amplitude: float, *, swap_iq: bool = False,
              mirror_doppler: bool = False) -> np.ndarray:
    """One reflector at ``ranges_m`` (any shape, held during each chirp) -> (..., N_SAMPLES) complex
    IF samples, by literally mixing the paper's S_TX(t) with its echo S_RX(t) = S_TX(t - tau), tau =
    2 R / c: IF = S_TX conj(S_RX), sampled at t = adcStart + n / fs after each ramp start.
    ``swap_iq``: I and Q exchanged, as some capture configurations deliver them. ``mirror_doppler``:
    the carrier phase 2 pi tau (f0 + S adcStart) negated, the fast-time tone kept (a wrong convention)."""
    t = ADC_START_S + np.arange(N_SAMPLES) / FS_HZ
    tau = 2 * np.asarray(ranges_m, dtype=np.float64)[..., None] / C
    sig = amplitude * np.exp(2j * np.pi * (tx_phase_cycles(t) - tx_phase_cycles(t - tau)))
    if mirror_doppler:
        sig = sig * np.exp(-4j * np.pi * tau * (F0_HZ + SLOPE_HZ_S * ADC_START_S))
    return sig.imag + 1j * sig.real if swap_iq else sig


def adc_bytes(ranges_m: np.ndarray, amplitude: float, *, swap_iq: bool = False, mirror_doppler: bool = False,
              rx_gains: tuple[float, ...] = (1.0,), noise_counts: float = 0.0, seed: int = 0) -> bytes:
    """One reflector at ``ranges_m`` (frames, loops) -> DCA1000 bytes, one RX per entry of ``rx_gains``
    (its amplitude factor; 0: a dead channel), RX-major within each chirp. ``noise_counts``: rms (ADC
    counts) of white Gaussian receiver noise added to I and to Q alike, drawn from ``seed``."""
    sig = if_signal(ranges_m, amplitude, swap_iq=swap_iq, mirror_doppler=mirror_doppler)
    sig = sig[..., None, :] * np.asarray(rx_gains, dtype=np.float64)[:, None]  # (frames, loops, rx, samples)
    if noise_counts:  # circular white noise: the same before and after an I/Q exchange
        rng = np.random.default_rng(seed)
        sig = sig + noise_counts * (rng.standard_normal(sig.shape) + 1j * rng.standard_normal(sig.shape))
    i = np.rint(sig.real).astype("<i2").reshape(-1, N_SAMPLES // 2, 2)
    q = np.rint(sig.imag).astype("<i2").reshape(-1, N_SAMPLES // 2, 2)
    return np.concatenate([i, q], axis=-1).tobytes()  # I(n) I(n+1) Q(n) Q(n+1)


# Leap mm -> radar m: radar (x, y, z) = 1e-3 (Leap x, -Leap z, Leap y) + (0.01, -0.02, 0.05)
LEAP_TO_RADAR = [[0.001, 0.0, 0.0, 0.01], [0.0, 0.0, -0.001, -0.02], [0.0, 0.001, 0.0, 0.05], [0.0, 0.0, 0.0, 1.0]]
HAND_ROT = rotation("x", 180)  # template palm (+z) turned to face the radar (-z); fingers toward -y


@dataclass
class Scene:
    gesture: str = "grasp"
    subject: str = "s01"
    angle_deg: float = 0.0
    occlusion: bool = False
    repetition: int = 1
    n_frames: int = 24
    z0_m: float = 0.50  # hand centre height before the motion
    velocity_m_s: float = -0.15  # along boresight; negative approaches the radar
    move_span_s: tuple[float, float] = (0.6, 2.2)  # still before and after: the motion fills frames 6..21
    amplitude: float = 3000.0
    radar_start_us: int = 2_000_000
    leap_rate_hz: float = 100.0
    leap_span_s: tuple[float, float] = (-0.1, 2.5)
    leap_scale: float = 1.0  # multiplies the Leap coordinates written (0.001: metres instead of millimetres)
    swap_iq: bool = False  # I and Q exchanged in adc_data.bin
    mirror_doppler: bool = False  # carrier phase of the wrong sign (if_signal)
    x0_m: float = 0.0  # hand centre across boresight (radar x)
    rx_gains: tuple[float, ...] = (1.0,)  # one RX channel per entry, its amplitude factor (0: dead)
    noise_counts: float = 0.0  # rms receiver noise on I and on Q (ADC counts), seeded by the repetition
    extra_meta: dict = field(default_factory=dict)

    def centre(self, t: np.ndarray) -> np.ndarray:
        a, b = self.move_span_s
        z = self.z0_m + self.velocity_m_s * (np.clip(t, a, b) - a)
        return np.stack([np.full_like(t, self.x0_m), np.zeros_like(t), z], axis=-1)

    def joints(self, t: np.ndarray) -> np.ndarray:
        """(len(t), 21, 3) radar-frame joints; the template's hand centre rides on ``centre(t)``."""
        tpl = TEMPLATE_RIGHT @ HAND_ROT.T
        tpl = tpl - tpl[[0, 5, 9, 13, 17]].mean(axis=0)
        return tpl[None] + self.centre(t)[:, None, :]


def leap_frame(i: int, ts_us: int, joints_radar: np.ndarray, scale: float = 1.0) -> dict:
    m = np.array(LEAP_TO_RADAR)
    mm = scale * ((joints_radar - m[:3, 3]) @ np.linalg.inv(m[:3, :3]).T)
    r = lambda v: [round(float(x), 4) for x in v]  # noqa: E731
    hand = {"id": 3, "type": "right", "palmPosition": r(mm[[0, 5, 9, 13, 17]].mean(0)), "palmNormal": [0, -1, 0],
            "direction": [0, 0, -1], "palmWidth": 80.0, "wrist": r(mm[0]), "elbow": r(mm[0] + [0, -50, 200])}
    pointables = []
    for f in range(5):
        j = mm[1 + 4 * f: 5 + 4 * f]
        carp = j[0] if f == 0 else mm[0] + 0.3 * (j[0] - mm[0])
        pointables.append({"handId": 3, "type": f, "width": 18.0, "carpPosition": r(carp), "mcpPosition": r(j[0]),
                           "pipPosition": r(j[1]), "dipPosition": r(j[2]), "btipPosition": r(j[3])})
    return {"id": i, "timestamp": ts_us, "currentFrameRate": 100.0, "hands": [hand], "pointables": pointables}


def write_recording(folder: Path, scene: Scene) -> Path:
    folder.mkdir(parents=True)
    (folder / "radar.cfg").write_text(cfg_text(scene.n_frames, len(scene.rx_gains)))
    ranges = np.linalg.norm(scene.centre(chirp_times(scene.n_frames)), axis=-1)
    (folder / "adc_data.bin").write_bytes(adc_bytes(ranges, scene.amplitude, swap_iq=scene.swap_iq,
                                                              mirror_doppler=scene.mirror_doppler,
                                                              rx_gains=scene.rx_gains,
                                                              noise_counts=scene.noise_counts, seed=scene.repetition))
    t = np.arange(scene.leap_span_s[0], scene.leap_span_s[1], 1 / scene.leap_rate_hz)
    joints = scene.joints(t)
    with (folder / "leap.jsonl").open("w") as fh:
        for i, (ti, j) in enumerate(zip(t, joints)):
            fh.write(json.dumps(leap_frame(i, int(round(scene.radar_start_us + ti * 1e6)), j, scene.leap_scale)) + "\n")
    meta = {"format": "handradar.recording/1", "gesture": scene.gesture, "subject": scene.subject,
            "angle_deg": scene.angle_deg, "hands": 1, "occlusion": scene.occlusion, "repetition": scene.repetition,
            "radar_start_us": scene.radar_start_us, "leap_to_radar": LEAP_TO_RADAR, **scene.extra_meta}
    (folder / "meta.json").write_text(json.dumps(meta, indent=1))
    return folder


def expected_doppler_row(velocity_m_s: float, stft_len: int = 64) -> int:
    """Row of a reflector moving at ``velocity_m_s`` along the line of sight (negative: approaching):
    rows ordered by the echo's Doppler shift 2 v / lambda, approaching above the centre row."""
    f_d = -2 * velocity_m_s / wavelength()
    return int(round(f_d * stft_len * (IDLE_S + RAMP_END_S))) + stft_len // 2

