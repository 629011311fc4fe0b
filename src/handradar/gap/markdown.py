"""``gap_report.md``: the gap report as text, tables and figures (paths relative to the report)."""

from __future__ import annotations

from pathlib import Path

from handradar.runs.tables import fmt_number


# the report's ``skipped`` keys as a reader names the step
STEP_NAMES = {"radarweightnet": "RadarWeightNet readout"}


def _params(p: dict) -> str:
    return ", ".join(f"{k}={v:.4g}" for k, v in p.items()) or "-"


# step 0's generic settings beside the exponent: (grid axis name, the fitted value as a clause, the paper's value)
_GENERIC_TEXT = {"metacarpal_gain": ("metacarpal", "the metacarpals' amplitude to {:g}", 1),
                 "coherence": ("coherence", "the bones' cross terms kept at {:g}", 1)}


def _calibration(cal: dict | None) -> str:
    """Step 0 (the RCS exponent, the metacarpal gain and coherence if fitted, the baseline's own effects),
    as a clause of the baseline line."""
    cal = cal or {}
    if not cal.get("grid"):
        text = " (the paper's cylinder RCS, not calibrated)"
    else:
        extra = [k for k in _GENERIC_TEXT if k in cal]  # fitted beside the exponent: a tuple per grid point
        keys = ["rcs_exponent", *extra]

        def point(g: dict) -> str:
            return f"({', '.join(f'{g[k]:g}' for k in keys)})" if extra else f"{g['rcs_exponent']:g}"

        tried = ", ".join(f"{point(g)}: {fmt_number(g['ssim'])}" for g in cal["grid"])
        fitted = "".join(f" and {_GENERIC_TEXT[k][1].format(cal[k])}" for k in extra)
        axes = f"({', '.join(['exponent'] + [_GENERIC_TEXT[k][0] for k in extra])})" if extra else "exponent"
        paper = (f"({', '.join(['1'] + [str(_GENERIC_TEXT[k][2]) for k in extra])}) = the paper's model" if extra
                 else "1 = the paper's RCS")
        text = (f", with the cylinder RCS aspect exponent calibrated to {cal['rcs_exponent']:g}{fitted} "
                f"(mean SSIM on the fitting rows by {axes}: {tried}; {paper})")
    if cal.get("effects"):
        text += ("; the baseline's own effects fitted there on their grids: "
                 + "; ".join(f"{k} {_params(v)}" for k, v in cal["effects"].items()))
    return text


def _rows(report: dict) -> str:
    """The rows line: one calibration/evaluation split, or cross-fitting."""
    folds = report.get("settings", {}).get("folds", 1)
    if folds == 1:
        return (f"- Rows: {report['n_calibration']} calibration (effect parameters are fitted here), "
                f"{report['n_evaluation']} evaluation (every number below)")
    return (f"- Rows: {report['n_evaluation']}, cross-fitted in {folds} folds: every row is scored (every number "
            f"below) with parameters fitted on the other folds (at least {report['n_calibration']} rows); the "
            "parameters shown are fitted on all rows")


def _cause(cause: str, ev: dict) -> str:
    """The cause line; what "none" and "inconclusive" rest on, and the recordings that would decide the latter."""
    line = f"- **Cause: {cause}**"
    if cause == "none" and ev.get("leader"):
        return line + (" (the leader's 95 % CI of gap_closed ends below the relevance threshold: no candidate "
                       "closes a relevant part of the gap)")
    if cause != "inconclusive":
        return line
    line += (" (the leading candidate may close a relevant part of the gap, but its gain is not significant or "
             "not separable from the runner-up's: neither an effect nor none is shown)")
    if ev.get("recordings_needed") is None:
        return line + f". No number of recordings is estimated to decide it: {ev.get('decides') or '-'}."
    return (line + f". About {ev['recordings_needed']} recordings ({ev['evaluation_rows_needed']} evaluation rows; "
            f"standard errors scaled by 1/sqrt(rows); 80 % likely if the estimates are the truth) would show "
            f"{ev['decides']}.")


def _ci(ci: list[float]) -> str:
    return f"[{fmt_number(ci[0], signed=True)}, {fmt_number(ci[1], signed=True)}]"


def render(report: dict, figures: dict[str, Path], out_dir: Path, source: str = "") -> str:
    """Markdown of a (validated) report, in the order a user acts on it: the verdict and its evidence, the
    fitted simulator and how far it closes the gap, where the residual lies, the candidates table.
    ``figures`` by name as written by handradar.viz.gap."""
    rel = {k: Path(v).relative_to(out_dir).as_posix() if Path(v).is_relative_to(out_dir) else str(v)
           for k, v in figures.items()}
    base, after, ev = report["baseline"], report["after"], report.get("evidence", {})
    lines = ["# Sim-to-real gap report", ""] + ([f"Data: `{source}`", ""] if source else [])
    lines += ["## Verdict", "", _cause(report["cause"], ev), _rows(report)]
    if ev.get("leader"):
        lead = (f"its lead over {ev['runner_up']} {fmt_number(ev['lead'], signed=True)} {_ci(ev['lead_ci95'])}"
                if ev.get("runner_up") else "no runner-up")
        top = report["candidates"][0]
        lines.append(f"- Evidence: leader {ev['leader']} closes {fmt_number(top['gap_closed'], signed=True)} "
                     f"{_ci(top['ci95'])} of the gap; {lead}")
    lines += [f"- Rule: {ev['rule']}" if ev.get("rule") else "", ""]
    effects = ", ".join(base.get("effects", {})) or "none (the paper's model)"
    lines += ["## The fitted simulator and how far it closes the gap", "",
              f"- Baseline (effects: {effects}): SSIM {fmt_number(base['ssim'])}, gap = 1 - SSIM = "
              f"{fmt_number(1 - base['ssim'])}" + _calibration(base.get("calibration")),
              f"- Adding {', '.join(f'{k} ({_params(v)})' for k, v in after['params'].items()) or 'nothing'}: "
              f"SSIM {fmt_number(after['ssim'])}, gap closed {fmt_number(after['gap_closed'], signed=True)} "
              "(greedy forward selection, each chosen effect refitted given the others; `fitted_sim.yaml`)"]
    steps = [s for s in report.get("selection", []) if s["candidates"]]
    if len(steps) > 1:
        lines.append("- Selection: " + "; ".join(
            f"step {s['step']} leader {s['candidates'][0]['effect']} "
            f"{fmt_number(s['candidates'][0]['gap_closed_of_remaining'], signed=True)} of the remaining gap"
            for s in steps))
    rwn = report.get("radarweightnet")
    if rwn:
        on = (f", scored on the {rwn['evaluation_rows']} held-out rows of fold {rwn.get('fold', 0)}"
              if "evaluation_rows" in rwn else "")
        lines.append(f"- RadarWeightNet readout ({rwn['train_rows']} training rows{on}): gap closed "
                     f"{fmt_number(rwn['gap_closed'], signed=True)} {_ci(rwn['ci95'])}")
    lines += [f"- Skipped: the {STEP_NAMES.get(step, step)}: {why}" for step, why in report.get("skipped", {}).items()]
    lines.append("")
    if "examples" in rel:
        lines += [f"![examples]({rel['examples']})", ""]
    lines += ["## Where the residual lies", "",
              "Signed mean residual (measured - simulated): positive where the measurement has energy the simulator "
              "misses.", ""]
    lines += [f"![{k}]({rel[k]})\n" for k in ("residual", "factors") if k in rel]
    for factor, levels in report["where"]["by_factor"].items():
        if levels:
            worst = min(levels, key=lambda k: levels[k]["ssim"])
            lines.append(f"- {factor}: lowest SSIM at {worst} ({fmt_number(levels[worst]['ssim'])}, n={levels[worst]['n']})")
    rp = report["where"]["reflection_points"]
    if rp:
        top5 = sorted(rp.items(), key=lambda kv: -abs(kv[1]))[:5]
        lines.append("- Reflection points (+ missing energy, - excess), largest first: "
                     + ", ".join(f"{k} {fmt_number(v, signed=True)}" for k, v in top5))
    lines += [""] + ([f"![bones]({rel['bones']})", ""] if "bones" in rel else [])
    lines += ["## Candidates", "",
              "| effect | fitted parameters | SSIM | gap_closed [95 % CI] | significant | signature r "
              "| gain where its physics acts [95 % CI] |",
              "|---|---|---|---|---|---|---|"]
    for c in report["candidates"]:
        sp = c.get("specificity")
        spec = "-" if not sp else f"{fmt_number(sp['contrast'], signed=True)} {_ci(sp['ci95'])} ({sp['factor']})"
        lines.append(f"| {c['effect']} | {_params(c['params'])} | {fmt_number(c['ssim'])} | "
                     f"{fmt_number(c['gap_closed'], signed=True)} {_ci(c['ci95'])} | "
                     f"{'yes' if c.get('significant') else 'no'} | {fmt_number(c.get('signature_correlation'), 2, True)} | {spec} |")
    lines += ["", "Signature r: the correlation of the change a candidate makes with the baseline residual. The last "
                  "column: the candidate's mean per-row gain where the factor its physics acts through is high minus "
                  "where it is low (near 0 or below: it closes a generic gap).", ""]
    lines += [f"![{k}]({rel[k]})\n" for k in ("candidates", "signatures") if k in rel]
    return "\n".join(lines)
