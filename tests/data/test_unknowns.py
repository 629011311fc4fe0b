"""The unknowns of a measured manifest, defined once (handradar.data.unknowns): the job's configuration mirrors them
and refuses others; the manifest checks a stated value's kind."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from handradar.data.unknowns import MOTION, UNKNOWNS, Unknown, by_section
from handradar.tasks.measured import MeasuredSetup
from tests.tasks.fakes import compose_train


def test_the_preset_mirrors_the_unknowns():
    """synth.measured.unknowns and fit.grid list every unknown, with its default candidates, and nothing else."""
    m = compose_train(["+experiment=measured"]).synth.measured
    assert list(m.unknowns) == list(UNKNOWNS) and all(v is None for v in m.unknowns.values())
    grid = OmegaConf.to_container(m.fit.grid)
    assert grid == {k: list(u.grid) for k, u in UNKNOWNS.items()}


def test_the_job_refuses_what_is_no_unknown():
    cfg = compose_train(["+experiment=measured", "++synth.measured.unknowns.speed=1.0"])
    with pytest.raises(ValueError, match="synth.measured.unknowns.speed is no unknown"):
        MeasuredSetup.from_cfg(cfg)
    cfg = compose_train(["+experiment=measured", "++synth.measured.fit.grid.gain=[1.0]"])
    with pytest.raises(ValueError, match="synth.measured.fit.grid.gain is no unknown"):
        MeasuredSetup.from_cfg(cfg)


def test_sections_and_kinds():
    assert set(by_section("radar")) == {"v_max_m_s", "frame_period_s", "chirps_per_frame", "dynamic_range_db"}
    assert set(by_section("processing")) == {"range", "scale", "quantity", "normalise"}
    assert set(by_section("axes")) == {"approaching"}
    assert UNKNOWNS["chirps_per_frame"].check(32) is None and UNKNOWNS["chirps_per_frame"].check(32.5)
    assert UNKNOWNS["v_max_m_s"].check(0.0) and UNKNOWNS["v_max_m_s"].check(True)
    assert UNKNOWNS["scale"].check("linear") is None and "one of ['db', 'linear']" in UNKNOWNS["scale"].check("log")


def test_motion_unknowns_move_their_draw_range():
    """A factor multiplies the prior range, a shift adds to it (a non-negative field stays at or above 0), and the
    identity keeps it; an unknown whose stage and move disagree is refused."""
    speed, tremor, azimuth = UNKNOWNS["speed_factor"], UNKNOWNS["tremor_shift_mm"], UNKNOWNS["azimuth_shift_deg"]
    assert speed.moved((0.5, 1.0), 1.5) == (0.75, 1.5) and speed.moved((0.5, 1.0), speed.identity) == (0.5, 1.0)
    assert tremor.moved((0.2, 1.0), -0.5) == (0.0, 0.5) and tremor.moved((0.0, 0.0), tremor.identity) == (0.0, 0.0)
    assert azimuth.moved((-20.0, 20.0), -30.0) == (-50.0, -10.0)
    assert all(UNKNOWNS[k].identity in UNKNOWNS[k].grid for k in MOTION)  # the prior is always a candidate
    with pytest.raises(ValueError, match="stage 'motion', move ''"):
        Unknown("x", "", "number", (1.0,), "motion", "no move")
