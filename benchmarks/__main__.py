"""Run every benchmark module (or those named on the command line) and write benchmarks/results.md.

The file is rewritten after each module, so the figures of finished modules survive a later
failure; a failing module is reported (its row says so) and the others still run; the exit status
is 1 if any failed."""

from __future__ import annotations

import importlib
import sys
import traceback
from pathlib import Path

import torch

from handradar.provenance import code_version, machine

HERE = Path(__file__).parent


def main(argv: list[str]) -> int:
    names = argv or sorted(p.stem for p in HERE.glob("bench_*.py"))
    command = " ".join(["python -m benchmarks", *argv])
    lines = [f"# Benchmarks\n\n`{command}` at {code_version()}: {machine()}, {torch.get_num_threads()} torch threads, "
             f"torch {torch.__version__}\n", "| benchmark | value | unit | note |", "|---|---|---|---|"]
    out = HERE / "results.md"
    failed = []
    for name in names:
        print(f"== {name}", flush=True)
        try:
            for r in importlib.import_module(f"benchmarks.{name}").run():
                print(f"  {r.name}: {r.value:.4g} {r.unit} {r.note}", flush=True)
                lines.append(r.row())
        except Exception as exc:  # report it, keep the other modules' figures
            traceback.print_exc()
            failed.append(name)
            lines.append(f"| {name} | failed | - | {type(exc).__name__}: {exc} |")
        out.write_text("\n".join(lines) + "\n")
    print(out)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
