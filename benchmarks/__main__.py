"""Run every benchmark module (or those named on the command line) and write benchmarks/results.md."""

from __future__ import annotations

import importlib
import platform
import sys
from pathlib import Path

import torch

HERE = Path(__file__).parent


def main(argv: list[str]) -> None:
    names = argv or sorted(p.stem for p in HERE.glob("bench_*.py"))
    lines = [f"# Benchmarks\n\n{platform.processor() or platform.machine()}, {torch.get_num_threads()} torch threads, "
             f"torch {torch.__version__}\n", "| benchmark | value | unit | note |", "|---|---|---|---|"]
    for name in names:
        mod = importlib.import_module(f"benchmarks.{name}")
        print(f"== {name}", flush=True)
        for r in mod.run():
            print(f"  {r.name}: {r.value:.4g} {r.unit} {r.note}", flush=True)
            lines.append(r.row())
    out = HERE / "results.md"
    out.write_text("\n".join(lines) + "\n")
    print(out)


if __name__ == "__main__":
    main(sys.argv[1:])
