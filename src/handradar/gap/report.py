"""The gap report ``handradar.gap_report/1`` (docs/architecture.md, "Gap report"): structure and validation,
and the fitted simulator a report describes (:func:`fitted_simulator`)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path

from handradar.atomic import atomic_write_text

# Step 0's generic simulator settings (handradar.gap.fit.calibrate_settings): the diagnosis's list of
# values to try -> (the simulator setting, its value in the paper's model, the largest value allowed).
# A setting whose list is only the paper's value is not fitted; the report's calibration holds the
# fitted ones, which fitted_simulator (below) writes back as ``sim`` settings.
GENERIC_SETTINGS: dict[str, tuple[str, float, float]] = {"rcs_exponents": ("rcs_exponent", 1.0, 1.0),
                                                         "metacarpal_gains": ("metacarpal_gain", 1.0, 1.0),
                                                         "coherences": ("coherence", 1.0, 1.0)}

FORMAT = "handradar.gap_report/1"
FACTORS = ("gesture", "angle_deg", "hands", "occlusion", "subject")
VERDICTS = ("none", "inconclusive")  # the values of ``cause`` that name no effect (handradar.gap.diagnosis.decide)


class ReportError(ValueError):
    """A gap report that does not follow the contract."""


def _number(obj: dict, key: str, where: str) -> float:
    v = obj.get(key)
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
        raise ReportError(f"{where}.{key} must be a finite number, found {v!r}")
    return float(v)


def _interval(obj: dict, where: str) -> None:
    ci = obj.get("ci95")
    if not isinstance(ci, list) or len(ci) != 2 or not ci[0] <= ci[1]:
        raise ReportError(f"{where}.ci95 must be [low, high] with low <= high, found {ci!r}")


def _scores(obj: object, where: str) -> None:
    if not isinstance(obj, dict):
        raise ReportError(f"{where} must be an object")
    _number(obj, "ssim", where)
    _number(obj, "mse", where)


def validate_report(report: dict, *, n_doppler: int = 64, n_columns: int = 32) -> None:
    """Raise ReportError unless ``report`` follows the contract exactly (keys, types, sorting)."""
    if report.get("format") != FORMAT:
        raise ReportError(f"format must be {FORMAT!r}, found {report.get('format')!r}")
    for k in ("n_calibration", "n_evaluation"):
        if not isinstance(report.get(k), int) or report[k] < 1:
            raise ReportError(f"{k} must be a positive integer, found {report.get(k)!r}")
    _scores(report.get("baseline"), "baseline")
    where = report.get("where")
    if not isinstance(where, dict):
        raise ReportError("where must be an object")
    for key, n in (("doppler_profile", n_doppler), ("time_profile", n_columns)):
        prof = where.get(key)
        if not isinstance(prof, list) or len(prof) != n or not all(isinstance(v, (int, float)) for v in prof):
            raise ReportError(f"where.{key} must be a list of {n} numbers")
    by = where.get("by_factor")
    if not isinstance(by, dict) or set(by) != set(FACTORS):
        raise ReportError(f"where.by_factor must have exactly the keys {FACTORS}, found {sorted(by or {})}")
    for factor, levels in by.items():
        if not isinstance(levels, dict):
            raise ReportError(f"where.by_factor.{factor} must be an object")
        for level, v in levels.items():
            _number(v, "ssim", f"where.by_factor.{factor}.{level}")
            if not isinstance(v.get("n"), int):
                raise ReportError(f"where.by_factor.{factor}.{level}.n must be an integer")
    rp = where.get("reflection_points")
    if not isinstance(rp, dict) or not all(isinstance(v, (int, float)) for v in rp.values()):
        raise ReportError("where.reflection_points must map reflection-point names to numbers")
    cands = report.get("candidates")
    if not isinstance(cands, list):
        raise ReportError("candidates must be a list")
    names = []
    for i, c in enumerate(cands):
        w = f"candidates[{i}]"
        if not isinstance(c, dict) or not isinstance(c.get("effect"), str) or not isinstance(c.get("params"), dict):
            raise ReportError(f"{w} needs 'effect' (string) and 'params' (object)")
        _scores(c, w)
        _number(c, "gap_closed", w)
        _interval(c, w)
        sp = c.get("specificity")
        if sp is not None:  # optional evidence (handradar.gap.specificity)
            if not isinstance(sp, dict) or not isinstance(sp.get("factor"), str):
                raise ReportError(f"{w}.specificity must be an object with a 'factor' (string)")
            _number(sp, "contrast", f"{w}.specificity")
            _interval(sp, f"{w}.specificity")
        names.append(c["effect"])
    if len(set(names)) != len(names):
        raise ReportError(f"candidates must name each effect once, found {names}")
    closed = [c["gap_closed"] for c in cands]
    if closed != sorted(closed, reverse=True):
        raise ReportError("candidates must be sorted by gap_closed, largest first")
    cause = report.get("cause")
    if cause not in VERDICTS and cause not in names:
        raise ReportError(f"cause must be 'none', 'inconclusive' or a candidate's effect, found {cause!r}")
    if cause == "inconclusive":  # its evidence says how many recordings would decide it (null: none would)
        ev = report.get("evidence")
        needed = ev.get("recordings_needed", "missing") if isinstance(ev, dict) else "missing"
        if needed is not None and (not isinstance(needed, int) or isinstance(needed, bool) or needed < 1):
            raise ReportError(f"evidence.recordings_needed of an inconclusive cause must be a positive integer "
                              f"or null, found {needed!r}")
    skipped = report.get("skipped", {})
    if not isinstance(skipped, dict) or not all(isinstance(v, str) and v for v in skipped.values()):
        raise ReportError(f"skipped must map each skipped step to its reason (text), found {skipped!r}")
    after = report.get("after")
    _scores(after, "after")
    _number(after, "gap_closed", "after")
    if not isinstance(after.get("effects"), list) or not all(e in names for e in after["effects"]):
        raise ReportError("after.effects must list candidate effects")


def write_report(path: str | Path, report: dict, *, n_doppler: int = 64, n_columns: int = 32) -> Path:
    """Validate and write ``gap_report.json`` atomically (nothing is written if invalid)."""
    validate_report(report, n_doppler=n_doppler, n_columns=n_columns)
    path = Path(path)
    atomic_write_text(path, json.dumps(report, indent=1) + "\n")
    return path


def fitted_simulator(report: dict, sim_settings: Mapping | None = None) -> dict:
    """The simulator a diagnosis fitted, as ``sim`` settings (conf/sim/fitted.yaml reads them back):
    the baseline's settings with step 0's calibrated generic settings (GENERIC_SETTINGS), and the baseline's effects plus
    those the greedy selection kept, each with its fitted parameters."""
    base = dict(report["baseline"].get("effects") or {})
    after = report["after"]
    params = {**{k: dict(v) for k, v in base.items()}, **{k: dict(v) for k, v in (after.get("params") or {}).items()}}
    effects = [*base, *[e for e in after["effects"] if e not in base]]
    settings = {k: v for k, v in dict(sim_settings or {}).items()
                if not str(k).startswith("_") and k not in ("effects", "effect_params", "from_report")}
    calibration = report["baseline"].get("calibration") or {}
    for name, _, _ in GENERIC_SETTINGS.values():
        if name in calibration:
            settings[name] = float(calibration[name])
    return {**settings, "effects": effects, "effect_params": {k: params.get(k, {}) for k in effects}}
