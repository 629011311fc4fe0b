"""Write a gap benchmark's cases as folders of recordings, with the manifest that ``benchmark.folders`` reads
(``python -m benchmarks.case_folders OUT world=scatterers benchmark.size=36``).

The same case worlds the benchmark builds directly (handradar.gap.benchmark.BenchmarkWorlds, from
``+experiment=gap_benchmark`` and the given overrides), written as ``handradar.recording/1`` folders
(OUT/<case>/) by the world's own writer, and OUT/folders.yaml naming each folder's answer. Diagnosing
them with ``python diagnose.py +experiment=gap_benchmark benchmark.folders=OUT/folders.yaml`` then
goes through the path a user's (or a held-back) folder takes: the recordings on disk, ingest, the
convention check. A stopped run resumes: finished recordings are kept.
"""

from __future__ import annotations

import shlex
import sys
import time
from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from handradar.atomic import atomic_write_text
from handradar.config import VERSION_BASE, config_dir
from handradar.gap.benchmark import BenchmarkWorlds, always_present, cases
from handradar.world import write_world_recordings


def main(out: str | Path, overrides: list[str]) -> Path:
    """Every case of the composed benchmark under ``out``; returns the manifest's path."""
    with initialize_config_dir(config_dir=str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("diagnose", overrides=["+experiment=gap_benchmark", *overrides])
    worlds = BenchmarkWorlds.from_config(cfg)
    out = Path(out).resolve()
    folders = {}
    for case in cases(list(cfg.benchmark.cases)):
        t0 = time.perf_counter()
        written = write_world_recordings(worlds.config(case), worlds.radar, out / case.name, progress=False)
        print(f"{case.name}: {len(written)} recordings ({time.perf_counter() - t0:.0f} s)", flush=True)
        folders[case.name] = {"root": case.name, "truth": case.truth}
    manifest = out / "folders.yaml"
    # the first line says how the folders were made: the benchmark's record names them by it (FolderCases.source)
    command = shlex.join(["python", "-m", "benchmarks.case_folders", str(out), *overrides])
    atomic_write_text(manifest, f"# {command}\n" + OmegaConf.to_yaml(
        {"also_present": always_present(worlds.world), "folders": folders}))
    return manifest


if __name__ == "__main__":
    if len(sys.argv) < 2 or "=" in sys.argv[1]:
        sys.exit("usage: python -m benchmarks.case_folders OUT [diagnose.py overrides, e.g. world=scatterers "
                 "benchmark.size=36]")
    print(main(sys.argv[1], sys.argv[2:]))
