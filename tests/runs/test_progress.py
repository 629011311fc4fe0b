"""Stage progress: numbered stages, elapsed time, the next stage, and each stage's duration."""

from __future__ import annotations

import logging

import pytest

from handradar.runs.progress import Stages, clock_text


@pytest.mark.parametrize(("seconds", "text"), [(0, "0:00"), (59.6, "1:00"), (61, "1:01"), (3599, "59:59"),
                                                (3661, "1:01:01")])
def test_clock_text(seconds: float, text: str):
    assert clock_text(seconds) == text


def test_stages_announce_number_elapsed_next_and_duration(caplog: pytest.LogCaptureFixture):
    now = [100.0]
    stages = Stages(["data", "train", "summary"], clock=lambda: now[0])
    with caplog.at_level(logging.INFO, logger="handradar.runs.progress"):
        with stages("data"):
            now[0] += 65
        with stages("train"):
            now[0] += 10
        with stages("extra"):  # outside the plan: announced without a number
            pass
        with stages("summary"):
            now[0] += 1
    assert caplog.messages == [
        "[1/3] data (elapsed 0:00; then: train)", "[1/3] data done in 65 s",
        "[2/3] train (elapsed 1:05; then: summary)", "[2/3] train done in 10 s",
        "extra (elapsed 1:15)", "extra done in 0 s",
        "[3/3] summary (elapsed 1:15; last stage)", "[3/3] summary done in 1 s",
    ]
    assert stages.durations == {"data": 65, "train": 10, "extra": 0, "summary": 1}


def test_a_failing_stage_is_not_reported_done(caplog: pytest.LogCaptureFixture):
    stages = Stages(["a"])
    with caplog.at_level(logging.INFO, logger="handradar.runs.progress"), pytest.raises(RuntimeError):
        with stages("a"):
            raise RuntimeError("boom")
    assert caplog.messages == ["[1/1] a (elapsed 0:00; last stage)"] and "a" not in stages.durations
