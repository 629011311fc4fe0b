"""Result tables in the paper's layout, from job records (MLflow runs or one finished job).

- Table I (synthesis): one row per evaluation (held-out rows and the four generalisation
  shifts), columns SSIM and MSE of the modelling-only and the RadarWeightNet-enhanced simulator.
- Table II (few-shot): one row per real-data fraction and test protocol (``*``: the fixed test split
  of the complete dataset), one column per variant (radar only, + model-based synthetic,
  + RadarWeightNet-enhanced synthetic, + CGAN; synthetic only, enhanced and model-based: train on
  synthetic, test on real; the pool's real rows, their upper reference).
- Table III (pre-training): one row per (classes, fraction), columns trained from scratch and
  pre-trained on synthetic spectrograms of an external skeleton dataset.
- Table IV (out of distribution): one row per OOD split, the variant columns.

Cells are ``mean ± std`` of the accuracy over the records of a row (seeds), with the count.
A record is ``{"params": flat config (dotted keys -> str), "metrics": {name: float}}``.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

VARIANT_COLUMNS = (
    ("radar_only", "Radar only"),
    ("model_synth", "+ model-based synthetic"),
    ("enhanced_synth", "+ RadarWeightNet synthetic"),
    ("cgan", "+ CGAN"),
    ("synth_only", "synthetic only (RadarWeightNet)"),
    ("model_synth_only", "synthetic only (model-based)"),
    ("radar_pool", "radar, whole pool"),
)
OOD_LABELS = {
    "angle": "angle (0° → ±30°)",
    "subject": "subject (unseen subjects)",
    "hands": "hands (single → double)",
    "occlusion": "occlusion (without → with)",
}
SYNTH_ROWS = (("", "held-out"), ("_hands", "single → double hands"), ("_occlusion", "non-occluded → occluded"),
              ("_angle", "0° → ±30°"), ("_subject", "unseen subjects"))
SYNTH_COLUMNS = (("ssim_model", "SSIM modelling"), ("ssim_enhanced", "SSIM + RadarWeightNet"),
                 ("mse_model", "MSE modelling"), ("mse_enhanced", "MSE + RadarWeightNet"))
SYNTH_JOB = "handradar.synthesis.job.run_synth_fit"
PRETRAIN_METRIC = re.compile(r"^test/acc_(scratch|pretrained)_(\d+)c_(\d+)pct$")


@dataclass
class Table:
    name: str
    title: str
    columns: list[str]
    rows: dict[str, dict[str, list[float]]] = field(default_factory=dict)  # row -> column -> values
    order: dict[str, tuple] = field(default_factory=dict)  # row -> sort key

    def add(self, row: str, column: str, value: float, sort_key: tuple = ()) -> None:
        self.rows.setdefault(row, {}).setdefault(column, []).append(float(value))
        self.order.setdefault(row, sort_key)

    def sorted_rows(self) -> list[str]:
        return sorted(self.rows, key=lambda r: (self.order[r], r))

    def markdown(self) -> str:
        lines = [f"**{self.title}**", "", "| | " + " | ".join(self.columns) + " |",
                 "|---|" + "---|" * len(self.columns)]
        for r in self.sorted_rows():
            lines.append(f"| {r} | " + " | ".join(mean_std(self.rows[r].get(c, [])) for c in self.columns) + " |")
        return "\n".join(lines)

    def csv(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf)
        w.writerow(["row", *[f"{c} {s}" for c in self.columns for s in ("mean", "std", "n")]])
        for r in self.sorted_rows():
            cells = []
            for c in self.columns:
                m, s, n = stats(self.rows[r].get(c, []))
                cells += ["" if n == 0 else f"{m:.4f}", "" if n < 2 else f"{s:.4f}", n]
            w.writerow([r, *cells])
        return buf.getvalue()


def stats(values: Sequence[float]) -> tuple[float, float, int]:
    """Mean, sample standard deviation (ddof 1; nan below 2 values) and count."""
    n = len(values)
    if n == 0:
        return math.nan, math.nan, 0
    m = sum(values) / n
    s = math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1)) if n > 1 else math.nan
    return m, s, n


def fmt_number(x: float | None, digits: int = 3, signed: bool = False) -> str:
    """A number for a markdown table: ``digits`` decimals, with its sign when ``signed``; None as "-"."""
    if x is None:
        return "-"
    return f"{x:+.{digits}f}" if signed else f"{x:.{digits}f}"


def mean_std(values: Sequence[float]) -> str:
    m, s, n = stats(values)
    if n == 0:
        return "–"
    if n == 1:
        return f"{m:.3f}"
    return f"{m:.3f} ± {s:.3f} (n={n})"


def _pct(fraction: str | float) -> str:
    return f"{float(fraction) * 100:g} %"


def synthesis_setting(p: Mapping[str, str]) -> str:
    """How a job's synthetic rows were made, when not by the configured simulator as is: its rows
    must not be averaged with those of other settings (e.g. " [fitted: effects, 2 draws]")."""
    parts = []
    if p.get("synth.fit_sim", "none") not in ("none", "None"):
        parts.append(f"fitted: {p['synth.fit_sim']}")
    if int(float(p.get("synth.samples_per_row", 1))) > 1:
        parts.append(f"{int(float(p['synth.samples_per_row']))} draws")
    elif any(k.startswith("synth.randomize.") for k in p):
        parts.append("randomised")
    return f" [{', '.join(parts)}]" if parts else ""


def build_tables(records: Iterable[Mapping]) -> list[Table]:
    """Tables I-IV from job records; a table without records is left out."""
    variant_cols = [label for _, label in VARIANT_COLUMNS]
    synth = Table("table1_synthesis", "Table I: simulated vs measured spectrograms (modelling only vs + RadarWeightNet)",
                  [label for _, label in SYNTH_COLUMNS])
    few = Table("table2_few_shot", "Table II: few-shot accuracy (* = fixed test split of the complete dataset)",
                variant_cols)
    pre = Table("table3_pretrain", "Table III: accuracy with and without pre-training on external synthetic data",
                ["from scratch", "pre-trained"])
    ood = Table("table4_ood", "Table IV: out-of-distribution accuracy", variant_cols)
    for rec in records:
        p, metrics = rec["params"], rec["metrics"]
        kind = p.get("split.kind", "few_shot")
        if p.get("job") == SYNTH_JOB:
            for i, (suffix, row) in enumerate(SYNTH_ROWS):
                for key, label in SYNTH_COLUMNS:
                    value = metrics.get(f"test/{key}{suffix}")
                    if value is not None:
                        synth.add(row, label, value, (i,))
            continue
        if p.get("job") not in ("variants", "external_pretrain"):
            continue  # not a train.py job
        if p.get("job") == "external_pretrain":
            source = p.get("pretrain.source", "external")
            for name, value in metrics.items():
                m = PRETRAIN_METRIC.match(name)
                if m:
                    init, classes, pct = m.groups()
                    pre.add(f"{classes} classes, {pct} % ({source})", "pre-trained" if init == "pretrained" else "from scratch",
                            value, (-int(classes), int(pct)))
            continue
        if kind == "ood":
            ood_kind = p.get("split.ood", "?")
            row, table, key = OOD_LABELS.get(ood_kind, ood_kind), ood, (list(OOD_LABELS).index(ood_kind)
                                                                        if ood_kind in OOD_LABELS else 9,)
        elif "split.fraction" in p:
            fixed = p.get("split.test", "remainder") == "fixed"
            row, table, key = _pct(p["split.fraction"]) + ("*" if fixed else ""), few, (fixed, float(p["split.fraction"]))
        else:
            continue
        setting = synthesis_setting(p)
        row, key = row + setting, (*key, setting)
        for variant, label in VARIANT_COLUMNS:
            value = metrics.get(f"test/acc_{variant}")
            if value is not None:
                table.add(row, label, value, key)
    return [t for t in (synth, few, pre, ood) if t.rows]


def job_table(params: Mapping[str, str], metrics: Mapping[str, float]) -> str:
    """The table rows of one finished job (what train.py prints at its end)."""
    tables = build_tables([{"params": params, "metrics": metrics}])
    return "\n\n".join(t.markdown() for t in tables) if tables else "(no table metrics)"
