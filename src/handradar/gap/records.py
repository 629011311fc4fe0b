"""Compact records of gap-benchmark runs and the one summary table rendered from them (``make gap-report``).

A record (``handradar.gap_benchmark/1``, one JSON file per run, results/gap_benchmark/<world>_<size>.json)
keeps what a published figure needs and where it came from: the world (config group choice) and its
generator version, the size (recordings per case), the command (as published: no path of the machine
that ran it, handradar.runs.tables.published_command), commit, seeds and machine, the scores and each
case's verdict with the true effect's gap_closed. ``data_source`` (folders of recordings only): the
command that wrote them, from their manifest's first line. ``variants`` (optional) lists settings tried
on the same world and size and judged, each with its command, commit and headline figures.

Public API:

    benchmark_record(results, scores, settings, *, world, size, world_version, machine, command) -> dict
    record_name(record) -> str                 (``<world>_<size>.json``)
    validate_record(record, where) -> dict     (FormatError naming ``where`` and the missing key)
    withheld(truth) -> [effect]; found(case) -> bool; wrong_cause(case) -> bool   (how a case's answer is judged)
    load_records(folder) -> list[dict]         (every *.json, validated, in table order)
    summary_markdown(records, source) -> str   (the summary table, its legend once, the provenance)
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from handradar.errors import FormatError
from handradar.gap.report import VERDICTS
from handradar.provenance import commit_of
from handradar.runs.tables import DIRTY_MARK, DIRTY_NOTE, dirty, fmt_number, published

FORMAT = "handradar.gap_benchmark/1"
WORLD_ORDER = ("default", "heldout", "heldout2", "heldout3")  # the tuning world first, then the test side
SCORE_KEYS = ("effects_correct", "effects_found", "wrong_causes", "effects_total", "controls_correct",
              "controls_total", "effects_inconclusive", "controls_inconclusive", "mean_true_gap_closed",
              "mean_after_gap_closed")
CASE_KEYS = ("case", "truth", "cause", "correct", "recordings_needed", "true_gap_closed", "true_ci95",
             "true_rank", "top_candidate", "top_gap_closed", "after_effects", "after_gap_closed", "kept_precision",
             "kept_recall", "reference_gap_closed", "also_present", "convention_fix")
# Effects no candidate scored row by row can earn (the world's palm return is an interference pattern that
# 0.5 mm of geometry redraws): judged "must not mislead" (docs/gap_validation.md#how-a-case-is-judged)
MUST_NOT_MISLEAD = frozenset({"palm"})


def withheld(truth: str) -> list[str]:
    """The effects a case's ``truth`` names: one, or several joined by "+" ("none" for a control)."""
    return truth.split("+")


def found(case: Mapping) -> bool:
    """The case's answer counts as found: the true effect named, or leading an "inconclusive" verdict; for an
    effect in MUST_NOT_MISLEAD also "none", or "inconclusive" with no other effect kept by the greedy
    selection (a record without ``after_effects`` cannot show that). A control is found when it says "none".
    Where effects are present in every case (``also_present``: a world's Leap jitter floor), naming them is
    right too (for a must-not-mislead effect: when nothing else is kept), and the withheld effect is also
    found when the greedy selection keeps it."""
    truth, cause, truths = case["truth"], case["cause"], withheld(case["truth"])
    present, kept = set(case.get("also_present") or []), case.get("after_effects")
    if truth == "none":
        return cause == "none" or cause in present
    if cause in truths or (cause == "inconclusive" and case.get("top_candidate") in truths):
        return True
    if present and kept is not None and set(truths) & set(kept):
        return True
    if truth not in MUST_NOT_MISLEAD or (cause not in VERDICTS and cause not in present):
        return False  # an effect present everywhere, named, misleads no more than "none" does
    return cause == "none" or (kept is not None and all(e == truth or e in present for e in kept))


def wrong_cause(case: Mapping) -> bool:
    """The worst answer: an effect named that is neither withheld nor present in every case (any other effect,
    for a control)."""
    return (case["cause"] not in VERDICTS and case["cause"] not in withheld(case["truth"])
            and case["cause"] not in (case.get("also_present") or []))
REQUIRED = ("format", "world", "size", "world_version", "command", "commit", "seeds", "machine", "scores", "cases")


def benchmark_record(results: Sequence[Mapping], scores: Mapping, settings: Mapping, *, world: str, size: int | None,
                     world_version: str, machine: str, command: str) -> dict:
    """The compact record of one benchmark run (``results`` / ``scores`` / ``settings`` as
    handradar.gap.benchmark writes them to benchmark.json)."""
    return {"format": FORMAT, "world": world, "size": int(size) if size is not None else int(settings.get("rows") or 0),
            "world_version": world_version, "command": command, "commit": commit_of(str(settings.get("code_version", ""))),
            "seeds": [int(settings.get("seed", 0))], "machine": machine, "threads": settings.get("threads"),
            "wall_min": round(float(settings.get("minutes", 0.0)), 1), "rows": settings.get("rows"),
            "split": settings.get("split"),
            **({"data_source": settings["data_source"]} if settings.get("data_source") else {}),
            "scores": {k: scores.get(k) for k in SCORE_KEYS},
            "cases": [{k: r.get(k) for k in CASE_KEYS} for r in results]}


def record_name(record: Mapping) -> str:
    return f"{record['world']}_{record['size']}.json"


def validate_record(record: Any, where: str) -> dict:
    """``record`` if it is a complete record, else FormatError naming ``where`` and what is wrong."""
    if not isinstance(record, dict):
        raise FormatError(where, "not a JSON object")
    if record.get("format") != FORMAT:
        raise FormatError(where, f"format {record.get('format')!r}, expected {FORMAT!r}")
    missing = [k for k in REQUIRED if k not in record]
    if missing:
        raise FormatError(where, f"missing {', '.join(missing)}")
    for i, case in enumerate(record["cases"]):
        lacking = [k for k in ("case", "truth", "cause", "correct") if k not in case]
        if lacking:
            raise FormatError(where, f"case {i} lacks {', '.join(lacking)}")
    return record


def _order(record: Mapping) -> tuple:
    w = record["world"]
    return (-int(record["size"]), WORLD_ORDER.index(w) if w in WORLD_ORDER else len(WORLD_ORDER), w)


def load_records(folder: str | Path) -> list[dict]:
    """Every ``*.json`` record in ``folder``, validated, ordered by size (largest first), then world."""
    out = []
    for path in sorted(Path(folder).glob("*.json")):
        try:
            obj = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise FormatError(path, f"not JSON ({exc.msg})", line=exc.lineno) from None
        out.append(validate_record(obj, str(path)))
    return sorted(out, key=_order)


def _cause(case: Mapping) -> str:
    cause = str(case["cause"])
    if cause == "inconclusive" and case.get("recordings_needed") is not None:
        cause += f" ~{case['recordings_needed']}"
    return cause


def case_cell(case: Mapping) -> str:
    """``✓`` (named), ``(✓) <verdict>`` (found, undecided) or ``✗ <what was said>``, with the true effect's
    gap_closed where it has one."""
    mark = "✓" if case["correct"] else f"(✓) {_cause(case)}" if found(case) else f"✗ {_cause(case)}"
    g = case.get("true_gap_closed")
    return mark if g is None else f"{mark} ({fmt_number(g, signed=True)})"


LEGEND = ("Each column is one benchmark run: for every case, a reference world with one effect on (the other "
          "vocabulary effects off) diagnosed by the paper's simulator without it; `nothing` and `iq_imbalance` are "
          "controls whose right answer is `none`. ✓: the diagnosis names the withheld effect (a control: `none`); "
          "(✓): found but undecided, the true effect leading an `inconclusive` verdict (palm: also `none`, or no "
          "other effect kept); ✗: anything else, with what it said (`inconclusive ~N`: about N recordings estimated "
          "to decide it). In brackets the gap_closed of the true effect's candidate. `default` is the world the "
          "settings were chosen on; the others judge them. `scatterers` carries a Leap jitter floor in every case: "
          "naming tracking jitter is never wrong there, and an effect the greedy selection keeps is found. "
          "`folders-<name>`: folders of recordings judged through ingest (`benchmark.folders`). Sizes: recordings "
          "per case; how each run split its rows is under Provenance.")


def summary_markdown(records: Sequence[Mapping], source: str = "results/gap_benchmark") -> str:
    """The one summary table of ``records`` (cases x runs), its legend once, then each run's provenance
    (the settings tried on a run stay in its record's ``variants``; docs/gap_validation.md lists them)."""
    if not records:
        return f"# Gap benchmark\n\n(no records in {source})\n"
    heads = [f"{r['world']} {r['size']}" + (f" {DIRTY_MARK}" if dirty(r["commit"]) else "") for r in records]
    cases: list[tuple[str, str]] = []
    for r in records:
        for c in r["cases"]:
            if (c["case"], c["truth"]) not in cases:
                cases.append((c["case"], c["truth"]))
    lines = ["# Gap benchmark", "", f"Generated by `make gap-report` from {source}/*.json; do not edit.", "", LEGEND, "",
             "| case (truth) | " + " | ".join(heads) + " |", "|---|" + "---|" * len(records)]
    for name, truth in cases:
        cells = []
        for r in records:
            c = next((c for c in r["cases"] if c["case"] == name), None)
            cells.append("-" if c is None else case_cell(c))
        lines.append(f"| {name} ({truth}) | " + " | ".join(cells) + " |")
    s = [r["scores"] for r in records]
    lines.append("| **effects named** | " + " | ".join(f"**{x['effects_correct']} of {x['effects_total']}**" for x in s) + " |")
    lines.append("| **effects found** | " + " | ".join(
        f"{sum(found(c) for c in r['cases'] if c['truth'] != 'none')} of {x['effects_total']}" for r, x in zip(records, s)) + " |")
    lines.append("| **controls none** | " + " | ".join(f"**{x['controls_correct']} of {x['controls_total']}**" for x in s) + " |")
    lines.append("| **wrong causes** | " + " | ".join(f"**{sum(wrong_cause(c) for c in r['cases'])}**" for r in records) + " |")
    lines.append("| mean gap_closed, true effect | " + " | ".join(fmt_number(x.get("mean_true_gap_closed"), signed=True)
                                                          for x in s) + " |")
    lines.append("| world version | " + " | ".join(r["world_version"] for r in records) + " |")
    lines.append("| commit | " + " | ".join(f"`{r['commit']}`" for r in records) + " |")
    lines += ["", DIRTY_NOTE] if any(dirty(r["commit"]) for r in records) else []
    lines += ["", "## Provenance", ""]
    for h, r in zip(heads, records):
        seeds = ", ".join(map(str, r["seeds"]))
        wall = "" if r.get("wall_min") is None else f", {r['wall_min']} min on {r.get('threads') or '?'} thread(s)"
        split = f", {r['split']}" if r.get("split") else ""
        lines.append(f"- **{h}**: {published(r['command'], r.get('data_source'))} at `{r['commit']}` "
                     f"({r['world_version']}), seed {seeds}{split}, "
                     f"{r['machine']}{wall}." + (f" {r['note']}" if r.get("note") else ""))
    return "\n".join(lines) + "\n"
