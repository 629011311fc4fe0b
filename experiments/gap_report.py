"""The gap benchmark's summary table from its kept records (``make gap-report``).

    python -m experiments.gap_report [--results DIR] [--out FILE]

Reads every record in DIR (default results/gap_benchmark: one ``<world>_<size>.json`` per published
run, handradar.gap.records), prints the table and writes it to FILE (default docs/gap_report.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from handradar.atomic import atomic_write_text
from handradar.gap.records import load_records, summary_markdown
from handradar.provenance import REPO_ROOT


def main(argv: list[str] | None = None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=REPO_ROOT / "results" / "gap_benchmark", help="records folder")
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "docs" / "gap_report.md", help="markdown file to write")
    args = ap.parse_args(argv)
    try:
        source = args.results.resolve().relative_to(REPO_ROOT).as_posix()
    except ValueError:
        source = str(args.results)
    md = summary_markdown(load_records(args.results), source)
    atomic_write_text(args.out, md)
    print(md, end="")
    print(args.out)
    return args.out


if __name__ == "__main__":
    from handradar.runs.cli import run_cli

    run_cli(lambda: main(sys.argv[1:]), usage="python -m experiments.gap_report [--results DIR] [--out FILE]")
