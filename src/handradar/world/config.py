"""Typed configuration of the reference world (``conf/world/default.yaml``, keys under ``world.``).

Every effect has an ``enabled`` switch and physical parameters (SI units: metres, seconds, dB,
degrees where the name says so). :func:`world_config` turns a Hydra/OmegaConf node or a plain
dict into a :class:`WorldConfig`, rejecting unknown keys so that a typo in an override fails
loudly instead of silently generating the default world.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from handradar.vocab import EFFECTS as SIMULATED_EFFECTS
from handradar.vocab import GESTURES, WORLD_ONLY_EFFECTS

# Bump when the physics or the kinematics change: it enters every cache key.
WORLD_VERSION = "world/3"

# Every effect the world can switch: the simulator's vocabulary and the world-only ones (handradar.vocab).
EFFECTS = SIMULATED_EFFECTS + WORLD_ONLY_EFFECTS


@dataclass(frozen=True)
class Occlusion:
    """Ray-cast shadowing between all parts of both hands (and forearms)."""

    enabled: bool = True


@dataclass(frozen=True)
class Palm:
    """Palm (palmar face) and back of the hand as a slab of this thickness."""

    enabled: bool = True
    thickness_m: float = 0.026


@dataclass(frozen=True)
class Forearm:
    """Wrist and forearm: a truncated cone from the wrist towards an elbow fixed per recording."""

    enabled: bool = True
    length_m: float = 0.26
    radius_wrist_m: float = 0.026
    radius_elbow_m: float = 0.038


@dataclass(frozen=True)
class Multipath:
    """Double bounces: hand-table-hand (image of the hands in the table plane) and hand-hand.

    table_below_m: table plane depth below the antenna phase centre (the radar lies on it).
    table_reflection: amplitude reflection coefficient of the table (sign included).
    n_paths: strongest double-bounce paths kept per recording (by rms amplitude).
    samples_per_hand: surface facets per hand (area-weighted draw) that take part in bounces.
    """

    enabled: bool = True
    table_below_m: float = 0.01
    table_reflection: float = -0.5
    hand_hand: bool = True
    table: bool = True
    n_paths: int = 48
    samples_per_hand: int = 32


@dataclass(frozen=True)
class AntennaPattern:
    """Patch antenna power pattern cos^n(theta), n set per principal plane by the half-power beamwidth."""

    enabled: bool = True
    hpbw_az_deg: float = 64.0
    hpbw_el_deg: float = 56.0
    floor_db: float = -25.0  # back and grazing directions


@dataclass(frozen=True)
class Noise:
    """Receiver noise (complex white, SNR per ADC sample against the hand's signal) and int16 rounding."""

    enabled: bool = True
    snr_db: float = 0.0
    quantisation: bool = True


@dataclass(frozen=True)
class SyncOffset:
    """Leap-vs-radar clock offset (latency included): the true radar start on the Leap clock is
    meta.json's ``radar_start_us`` + offset; per recording offset ~ N(offset_s, spread_s)."""

    enabled: bool = True
    offset_s: float = 0.035
    spread_s: float = 0.008


@dataclass(frozen=True)
class TrackingJitter:
    """Leap joint jitter: 3-D rms per joint (metres), first-order correlated over ``corr_time_s``.

    1 mm: the Leap Motion's dynamic position error (Weichert et al., Sensors 2013: 1.2 mm dynamic,
    below 0.2 mm static; Guna et al., Sensors 2014: below 0.5 mm static). The former default of
    4 mm is kept as the preset ``world=strong_jitter`` (conf/world/strong_jitter.yaml)."""

    enabled: bool = True
    rms_m: float = 0.001
    corr_time_s: float = 0.02


@dataclass(frozen=True)
class Dropouts:
    """Leap frames with no hands: fraction ``rate`` of frames, in bursts of mean length ``mean_burst``."""

    enabled: bool = True
    rate: float = 0.03
    mean_burst: float = 3.0


@dataclass(frozen=True)
class Calibration:
    """Leap-to-radar calibration error: the true matrix differs from meta.json's nominal one by a
    rotation of ~rotation_deg (random axis) and a translation of ~translation_m per axis (rms)."""

    enabled: bool = True
    rotation_deg: float = 1.0
    translation_m: float = 0.003


@dataclass(frozen=True)
class StaticClutter:
    """TX-RX leakage and static reflectors (removed by the chain's clutter removal; they load the ADC)."""

    enabled: bool = True
    leakage_db: float = 25.0  # above the reference hand return
    leakage_range_m: float = 0.04
    reflector_ranges_m: tuple[float, ...] = (1.1, 2.3)
    reflector_db: tuple[float, ...] = (10.0, 6.0)


@dataclass(frozen=True)
class IQImbalance:
    """Receiver gain/phase imbalance: y = mu x + nu conj(x), image rejection |nu/mu|^2.

    stage ``slow_time``: applied to each range bin's slow-time signal, so the image appears at the
    mirrored Doppler in the same range bin (visible in spectrograms: the diagnosis control).
    stage ``adc``: applied to the ADC samples, where physics puts it; the image then lies at the
    mirrored range *and* Doppler, outside the default range gate.
    """

    enabled: bool = False
    gain_db: float = 1.5
    phase_deg: float = 10.0
    stage: str = "slow_time"


@dataclass(frozen=True)
class Effects:
    occlusion: Occlusion = field(default_factory=Occlusion)
    palm: Palm = field(default_factory=Palm)
    forearm: Forearm = field(default_factory=Forearm)
    multipath: Multipath = field(default_factory=Multipath)
    antenna_pattern: AntennaPattern = field(default_factory=AntennaPattern)
    noise: Noise = field(default_factory=Noise)
    sync_offset: SyncOffset = field(default_factory=SyncOffset)
    tracking_jitter: TrackingJitter = field(default_factory=TrackingJitter)
    dropouts: Dropouts = field(default_factory=Dropouts)
    calibration: Calibration = field(default_factory=Calibration)
    static_clutter: StaticClutter = field(default_factory=StaticClutter)
    iq_imbalance: IQImbalance = field(default_factory=IQImbalance)

    def enabled(self) -> list[str]:
        return [n for n in EFFECTS if getattr(self, n).enabled]

    def only(self, *names: str) -> Effects:
        """These effects on (others off), parameters unchanged."""
        unknown = set(names) - set(EFFECTS)
        if unknown:
            raise ValueError(f"unknown effect(s) {sorted(unknown)}; expected some of {EFFECTS}")
        return dataclasses.replace(self, **{n: dataclasses.replace(getattr(self, n), enabled=n in names)
                                            for n in EFFECTS})

    def with_(self, name: str, **params: Any) -> Effects:
        """A copy with effect ``name`` changed (e.g. ``with_('noise', enabled=False)``)."""
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; expected one of {EFFECTS}")
        return dataclasses.replace(self, **{name: dataclasses.replace(getattr(self, name), **params)})


@dataclass(frozen=True)
class Kinematics:
    """Per-subject and per-repetition variation of the gesture kinematics."""

    height_m: tuple[float, float] = (0.22, 0.36)  # hand centre above the radar
    hand_scale: tuple[float, float] = (0.85, 1.15)
    speed: tuple[float, float] = (0.8, 1.25)
    amplitude: tuple[float, float] = (0.8, 1.2)
    duration_s: float = 1.3  # nominal gesture duration at speed 1
    left_handed_fraction: float = 0.15
    repetition_jitter: float = 0.07  # relative duration/amplitude change between repetitions
    position_jitter_m: float = 0.015
    rotation_jitter_deg: float = 6.0
    tremor_m: float = 0.0004  # physiological tremor amplitude (8-12 Hz)
    drift_m: float = 0.0015  # slow postural drift over the capture


SCATTERING = ("surfaces", "bone_points")  # how the scene's direct returns are built (Scene.scattering)


@dataclass(frozen=True)
class BonePoints:
    """Discrete scatterers of ``scene.scattering: bone_points`` (handradar.world.points, which states
    the law): a grid of points ``spacing_m`` apart over every part, each with the monostatic RCS

        sigma_i = g_i dA_i (rcs_per_area cos(theta_i)^exponent + isotropic)   (m^2, theta_i < 90 deg),

    dA_i the area (m^2) the point stands for, g_i ~ Exponential(1) drawn once per recording."""

    spacing_m: float = 0.008  # about two wavelengths at 77 GHz
    rcs_per_area: float = 1.0  # m^2 per m^2 of skin, lobe peak (normal incidence)
    exponent: float = 2.0  # q of the cos(theta)^q lobe
    isotropic: float = 0.05  # m^2 per m^2, the same in every direction of the front half-space


@dataclass(frozen=True)
class Scene:
    """Surface tessellation, skin reflectivity and the ADC scale; ``scattering`` picks how the direct
    returns are built: ``surfaces`` (physical optics and skin texture, handradar.world.scattering) or
    ``bone_points`` (discrete scatterers with an RCS law of their own, handradar.world.points)."""

    scattering: str = "surfaces"
    points: BonePoints = field(default_factory=BonePoints)
    rate_hz: float = 100.0  # skeleton rate of the scene; motion is then interpolated to chirp times
    visibility_rate_hz: float = 50.0  # ray casting rate; visibility is interpolated linearly in between
    finger_sides: int = 6
    finger_rings: int = 1
    palm_subdivisions: int = 1
    forearm_sides: int = 8
    forearm_rings: int = 3
    # another facet layout of the same surfaces: every cylinder's facets (fingers, forearm) turned about
    # its axis by this fraction of a side, the apex of the palm's triangle fan moved around a 1 cm circle.
    # The returns are integrals over the smooth surfaces, so a relayout changes spectrograms by little
    # (benchmarks/world_convergence.py measures how little)
    facet_turn: float = 0.0
    finger_radius_m: float = 0.0085  # at the MCP, for hand scale 1; tapers to 75 % at the tip
    # physical optics: cylinder facets are cut into strips (<= 30 deg) and segments along them whose
    # near-field phase departs from linear by at most po_phase_tol_rad at po_ref_range_m (integrated to
    # second order in it); palm facets into flat triangles within half of it
    po_phase_tol_rad: float = 1.0
    po_ref_range_m: float = 0.2
    skin_reflectivity: float = 0.35  # amplitude reflectivity of the coherent (mirror-like) return, normal incidence
    # skin texture: the incoherent glossy/diffuse return, carried by points fixed on the surfaces
    texture_per_cm2: float = 1.0
    skin_diffuse: float = 0.3  # diffuse RCS per unit area (m^2 / m^2) at normal incidence
    skin_specular: float = 1.0  # glossy lobe RCS per unit area at normal incidence
    specular_exponent: float = 8.0
    ref_counts: float = 400.0  # ADC amplitude (counts) of 0.01 m^2 at 0.3 m on boresight
    prune_db: float = 60.0  # scatterers whose peak is this far below the strongest are dropped


@dataclass(frozen=True)
class LeapSensor:
    """The Leap's clock and, whatever the effects, its floor of position noise.

    jitter_floor_m: white 3-D rms position noise on every tracked joint, in every frame, independent
    of the ``tracking_jitter`` effect (the gap benchmark switches effects off; a real Leap never is
    noiseless). 0 leaves the stream as before the setting existed; ``world=scatterers`` uses 0.4 mm,
    the Leap Motion's static precision (standard deviation below 0.5 mm: Guna et al., Sensors 14(2):3702,
    2014; below 0.2 mm deviation: Weichert et al., Sensors 13(5):6380, 2013)."""

    rate_hz: float = 115.0
    timestamp_jitter_us: float = 150.0
    lead_s: float = 0.15  # Leap data start this long before the radar capture and end as long after
    radar_start_us: tuple[float, float] = (8.0e5, 2.5e6)  # nominal radar start on the Leap clock
    jitter_floor_m: float = 0.0


@dataclass(frozen=True)
class WorldConfig:
    seed: int = 0
    capture_frames: int = 24
    skeleton_rate_hz: float = 100.0
    gestures: tuple[str, ...] = GESTURES
    subjects: int = 8
    angles_deg: tuple[float, ...] = (0.0, 30.0, -30.0)
    repetitions: int = 3
    workers: int = 2
    kinematics: Kinematics = field(default_factory=Kinematics)
    scene: Scene = field(default_factory=Scene)
    leap: LeapSensor = field(default_factory=LeapSensor)
    effects: Effects = field(default_factory=Effects)

    def __post_init__(self) -> None:
        bad = [g for g in self.gestures if g not in GESTURES]
        if bad:
            raise ValueError(f"world.gestures: unknown gesture(s) {bad}; expected some of {GESTURES}")
        if self.subjects < 1 or self.repetitions < 1 or not self.angles_deg:
            raise ValueError("world.subjects and world.repetitions must be >= 1 and world.angles_deg non-empty")
        if self.scene.scattering not in SCATTERING:
            raise ValueError(f"world.scene.scattering must be one of {SCATTERING}, found {self.scene.scattering!r}")
        if self.leap.jitter_floor_m < 0 or self.scene.points.spacing_m <= 0:
            raise ValueError("world.leap.jitter_floor_m must be >= 0 and world.scene.points.spacing_m > 0")
        if self.effects.iq_imbalance.stage not in ("slow_time", "adc"):
            raise ValueError(f"world.effects.iq_imbalance.stage must be 'slow_time' or 'adc', "
                             f"found {self.effects.iq_imbalance.stage!r}")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _like(default: Any, value: Any) -> Any:
    """Integers given for float fields become floats (3 and 3.0 must hash alike)."""
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _build(cls: type, data: Mapping, where: str) -> Any:
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(data) - set(fields)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {sorted(unknown)}; expected some of {sorted(fields)}")
    kwargs = {}
    for name, value in data.items():
        default = fields[name].default_factory() if fields[name].default_factory is not dataclasses.MISSING \
            else fields[name].default
        if dataclasses.is_dataclass(default):
            if not isinstance(value, Mapping):
                raise ValueError(f"{where}.{name}: expected a mapping, found {value!r:.60}")
            kwargs[name] = _build(type(default), value, f"{where}.{name}")
        elif isinstance(default, tuple):
            kwargs[name] = tuple(_like(default[0], v) if default else v for v in value)
        else:
            kwargs[name] = _like(default, value)
    return cls(**kwargs)


def world_config(cfg: Any = None) -> WorldConfig:
    """A WorldConfig from a DictConfig / dict (keys of ``world.``), a WorldConfig, or None (defaults)."""
    if cfg is None:
        return WorldConfig()
    if isinstance(cfg, WorldConfig):
        return cfg
    try:
        from omegaconf import DictConfig, OmegaConf

        if isinstance(cfg, DictConfig):
            cfg = OmegaConf.to_container(cfg, resolve=True)
    except ImportError:  # pragma: no cover - omegaconf is a dependency
        pass
    data = {k: v for k, v in dict(cfg).items() if k != "_target_"}
    return _build(WorldConfig, data, "world")
