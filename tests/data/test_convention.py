"""The sign-convention check of ingest on recordings written wrong on purpose (tests/data/writer.py)."""

from __future__ import annotations

import json

import pytest

from handradar.data.ingest import checks_path, ingest
from tests.data.writer import Scene, write_recording

SCENES = [dict(velocity_m_s=-0.15, z0_m=0.5), dict(velocity_m_s=0.2, z0_m=0.3), dict(velocity_m_s=-0.3, z0_m=0.6)]


def write(root, **wrong):
    for i, kw in enumerate(SCENES):
        write_recording(root / f"r{i}", Scene(repetition=i, **kw, **wrong))
    return root


def test_right_convention_passes_quietly(tmp_path, chain):
    summary = ingest(write(tmp_path / "rec"), tmp_path / "d.h5", chain, progress=False)
    s = summary.convention.summary()
    assert s["n_rows"] == 3 and s["median_r"] > 0.9 and s["median_range_mirror_db"] < -20
    assert not summary.convention.mirrored() and not summary.convention.iq_swapped()
    assert len(summary.convention.message().splitlines()) == 1  # the figures, no advice
    saved = json.loads(checks_path(tmp_path / "d.h5").read_text())["convention"]
    assert saved["median_r"] == pytest.approx(s["median_r"]) and set(saved["rows"]) == {"r0", "r1", "r2"}


@pytest.mark.parametrize(("wrong", "fix"), [({"swap_iq": True}, "iq_swap"), ({"mirror_doppler": True}, "doppler_flip")])
def test_a_mirrored_capture_is_named_with_its_fix_and_the_fix_reads_it_right(tmp_path, chain, wrong, fix):
    root = write(tmp_path / "rec", **wrong)
    summary = ingest(root, tmp_path / "d.h5", chain, progress=False)
    assert summary.convention.summary()["median_r"] < -0.3
    assert summary.convention.iq_swapped() == ("swap_iq" in wrong)
    assert f"{fix}=true" in summary.convention.message() and f"{fix}=true" in summary.report()
    fixed = ingest(root, tmp_path / "e.h5", chain, progress=False, **{fix: True})
    assert fixed.convention.summary()["median_r"] > 0.9 and "=true" not in fixed.convention.message()


def test_diagnosis_step_zero_reads_the_convention_off_a_dataset(tmp_path, chain):
    """The same check on dataset rows alone (the skeleton window, no ADC), as diagnose.py runs it first."""
    from handradar.gap.data import load_dataset
    from handradar.gap.job import check_convention

    for wrong, sign in (({}, 1), ({"mirror_doppler": True}, -1)):
        out = tmp_path / f"d{sign}.h5"
        ingest(write(tmp_path / f"rec{sign}", **wrong), out, chain, progress=False)
        check = check_convention(load_dataset(out))
        assert sign * check.summary()["median_r"] > 0.9 and check.mirrored() == (sign < 0)
