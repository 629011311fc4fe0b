"""What a measured dataset's manifest may leave unknown, defined once (docs/datasets.md#fitting-what-the-manifest-leaves-unknown).

Each :class:`Unknown` names its manifest key, its kind, the fit's default candidates and its stage: a
``simulated`` unknown (the radar's chirp set-up) needs a simulation per candidate; the others are applied
to rows simulated at a deep dB floor, approaching high, by the default processing
(handradar.synthesis.measured.finish_rows), and cost no simulation. The manifest (handradar.data.measured)
checks a stated value's kind here, the job (``synth.measured.unknowns`` / ``fit.grid``, handradar.tasks.measured)
sets or widens one by its name, the fit (handradar.synthesis.measured.fit_unknowns) reads the stages, the
tables read the fitted values (``synth.fitted.<name>``).
"""

from __future__ import annotations

from dataclasses import dataclass

from handradar.radar.chain import NORMALISATIONS, QUANTITIES, RANGE_MODES, SCALES


@dataclass(frozen=True)
class Unknown:
    """One unknown: ``manifest`` its key (``section.field``; empty: a nuisance no manifest states), ``kind``
    ``number`` (> 0 where a manifest states it), ``count`` or ``choice`` (of ``choices``), ``grid`` the fit's default
    candidates (None: absent, e.g. no noise), ``simulated`` whether each candidate is a simulation."""

    name: str
    manifest: str
    kind: str
    grid: tuple
    simulated: bool
    doc: str
    choices: tuple[str, ...] = ()

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


UNKNOWNS: dict[str, Unknown] = {u.name: u for u in (
    Unknown("v_max_m_s", "radar.v_max_m_s", "number", (0.7, 1.0, 1.5, 2.0, 3.0), True,
            "the Doppler axis's edge, m/s (the chirp loop's period)"),
    Unknown("frame_period_s", "radar.frame_period_s", "number", (0.025, 0.035, 0.05, 0.07, 0.1, 0.14), True,
            "time a column, s"),
    Unknown("chirps_per_frame", "radar.chirps_per_frame", "count", (16, 32, None), True,
            "chirp loops a frame (None: as many as the Doppler FFT's bins); fewer widen every Doppler line"),
    Unknown("noise_db", "", "number", (None, -60.0, -50.0, -40.0, -30.0, -20.0), False,
            "receiver noise a pixel, dB below each row's noise-free peak (None: none)"),
    Unknown("noise_looks", "", "count", (1,), False, "cells averaged into a pixel's noise (range bins, antennas)"),
    Unknown("dynamic_range_db", "radar.dynamic_range_db", "number", (20.0, 30.0, 40.0, 50.0, 60.0), False,
            "the dB floor below the reference"),
    Unknown("approaching", "axes.approaching", "choice", ("high", "low"), False,
            "which end of the Doppler axis is approaching", choices=("high", "low")),
    Unknown("range", "processing.range", "choice", RANGE_MODES, True,
            "how the range bins become one image: their sum, or each frame's strongest", choices=RANGE_MODES),
    Unknown("scale", "processing.scale", "choice", SCALES, False, "db or linear", choices=SCALES),
    Unknown("quantity", "processing.quantity", "choice", QUANTITIES, False,
            "power or magnitude (the same image in dB)", choices=QUANTITIES),
    Unknown("normalise", "processing.normalise", "choice", ("image", "frame"), False,
            "each image to its peak, or each column (frame) to its own", choices=NORMALISATIONS),
)}
UNKNOWN = "unknown"  # what a manifest writes for a value it leaves to the fit


def by_section(section: str) -> dict[str, Unknown]:
    """The unknowns a manifest's ``section`` (radar, axes, processing) may state, by field name."""
    return {u.manifest.split(".", 1)[1]: u for u in UNKNOWNS.values() if u.manifest.startswith(section + ".")}
