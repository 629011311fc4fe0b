"""The gap report contract: a valid report passes, each kind of violation is named."""

from __future__ import annotations

import copy
import json

import pytest

from handradar.gap.report import ReportError, validate_report, write_report


def valid_report() -> dict:
    return {
        "format": "handradar.gap_report/1", "n_calibration": 120, "n_evaluation": 120,
        "baseline": {"ssim": 0.61, "mse": 0.0076},
        "where": {"doppler_profile": [0.0] * 64, "time_profile": [0.0] * 32,
                  "by_factor": {"gesture": {"grasp": {"ssim": 0.6, "n": 12}}, "angle_deg": {}, "hands": {},
                                "occlusion": {}, "subject": {}},
                  "reflection_points": {"index_distal": 0.12}},
        "candidates": [
            {"effect": "occlusion", "params": {}, "ssim": 0.70, "mse": 0.0061, "gap_closed": 0.23, "ci95": [0.19, 0.27]},
            {"effect": "noise", "params": {"snr_db": 20}, "ssim": 0.62, "mse": 0.0070, "gap_closed": 0.02,
             "ci95": [-0.01, 0.05]},
        ],
        "cause": "occlusion",
        "after": {"effects": ["occlusion"], "ssim": 0.70, "mse": 0.0061, "gap_closed": 0.23},
    }


def test_valid_report_passes_and_round_trips(tmp_path):
    path = write_report(tmp_path / "gap_report.json", valid_report())
    assert json.loads(path.read_text()) == valid_report()


@pytest.mark.parametrize("mutate, message", [
    (lambda r: r.update(format="gap/0"), "format"),
    (lambda r: r["where"].update(doppler_profile=[0.0] * 10), "doppler_profile"),
    (lambda r: r["where"]["by_factor"].pop("subject"), "by_factor"),
    (lambda r: r["candidates"].reverse(), "sorted"),
    (lambda r: r.update(cause="palm"), "cause"),
    (lambda r: r.update(cause="undecided"), "cause must be 'none', 'inconclusive'"),
    (lambda r: r.update(cause="inconclusive"), "recordings_needed"),  # no evidence
    (lambda r: r.update(cause="inconclusive", evidence={"recordings_needed": 0}), "recordings_needed"),
    (lambda r: r.update(cause="inconclusive", evidence={"recordings_needed": 12.5}), "recordings_needed"),
    (lambda r: r.update(cause="inconclusive", evidence={"recordings_needed": True}), "recordings_needed"),
    (lambda r: r["candidates"][0].update(ci95=[0.3, 0.1]), "ci95"),
    (lambda r: r["baseline"].update(ssim=float("nan")), "baseline.ssim"),
    (lambda r: r["after"].update(effects=["forearm"]), "after.effects"),
])
def test_violations_are_named(mutate, message, tmp_path):
    r = copy.deepcopy(valid_report())
    mutate(r)
    with pytest.raises(ReportError, match=message):
        validate_report(r)
    with pytest.raises(ReportError):
        write_report(tmp_path / "bad.json", r)
    assert not (tmp_path / "bad.json").exists()


@pytest.mark.parametrize("cause, evidence", [
    ("none", {}),
    ("inconclusive", {"decides": "occlusion's 95 % CI of gap_closed above 0", "evaluation_rows_needed": 310,
                      "recordings_needed": 620}),
    ("inconclusive", {"decides": "...; no estimate: ...", "evaluation_rows_needed": None, "recordings_needed": None}),
])
def test_none_and_inconclusive_causes_pass(cause, evidence, tmp_path):
    r = {**valid_report(), "cause": cause, "evidence": evidence, "after": {**valid_report()["after"], "effects": []}}
    validate_report(r)
    assert json.loads(write_report(tmp_path / "gap_report.json", r).read_text())["cause"] == cause
