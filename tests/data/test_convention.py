"""The sign-convention check on recordings written wrong on purpose (tests/data/writer.py), through
ingest and, on the dataset alone, through step 0 of the diagnosis (handradar.gap.job.check_convention).

Captures: right, I/Q-swapped (x -> j conj(x): the hand at range bins N - b, its Doppler mirrored) and
Doppler-mirrored (the carrier phase of the wrong sign, range bins right), each without noise and with
white receiver noise of 30 ADC counts rms on I and on Q (37 dB below the 3000-count echo per sample).
Measured (3 rows each, noise 30): right r +1.00 and range -55 dB; mirrored r -1.00, -55 dB; swapped
r -0.42 (rows -0.53, +0.40, -0.42: window leakage and noise at the hand's bins) and +55 dB. Without
noise the swapped rows' leakage still carries the mirrored Doppler (r -0.85, +66 dB)."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from handradar.data.convention import MIRRORED_BELOW_R, MIRRORED_RANGE_DB, UNDETERMINED
from handradar.data.hdf5 import read_convention, validate
from handradar.data.ingest import checks_path, ingest
from handradar.gap.data import load_dataset
from handradar.gap.job import check_convention
from tests.data.writer import Scene, write_recording

SCENES = [dict(velocity_m_s=-0.15, z0_m=0.5), dict(velocity_m_s=0.2, z0_m=0.3), dict(velocity_m_s=-0.3, z0_m=0.6)]
NOISE = 30.0  # ADC counts rms on I and on Q
CAPTURES = {"right": ({}, None), "swapped": ({"swap_iq": True}, "iq_swap"),
            "mirrored": ({"mirror_doppler": True}, "doppler_flip")}


def write(root, noise=0.0, scenes=SCENES, **wrong):
    for i, kw in enumerate(scenes):
        write_recording(root / f"r{i}", Scene(repetition=i, noise_counts=noise, **{**kw, **wrong}))
    return root


@pytest.mark.parametrize("noise", [0.0, NOISE])
@pytest.mark.parametrize("capture", list(CAPTURES))
def test_ingest_and_the_diagnosis_name_the_fix_of_each_capture(tmp_path, chain, capture, noise):
    """Ingest (whole recordings, raw ADC) and step 0 of the diagnosis (the dataset's rows, with the range
    figure ingest wrote into it) name iq_swap for a swapped capture, doppler_flip for a mirrored one,
    nothing for a right one; reading with the named fix puts the rows right."""
    wrong, fix = CAPTURES[capture]
    root = write(tmp_path / "rec", noise, **wrong)
    summary = ingest(root, tmp_path / "d.h5", chain, progress=False)
    s, check = summary.convention.summary(), summary.convention
    assert s["n_range_rows"] == 3 and check.fix() == fix
    if capture == "swapped":  # the hand at the mirrored range bins, whatever the leakage's r says
        assert s["median_range_mirror_db"] > 40
    else:
        assert s["median_range_mirror_db"] < -40
        assert s["median_r"] > 0.9 if capture == "right" else s["median_r"] < -0.9
    message = check.message()
    assert (len(message.splitlines()) == 1) == (fix is None)  # the figures, and advice only where it is due
    for option in ("iq_swap", "doppler_flip"):
        named = option == fix
        assert (f"{option}=true" in message) == named and (f"{option}=true" in summary.report()) == named
    saved = json.loads(checks_path(tmp_path / "d.h5").read_text())["convention"]
    assert saved["fix"] == fix and saved["median_r"] == pytest.approx(s["median_r"])
    assert set(saved["rows"]) == {"r0", "r1", "r2"} and not saved["iq_swap"] and not saved["doppler_flip"]
    # the range figure travels in the dataset, where the diagnosis's step 0 finds it
    assert validate(tmp_path / "d.h5") == 3
    figure, options = read_convention(tmp_path / "d.h5")
    np.testing.assert_allclose(figure, check.mirror_db)
    assert options == {"iq_swap": False, "doppler_flip": False}
    data = load_dataset(tmp_path / "d.h5")
    assert check_convention(data).fix() == fix
    np.testing.assert_array_equal(data.take(np.array([2, 0])).range_mirror_db, figure[[2, 0]])  # rows keep theirs
    if fix is not None:
        fixed = ingest(root, tmp_path / "e.h5", chain, progress=False, **{fix: True})
        f = fixed.convention.summary()
        assert f["median_r"] > 0.9 and f["median_range_mirror_db"] < -40 and fixed.convention.fix() is None
        assert "=true" not in fixed.convention.message() and "=false" not in fixed.convention.message()
        assert check_convention(load_dataset(tmp_path / "e.h5")).fix() is None


def test_noise_alone_decides_a_swapped_captures_doppler_r(tmp_path, chain):
    """Why the range figure, not r, names a swap: with noise the swapped rows' r comes from leakage and
    noise (rows of both signs, median -0.42 here, a hair from the -0.3 threshold), and doppler_flip, the
    wrong fix, can pass the Doppler check while the hand stays at the mirrored range bins."""
    root = write(tmp_path / "rec", NOISE, swap_iq=True)
    check = ingest(root, tmp_path / "d.h5", chain, progress=False).convention
    r = [row["r"] for row in check.to_json()["rows"].values()]
    assert min(r) < 0 < max(r) and abs(check.summary()["median_r"] - MIRRORED_BELOW_R) < 0.2
    wrong = ingest(write(tmp_path / "clean", swap_iq=True), tmp_path / "w.h5", chain, progress=False, doppler_flip=True)
    s = wrong.convention.summary()
    assert s["median_r"] > 0.5 and not wrong.convention.mirrored()  # the Doppler check passes...
    assert s["median_range_mirror_db"] > 40 and wrong.convention.fix() == "iq_swap"  # ...the range check does not
    assert "iq_swap=true" in wrong.convention.message()
    assert check_convention(load_dataset(tmp_path / "w.h5")).fix() == "iq_swap"


def test_the_range_finding_stands_on_its_own_where_r_is_undefined(tmp_path, chain):
    """A swapped gesture with hardly any radial motion (1 cm/s: r undefined) is still named by its range
    figure; the message says that the Doppler was not checked."""
    slow = [dict(velocity_m_s=-0.01, z0_m=0.5), dict(velocity_m_s=0.01, z0_m=0.4)]
    summary = ingest(write(tmp_path / "rec", NOISE, slow, swap_iq=True), tmp_path / "d.h5", chain, progress=False)
    s = summary.convention.summary()
    assert s["median_r"] is None and s["n_rows"] == 0 and s["median_range_mirror_db"] > MIRRORED_RANGE_DB
    message = summary.convention.message()
    assert "Doppler not checked" in message and "re-ingest with iq_swap=true" in message
    assert check_convention(load_dataset(tmp_path / "d.h5")).fix() == "iq_swap"


def test_the_fix_turns_over_the_option_the_rows_were_read_with(tmp_path, chain):
    """A right capture read with iq_swap=true is swapped as read: the fix is iq_swap=false, from ingest
    and from the dataset's recorded options alike."""
    summary = ingest(write(tmp_path / "rec", NOISE), tmp_path / "d.h5", chain, progress=False, iq_swap=True)
    assert summary.convention.fix() == "iq_swap" and "re-ingest with iq_swap=false" in summary.convention.message()
    check = check_convention(load_dataset(tmp_path / "d.h5"))
    assert check.iq_swap and "re-ingest with iq_swap=false" in check.message()


@pytest.mark.parametrize("capture", ["swapped", "mirrored"])
def test_rows_without_a_range_figure_say_they_cannot_tell(tmp_path, chain, capture):
    """A dataset without ingest's range figure (another tool's, an older ingest's): mirrored Doppler rows
    are reported as undetermined between the two fixes, never as one of them. Noiseless, so that the
    swapped rows' leakage carries the mirrored Doppler and both captures look alike to r."""
    wrong, _ = CAPTURES[capture]
    ingest(write(tmp_path / "rec", **wrong), tmp_path / "d.h5", chain, progress=False)
    with h5py.File(tmp_path / "d.h5", "a") as h5:
        del h5["convention"]
    data = load_dataset(tmp_path / "d.h5")
    assert data.range_mirror_db is None
    check = check_convention(data)
    assert check.mirrored() and check.summary()["median_range_mirror_db"] is None and check.fix() == UNDETERMINED
    message = check.message()
    assert "range bins not checked" in message and "cannot tell" in message
    assert "iq_swap=true" in message and "doppler_flip=true" in message and "re-ingest with" not in message
