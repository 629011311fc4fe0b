"""What a measured dataset's manifest may leave unknown, defined once (docs/datasets.md#fitting-what-the-manifest-leaves-unknown).

Each :class:`Unknown` names its manifest key, its kind, the fit's default candidates and its stage (:data:`STAGES`):
a ``radar`` unknown (the chirp set-up, the range handling) needs a simulation per candidate, searched over every
combination; a ``finish`` unknown is applied to rows simulated at a deep dB floor, approaching high, by the default
processing (handradar.synthesis.measured.finish_rows), and costs no simulation; a ``motion`` unknown moves one draw
range of the motion library (handradar.hand.motions.DEFAULT_RANGES, or the manifest's ``motion_ranges``: the prior)
by a factor or a shift, and is searched one at a time at the chosen radar and finish (a simulation a candidate).
The manifest (handradar.data.measured) checks a stated value's kind here, the job (``synth.measured.unknowns`` /
``fit.grid``, handradar.tasks.measured) sets or widens one by its name, the fit
(handradar.synthesis.measured.fit_unknowns) reads the stages, the tables read the fitted values
(``synth.fitted.<name>``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from handradar.radar.chain import NORMALISATIONS, QUANTITIES, RANGE_MODES, SCALES

STAGES = {  # how the fit searches an unknown's candidates
    "radar": "a simulation each; every combination with the other radar unknowns",
    "finish": "applied to the simulated rows; every combination",
    "motion": "a simulation each; one unknown at a time, at the chosen radar and finish",
}
MOVES = ("factor", "shift")  # how a motion unknown moves its draw range: multiplied, or added to


@dataclass(frozen=True)
class Unknown:
    """One unknown: ``manifest`` its key (``section.field``; empty: a nuisance no manifest states), ``kind``
    ``number`` (> 0 where a manifest states it), ``count`` or ``choice`` (of ``choices``), ``grid`` the fit's default
    candidates (None: absent, e.g. no noise), ``stage`` how the fit searches it (:data:`STAGES`); a motion unknown
    names the draw range it moves (``motion``, a handradar.hand.motions.MotionDraw field) and how (``move``,
    :data:`MOVES`): its value 1 (factor) or 0 (shift) keeps the prior range."""

    name: str
    manifest: str
    kind: str
    grid: tuple
    stage: str
    doc: str
    choices: tuple[str, ...] = ()
    motion: str = ""
    move: str = ""

    def __post_init__(self) -> None:
        if self.stage not in STAGES or (self.stage == "motion") != (self.move in MOVES):
            raise ValueError(f"unknown {self.name!r}: stage {self.stage!r}, move {self.move!r}")

    def check(self, value: object) -> str | None:
        """Why a manifest's stated ``value`` is not one of this unknown's, or None."""
        if self.kind == "choice":
            return None if value in self.choices else f"must be one of {list(self.choices)} or unknown"
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0
        if self.kind == "count":
            ok = ok and float(value) == int(value)
        return None if ok else f"must be a positive {'whole ' if self.kind == 'count' else ''}number or unknown"

    @property
    def numeric(self) -> bool:
        return self.kind != "choice"

    @property
    def identity(self) -> float | None:
        """A motion unknown's value that keeps its prior range (1 for a factor, 0 for a shift); None otherwise."""
        return {"factor": 1.0, "shift": 0.0}.get(self.move)

    def keeps_prior(self, value: object) -> bool:
        """Whether ``value`` of a motion unknown leaves its draw range as the prior has it."""
        return value is not None and float(value) == self.identity

    def moved(self, prior: tuple[float, float], value: float) -> tuple[float, float]:
        """A motion unknown's draw range: the ``prior`` (lo, hi) multiplied by ``value`` (factor) or shifted by it
        (shift; a range of a non-negative field, tremor, stays at or above 0)."""
        lo, hi = map(float, prior)
        if self.move == "factor":
            return lo * value, hi * value
        floor = 0.0 if lo >= 0.0 else -np.inf
        return max(lo + value, floor), max(hi + value, floor)


UNKNOWNS: dict[str, Unknown] = {u.name: u for u in (
    Unknown("v_max_m_s", "radar.v_max_m_s", "number", (0.7, 1.0, 1.5, 2.0, 3.0), "radar",
            "the Doppler axis's edge, m/s (the chirp loop's period)"),
    Unknown("frame_period_s", "radar.frame_period_s", "number", (0.025, 0.035, 0.05, 0.07, 0.1, 0.14), "radar",
            "time a column, s"),
    Unknown("chirps_per_frame", "radar.chirps_per_frame", "count", (16, 32, None), "radar",
            "chirp loops a frame (None: as many as the Doppler FFT's bins); fewer widen every Doppler line"),
    Unknown("noise_db", "", "number", (None, -60.0, -50.0, -40.0, -30.0, -20.0), "finish",
            "receiver noise a pixel, dB below each row's noise-free peak (None: none)"),
    Unknown("noise_looks", "", "count", (1,), "finish", "cells averaged into a pixel's noise (range bins, antennas)"),
    Unknown("dynamic_range_db", "radar.dynamic_range_db", "number", (20.0, 30.0, 40.0, 50.0, 60.0), "finish",
            "the dB floor below the reference"),
    Unknown("approaching", "axes.approaching", "choice", ("high", "low"), "finish",
            "which end of the Doppler axis is approaching", choices=("high", "low")),
    Unknown("range", "processing.range", "choice", RANGE_MODES, "radar",
            "how the range bins become one image: their sum, or each frame's strongest", choices=RANGE_MODES),
    Unknown("scale", "processing.scale", "choice", SCALES, "finish", "db or linear", choices=SCALES),
    Unknown("quantity", "processing.quantity", "choice", QUANTITIES, "finish",
            "power or magnitude (the same image in dB)", choices=QUANTITIES),
    Unknown("normalise", "processing.normalise", "choice", ("image", "frame"), "finish",
            "each image to its peak, or each column (frame) to its own", choices=NORMALISATIONS),
    # the users and the set-up, shared by every class (docs/datasets.md#fitting-the-motions)
    Unknown("speed_factor", "", "number", (0.67, 1.0, 1.5), "motion", "the motions' speed, times the prior's",
            motion="speed", move="factor"),
    Unknown("tremor_shift_mm", "", "number", (-0.5, 0.0, 0.5), "motion", "the hand's tremor, mm over the prior's",
            motion="tremor_mm", move="shift"),
    Unknown("azimuth_shift_deg", "", "number", (-15.0, 0.0, 15.0), "motion",
            "the path's offset from boresight, degrees over the prior's", motion="azimuth_deg", move="shift"),
    Unknown("distance_factor", "", "number", (0.67, 1.0, 1.5), "motion", "radar to hand, times the prior's",
            motion="distance_m", move="factor"),
    Unknown("hand_size_factor", "", "number", (0.85, 1.0, 1.15), "motion", "the hands' size, times the prior's",
            motion="hand_scale", move="factor"),
)}
MOTION = tuple(k for k, u in UNKNOWNS.items() if u.stage == "motion")
UNKNOWN = "unknown"  # what a manifest writes for a value it leaves to the fit


def by_section(section: str) -> dict[str, Unknown]:
    """The unknowns a manifest's ``section`` (radar, axes, processing) may state, by field name."""
    return {u.manifest.split(".", 1)[1]: u for u in UNKNOWNS.values() if u.manifest.startswith(section + ".")}
