"""The one gap_benchmark preset composes, for each (world, size), exactly the settings of the eight presets
it replaced (gap_benchmark[_36][_heldout|_heldout2|_heldout3], captured at commit b341d26 in
gap_benchmark_golden.json): only output paths and run names may differ."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from handradar.config import VERSION_BASE, config_dir
from handradar.errors import HandradarError
from handradar.gap.benchmark import benchmark_world
from handradar.runs.mlflow import flatten

GOLDEN = json.loads((Path(__file__).parent / "gap_benchmark_golden.json").read_text())
PATHS = ["paths.root_dir=/ROOT", "paths.log_dir=/LOG", "paths.cache_dir=/CACHE"]  # as when the golden was taken
NAMES = {"task_name", "logger.experiment_name", "logger.artifact_location"}  # run names and where outputs go
# the new preset's own keys: their effect is effective_world (folders: null, the world's cases)
LAYERS = ("size", "sizes", "world", "record_dir", "folders")


def _compose(overrides: list[str]):
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        return compose("diagnose", overrides=["+experiment=gap_benchmark", *PATHS, *overrides])


def effective_settings(cfg) -> dict:
    """Flattened config without output paths and names, plus the world every case shares
    (``effective_world``); a world key equal to ``world.*`` is left out, as in the golden file."""
    c = OmegaConf.to_container(cfg, resolve=True)
    for key in LAYERS:
        c["benchmark"].pop(key, None)
    flat = {k: v for k, v in flatten(c).items() if k not in NAMES}
    flat.update(flatten({"effective_world": benchmark_world(cfg)}))
    flat = json.loads(json.dumps(flat))  # the golden file's types (lists, not tuples)
    return {k: v for k, v in flat.items()
            if not any(k.startswith(pre) and flat.get("world." + k[len(pre):], object()) == v
                       for pre in ("data.dataset.world.", "effective_world."))}


@pytest.mark.parametrize("run", sorted(GOLDEN["runs"]))
def test_world_and_size_compose_the_replaced_preset(run: str):
    world, size = run.rsplit("_", 1)
    got = effective_settings(_compose([f"world={world}", f"benchmark.size={size}"]))
    want = {**GOLDEN["shared"], **GOLDEN["runs"][run]}
    diff = {k: (got.get(k, "<missing>"), want.get(k, "<missing>")) for k in got.keys() | want.keys()
            if got.get(k, "<missing>") != want.get(k, "<missing>")}
    assert not diff, f"{run}: (new, old) differ at {diff}"


def test_default_size_is_240_and_the_golden_file_tells_the_sizes_apart():
    assert _compose([]).benchmark.size == 240
    assert effective_settings(_compose([])) == {**GOLDEN["shared"], **GOLDEN["runs"]["default_240"]}
    # the check above could not pass by accident: the sizes differ in the golden file itself
    assert GOLDEN["runs"]["default_240"]["effective_world.subjects"] != GOLDEN["runs"]["default_36"]["effective_world.subjects"]


def test_a_size_the_preset_does_not_define_is_a_one_line_error():
    with pytest.raises(HandradarError, match=r"benchmark.size=100: not one of the sizes in benchmark.sizes \(720, 240, 36\)"):
        benchmark_world(_compose(["benchmark.size=100"]))
    # a world override that breaks the size's count is named, not run under the wrong label
    with pytest.raises(HandradarError, match=r"benchmark.size=36: the world settings give 48 recordings per case"):
        benchmark_world(_compose(["benchmark.size=36", "+benchmark.world.subjects=2", "+benchmark.world.repetitions=2",
                                  "+benchmark.world.angles_deg=[0.0,30.0]"]))


@pytest.mark.parametrize("world", ["default", "heldout", "heldout2", "heldout3", "scatterers"])
def test_size_720_is_every_world_at_its_own_size(world: str):
    from handradar.world import world_config

    w = world_config(benchmark_world(_compose([f"world={world}", "benchmark.size=720"])))
    assert (len(w.gestures), w.subjects, len(w.angles_deg), w.repetitions) == (10, 8, 3, 3)
