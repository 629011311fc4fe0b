"""``gap_report.md``: the gap report as text, tables and figures (paths relative to the report)."""

from __future__ import annotations

import functools
from pathlib import Path

from handradar.runs.tables import fmt_number


def _params(p: dict) -> str:
    return ", ".join(f"{k}={v:.4g}" for k, v in p.items()) or "-"


# step 0's generic settings beside the exponent: (grid axis name, the fitted value as a clause, the paper's value)
_GENERIC_TEXT = {"bone_extent": ("extent", "the bones' extent to {:g} of their length", 0),
                 "doppler_spread": ("spread", "a Doppler spread of {:g} rows", 0),
                 "metacarpal_gain": ("metacarpal", "the metacarpals' amplitude to {:g}", 1),
                 "coherence": ("coherence", "the bones' cross terms kept at {:g}", 1)}


def _calibration(cal: dict | None) -> str:
    """Step 0 (the RCS exponent, the bones' extent and Doppler spread if fitted, the baseline's own effects),
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
        text = (f", with the cylinder RCS aspect exponent calibrated to {cal['rcs_exponent']:g}{fitted} on the "
                f"calibration rows (mean SSIM there by {axes}: {tried}; {paper})")
    if cal.get("effects"):
        text += ("; the baseline's own effects fitted there on their grids: "
                 + "; ".join(f"{k} {_params(v)}" for k, v in cal["effects"].items()))
    floor = cal.get("noise_floor")
    if floor:
        pct = floor["level_db_percentiles"]
        spread = f" (10/50/90 %: {', '.join(f'{v:+.1f}' for v in pct)} dB over the display floor)" if pct else ""
        text += (f"; a noise effect follows each row's measured floor, observable in {floor['rows_observed']} "
                 f"rows{spread}, below the display floor in {floor.get('rows_below_floor', 0)}")
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
            f"CI half-widths scaled by 1/sqrt(rows), if the estimates held) would show {ev['decides']}.")


def render(report: dict, figures: dict[str, Path], out_dir: Path, source: str = "") -> str:
    """Markdown of a (validated) report; ``figures`` by name as written by handradar.viz.gap."""
    rel = {k: Path(v).relative_to(out_dir).as_posix() if Path(v).is_relative_to(out_dir) else str(v)
           for k, v in figures.items()}
    base, after, ev = report["baseline"], report["after"], report.get("evidence", {})
    lines = ["# Sim-to-real gap report", ""]
    if source:
        lines += [f"Data: `{source}`", ""]
    effects = ", ".join(base.get("effects", {})) or "none (the paper's model)"
    lines += [f"- Baseline simulator effects: {effects}", _rows(report),
              f"- Baseline: SSIM {fmt_number(base['ssim'])}, MSE {fmt_number(base['mse'], 5)}, gap = 1 - SSIM = {fmt_number(1 - base['ssim'])}"
              + _calibration(base.get("calibration")),
              _cause(report["cause"], ev),
              f"- After adding {', '.join(after['effects']) or 'nothing'}: SSIM {fmt_number(after['ssim'])}, "
              f"gap closed {fmt_number(after['gap_closed'], signed=True)}", ""]
    lines += ["## Where", "",
              "Signed mean residual (measured - simulated, spectrogram units): positive where the measurement has "
              "energy the simulator misses.", ""]
    if "residual" in rel:
        lines += [f"![residual]({rel['residual']})", ""]
    if "factors" in rel:
        lines += [f"![factors]({rel['factors']})", ""]
    by = report["where"]["by_factor"]
    for factor, levels in by.items():
        if levels:
            worst = min(levels, key=lambda k: levels[k]["ssim"])
            lines.append(f"- {factor}: lowest SSIM at {worst} ({fmt_number(levels[worst]['ssim'])}, n={levels[worst]['n']})")
    rp = report["where"]["reflection_points"]
    if rp:
        top = sorted(rp.items(), key=lambda kv: -abs(kv[1]))[:5]
        lines += ["", "Reflection points (share-weighted mean residual over the pixels each bone's simulated "
                      "power shows in; + missing energy, - excess), largest first: "
                  + ", ".join(f"{k} {fmt_number(v, signed=True)}" for k, v in top), ""]
        if "bones" in rel:
            lines += [f"![bones]({rel['bones']})", ""]
    lines += ["## Which", "",
              "| effect | fitted parameters | SSIM | gap_closed | 95 % CI | significant | signature r "
              "| where its physics acts: gain high - low [95 % CI] |",
              "|---|---|---|---|---|---|---|---|"]
    for c in report["candidates"]:
        sp = c.get("specificity")
        spec = "-" if not sp else (f"{fmt_number(sp['contrast'], signed=True)} [{fmt_number(sp['ci95'][0], signed=True)}, "
                                   f"{fmt_number(sp['ci95'][1], signed=True)}] ({sp['factor']})")
        lines.append(f"| {c['effect']} | {_params(c['params'])} | {fmt_number(c['ssim'])} | {fmt_number(c['gap_closed'], signed=True)} | "
                     f"[{fmt_number(c['ci95'][0], signed=True)}, {fmt_number(c['ci95'][1], signed=True)}] | "
                     f"{'yes' if c.get('significant') else 'no'} | {fmt_number(c.get('signature_correlation'), 2, True)} | {spec} |")
    lines += ["", "The last column is specificity evidence (handradar.gap.specificity; part of the rule only with "
                  "diagnose.specificity_decides): "
                  "an effect's mean per-row gain where the factor its physics acts through is high minus where it "
                  "is low, factors from the skeletons (noise: within each row, the squared-residual reduction far "
                  "from every simulated return minus next to them). Near 0 or below, the candidate closes a generic "
                  "gap.", ""]
    if ev:
        lines += [f"Rule: {ev.get('rule', '')}.", ""]
        if ev.get("leader"):
            lead = (f"lead over {ev['runner_up']} {fmt_number(ev['lead'], signed=True)} "
                    f"[{fmt_number(ev['lead_ci95'][0], signed=True)}, {fmt_number(ev['lead_ci95'][1], signed=True)}]"
                    if ev.get("runner_up") else "no runner-up")
            lines += [f"Evidence: leader {ev['leader']} (significant: {'yes' if ev['leader_significant'] else 'no'}), "
                      f"{lead} (clearly ahead: {'yes' if ev['clearly_ahead'] else 'no'}); leader's gain specific: "
                      f"{'yes' if ev.get('leader_specific') else 'no'}, runner-up's: "
                      f"{'yes' if ev.get('runner_up_specific') else 'no'}"
                      + (" (named by specificity)" if ev.get("decided_by") == "specificity" else "") + ".", ""]
        sp = ev.get("speckle") or {}
        if sp.get("leader"):
            sg = functools.partial(fmt_number, signed=True)
            lead = (f", its lead over {sp['runner_up']} [{sg(sp['lead_ci95'][0])}, {sg(sp['lead_ci95'][1])}]"
                    if sp.get("runner_up") else "")
            lines += [f"Speckle deviance (evidence only, handradar.metrics.speckle_deviance: the measured power as "
                      f"speckle around the simulated expectation; baseline {fmt_number(base['speckle_deviance'])}): "
                      f"leader {sp['leader']}, gap_closed {sg(sp['gap_closed'])} [{sg(sp['ci95'][0])}, "
                      f"{sg(sp['ci95'][1])}]{lead}. On the benchmark worlds it favours any candidate that adds "
                      "power where the simulation shows none (docs/gap_diagnosis.md, \"Speckle deviance\"): read it beside 1 - SSIM, "
                      "not instead of it.", ""]
    for key in ("candidates", "signatures"):
        if key in rel:
            lines += [f"![{key}]({rel[key]})", ""]
    lines += ["## How far", "", "Greedy forward selection (each step refits every remaining candidate on "
              "calibration given those chosen; gap_closed of the remaining gap; then each chosen effect is "
              "refitted given the others):", ""]
    for step in report.get("selection", []):
        items = ", ".join(f"{c['effect']} {fmt_number(c['gap_closed_of_remaining'], signed=True)}" for c in step["candidates"])
        if not step["candidates"] and step.get("params"):
            items = "; ".join(f"{k} {v}" for k, v in step["params"].items())
        lines.append(f"- step {step['step']} (base: {', '.join(step['base']) or 'baseline'}): {items or '-'}")
    lines += ["", f"After: effects {after['effects'] or '[]'}, SSIM {fmt_number(after['ssim'])}, MSE {fmt_number(after['mse'], 5)}, "
              f"gap closed {fmt_number(after['gap_closed'], signed=True)}.", ""]
    rwn = report.get("radarweightnet")
    if rwn:
        corr = ", ".join(f"{k} {fmt_number(v, 2, True)}" for k, v in rwn.get("weight_correlation", {}).items() if v is not None)
        lines += ["## RadarWeightNet readout", "",
                  f"Trained {rwn['epochs']} epochs on {rwn['train_rows']} calibration rows (SSIM loss, cached slot "
                  f"profiles)" + (f", scored on the {rwn['evaluation_rows']} held-out rows of fold 0 (not cross-fitted)"
                                  if "evaluation_rows" in rwn else "")
                  + f": SSIM {fmt_number(rwn['ssim'])}, gap closed {fmt_number(rwn['gap_closed'], signed=True)} "
                  f"[{fmt_number(rwn['ci95'][0], signed=True)}, {fmt_number(rwn['ci95'][1], signed=True)}]."]
        if rwn.get("best_effect"):
            lines.append(f"Against the best physical effect ({rwn['best_effect']}, {fmt_number(rwn['best_effect_gap_closed'], signed=True)}): "
                         f"difference {fmt_number(rwn['minus_best_effect'], signed=True)} "
                         f"[{fmt_number(rwn['minus_best_effect_ci95'][0], signed=True)}, {fmt_number(rwn['minus_best_effect_ci95'][1], signed=True)}].")
        lines += [f"Learned per-bone log weights vs each effect's per-bone log amplitude change (Pearson r): "
                  f"{corr or 'no effect changes bone amplitudes'}; most correlated: {rwn.get('most_correlated') or '-'}.", ""]
    if "examples" in rel:
        lines += ["## Examples", "", f"![examples]({rel['examples']})", ""]
    return "\n".join(lines)
