"""Paper-style result tables from the MLflow runs of train.py jobs (``make tables``).

    python -m experiments.tables [--tracking-uri URI] [--out DIR] [--doc FILE]

Reads every FINISHED run tagged by handradar (handradar.runs.tables.load_records: the latest one per job
hash, so a re-run job counts once) and writes:

- FILE (default docs/results.md): Tables I (synthesis), II (few-shot), III (pre-training) and IV (OOD),
  each cell the mean ± standard deviation over seeds, and under each table every row's runs: the
  command that reproduces them, the commit, the seeds and the machine (the runs' ``handradar.command``
  and ``handradar.machine`` tags; for runs logged before those tags, the command from the run folder's
  ``.hydra/overrides.yaml`` where it still exists), as published (handradar.runs.tables.published: no path
  of the machine that ran them; a row from a dirty tree marked);
- into DIR (default logs/results): ``table2_few_shot.csv`` etc. with mean, std and n columns,
  ``confusion/<preset>[_fixed]_<variant>.png``, confusion matrices summed over seeds, and, when measured
  runs exist, ``measured_curve.png`` (accuracy against real rows per class, ``--measured-figure``).

The last line printed is the path of FILE.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np

from experiments.data_efficiency import curves, data_labels, dirty_points, fitted_effects, rwn_minus_model
from experiments.data_efficiency import markdown as curve_markdown
from handradar.atomic import atomic_write_text
from handradar.provenance import REPO_ROOT
from handradar.runs.mlflow import TAG_PREFIX, Tracker, sqlite_path
from handradar.runs.tables import DEFAULT_TRACKING_URI, build_tables, load_records, results_markdown

log = logging.getLogger(__name__)


def confusion_group(rec: dict) -> str:
    p = rec["params"]
    fixed = p.get("split.kind", "few_shot") == "few_shot" and p.get("split.test") == "fixed" and p.get("job") == "variants"
    return rec["tags"].get(f"{TAG_PREFIX}preset", "run") + ("_fixed" if fixed else "")


def write_confusions(tracking_uri: str, records: list[dict], out: Path) -> list[Path]:
    """Confusion matrices summed over the seeds of each (preset, variant), as PNGs."""
    from handradar.viz.confusion import plot_confusion

    tracker = Tracker(tracking_uri, "")
    sums: dict[tuple[str, str], np.ndarray] = {}
    classes: dict[tuple[str, str], list[str]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, rec in enumerate(records):
            try:
                files = tracker._call(lambda c: c.list_artifacts(rec["run_id"], "confusion"))
            except Exception as exc:  # an artifact store that moved: the tables still come out
                log.warning("no confusion matrices for run %s: %s", rec["run_id"], exc)
                continue
            for f in files:
                local = tracker._call(lambda c: c.download_artifacts(rec["run_id"], f.path, f"{tmp}/{i}"))
                obj = json.loads(Path(local).read_text())
                key = (confusion_group(rec), Path(f.path).stem)
                m = np.asarray(obj["matrix"], dtype=np.int64)
                sums[key] = sums[key] + m if key in sums and sums[key].shape == m.shape else m
                classes[key] = obj["classes"]
    paths = []
    for (group, variant), m in sorted(sums.items()):
        paths.append(plot_confusion(m, classes[(group, variant)], out / "confusion" / f"{group}_{variant}.png",
                                    title=f"{group} {variant}"))
    return paths


def main(argv: list[str] | None = None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tracking-uri", default=DEFAULT_TRACKING_URI, help=f"MLflow store (default {DEFAULT_TRACKING_URI})")
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "logs" / "results", help="output folder")
    ap.add_argument("--doc", type=Path, default=REPO_ROOT / "docs" / "results.md", help="the results markdown")
    ap.add_argument("--no-figures", action="store_true", help="skip the confusion-matrix PNGs")
    ap.add_argument("--log-dir", type=Path, default=REPO_ROOT / "logs", help="where the jobs' state folders are")
    ap.add_argument("--measured-figure", type=Path, default=None,
                    help="the measured curve's PNG (default DIR/measured_curve.png), when measured runs exist")
    ap.add_argument("--anchor", action="append", default=[], metavar="SPLIT=ACC",
                    help="a published accuracy drawn on the measured curve's panel of that test split (repeatable)")
    args = ap.parse_args(argv)
    records = load_records(args.tracking_uri)
    tables = build_tables(records)
    args.out.mkdir(parents=True, exist_ok=True)
    for t in tables:
        atomic_write_text(args.out / f"{t.name}.csv", t.csv())
        if t.name == "measured":
            from handradar.viz.measured import plot_measured_curve

            anchors = {a.split("=", 1)[0]: float(a.split("=", 1)[1]) for a in args.anchor}
            plot_measured_curve(t.rows, args.measured_figure or args.out / "measured_curve.png", anchors=anchors,
                                title="measured test splits: mean ± std over seeds")
    db = sqlite_path(args.tracking_uri)
    source = args.tracking_uri if db is None else _relative(db)
    md = results_markdown(tables, f"`{source}` ({len(records)} jobs)")
    # the same runs as Table II's "k per class*" rows, as the curve and the fitted simulators; one curve per data set
    for label in data_labels(records):
        curve = curves(records, label)
        if not curve:
            continue
        md += (f"\n## Data efficiency{' on ' + label if label else ''}\n\n`make data-efficiency` "
               "(`+experiment=data_efficiency`, seeds as counted, `hydra/launcher=joblib`, `threads=1`"
               f"{'; the data as labelled' if label else ''}); the latest run per point and seed. Under the curve, the "
               "simulator each job fitted on its k rows per gesture, with the fit's held-out SSIM before and after "
               "its effects: where that stays flat as k grows, the simulator's residual gap, not the real rows, "
               "limits synthetic-only training.\n\n"
               + curve_markdown(curve, fitted_effects(records, args.log_dir, label), rwn_minus_model(records, label),
                                dirty_points(records, label)))
    atomic_write_text(args.doc, md)
    if not args.no_figures:
        write_confusions(args.tracking_uri, records, args.out)
    print(md, end="")
    print(args.doc)
    return args.doc


def _relative(path: Path) -> str:
    """``path`` relative to the repository when inside it (the results file names no home folder)."""
    try:
        return path.resolve().relative_to(REPO_ROOT).as_posix()
    except ValueError:
        return str(path)


if __name__ == "__main__":
    main(sys.argv[1:])
