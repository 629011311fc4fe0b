"""diagnose.py: config composition (every preset instantiates) and the command end to end on recordings."""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import OmegaConf

from handradar.config import VERSION_BASE, config_dir
from handradar.data.datasets import ReferenceWorld
from handradar.errors import FormatError
from handradar.gap.benchmark import OUTPUT_KEYS
from handradar.gap.report import fitted_simulator, validate_report
from handradar.runs.hydra import command_line
from handradar.sim.factory import SimFactory
from tests.data.writer import Scene, write_recording
from tests.tasks.fakes import compose_train

REPO = Path(__file__).resolve().parents[2]


def _compose(overrides):
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        return compose("diagnose", overrides=overrides, return_hydra_config=False)


def test_benchmark_names_the_command_that_reproduces_it_without_output_locations():
    """The results file's command: the job's overrides as typed (shell-quoted), minus where outputs go."""
    assert command_line("diagnose.py", OUTPUT_KEYS) is None  # outside a Hydra job
    overrides = ["+experiment=gap_benchmark_heldout2", "diagnose.noise_floor=true", "diagnose.coherences=[1.0,0.5]",
                 "benchmark.state_dir=/tmp/st", "benchmark.results_md=/tmp/r.md", "progress=false"]
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("diagnose", overrides=overrides, return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)
    try:
        cmd = command_line("diagnose.py", OUTPUT_KEYS)
    finally:
        HydraConfig.instance().cfg = None  # other tests run outside a Hydra job
    assert cmd == ("python diagnose.py +experiment=gap_benchmark_heldout2 diagnose.noise_floor=true "
                   "'diagnose.coherences=[1.0,0.5]'")


def test_default_config_and_benchmark_preset_compose_and_instantiate(radar, chain):
    cfg = _compose(["data.root=/nowhere", "sim.effects=[noise]", "+sim.effect_params.noise.snr_db=15"])
    assert instantiate(cfg.data.dataset).root == Path("/nowhere")
    factory = SimFactory.from_config(cfg.sim, radar, chain)
    assert factory.effects == {"noise": {"snr_db": 15}}
    sim = factory({"noise": {"snr_db": 15}, "palm": {}})
    assert [e.name for e in sim.effects] == ["palm", "noise"] and sim.effect("noise").values() == {"snr_db": 15.0}
    assert cfg.logger.tracking_uri.startswith("sqlite:///") and cfg.logger.tracking_uri.endswith("mlflow/mlflow.db")
    b = _compose(["+experiment=gap_benchmark"])
    OmegaConf.resolve(b)  # every interpolation resolves (the run logs the resolved config)
    assert isinstance(instantiate(_compose(["data=world"]).data.dataset), ReferenceWorld)
    assert b.job == "handradar.gap.benchmark.run" and b.sim.effects == [] and not b.diagnose.radarweightnet
    assert b.benchmark.builder == "handradar.world.build_world_dataset"
    assert len(b.benchmark.cases) == 10 and {"nothing", "iq_imbalance"} <= set(b.benchmark.cases)
    assert SimFactory.from_config(b.sim, radar, chain)({}).hand.sections == 10  # the preset's coarser visibility mesh
    # the held-out preset: the same frozen diagnosis on the held-out world's physics
    h = _compose(["+experiment=gap_benchmark_heldout"])
    OmegaConf.resolve(h)
    assert h.diagnose == b.diagnose and h.sim == b.sim and h.hand == b.hand and h.benchmark.cases == b.benchmark.cases
    assert h.world.seed != b.world.seed and h.world.scene != b.world.scene and h.world.effects != b.world.effects
    assert h.benchmark.results_md.endswith("gap_benchmark_heldout.md") and h.benchmark.figure != b.benchmark.figure
    # the 36-recording presets: the frozen diagnosis (diagnose.folds=auto cross-fits them), 6 x 2 x 3 recordings per case
    s, sh = _compose(["+experiment=gap_benchmark_36"]), _compose(["+experiment=gap_benchmark_36_heldout"])
    OmegaConf.resolve(s), OmegaConf.resolve(sh)
    assert s.diagnose == b.diagnose and b.diagnose.folds == "auto" and s.sim == b.sim and s.benchmark.cases == b.benchmark.cases
    w = s.benchmark.world
    assert len(w.gestures) * w.subjects * len(s.world.angles_deg) * w.repetitions == 36
    assert sh.diagnose == s.diagnose and sh.benchmark.world == w and sh.world.seed == h.world.seed
    # the test suite's second held-out world: the same frozen diagnosis, physics unlike both other worlds
    h2, sh2 = _compose(["+experiment=gap_benchmark_heldout2"]), _compose(["+experiment=gap_benchmark_36_heldout2"])
    OmegaConf.resolve(h2), OmegaConf.resolve(sh2)
    assert h2.diagnose == b.diagnose and h2.sim == b.sim and h2.hand == b.hand and h2.benchmark.cases == b.benchmark.cases
    assert sh2.diagnose == s.diagnose and sh2.benchmark.world == w and sh2.world == h2.world
    for other in (b, h):
        assert h2.world.seed != other.world.seed and h2.world.scene != other.world.scene
        assert h2.world.kinematics != other.world.kinematics and h2.world.effects != other.world.effects
    # the third held-out world (36 recordings only): the same frozen diagnosis, physics unlike the other three
    h3, sh3 = _compose(["+experiment=gap_benchmark_heldout3"]), _compose(["+experiment=gap_benchmark_36_heldout3"])
    OmegaConf.resolve(h3), OmegaConf.resolve(sh3)
    assert h3.diagnose == b.diagnose and h3.sim == b.sim and h3.hand == b.hand and h3.benchmark.cases == b.benchmark.cases
    assert sh3.diagnose == s.diagnose and sh3.sim == s.sim and sh3.benchmark.world == w and sh3.world == h3.world
    for other in (b, h, h2):
        assert sh3.world.seed != other.world.seed and sh3.world.scene != other.world.scene
        assert sh3.world.kinematics != other.world.kinematics and sh3.world.effects != other.world.effects
    presets = (b, h, s, sh, h2, sh2, h3, sh3)
    assert len({m.benchmark.results_md for m in presets}) == 8 and len({m.benchmark.figure for m in presets}) == 8


@pytest.mark.slow
def test_diagnose_command_on_recordings(tmp_path):
    root = tmp_path / "recordings"
    for i in range(8):
        write_recording(root / f"rec{i}", Scene(gesture=("grasp", "circle")[i % 2], subject=f"s{i % 3}",
                                                velocity_m_s=-0.08 - 0.02 * i, repetition=i,
                                                extra_meta={"truth": {"effects": {"palm": {"enabled": True}}}}))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "src"), str(REPO)])}
    args = [sys.executable, str(REPO / "diagnose.py"), f"data.root={root}", f"paths.log_dir={tmp_path / 'logs'}",
            f"paths.cache_dir={tmp_path / 'cache'}", "progress=false", "diagnose.candidates=[palm,noise]",
            "diagnose.fit_rows=null", "diagnose.n_boot=200", "diagnose.rwn_epochs=2", "diagnose.rwn_hidden=16",
            "hand.sections=8", "hand.rings=9"]
    done = subprocess.run(args, capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    path = Path(done.stdout.strip().splitlines()[-1])  # the report's path is the last line
    assert path.name == "gap_report.json" and path.is_file()
    rep = json.loads(path.read_text())
    validate_report(rep)
    # diagnose.folds=auto: 8 recordings cross-fitted in 3 folds (4 rows a gesture: 2 + 1 + 1), every one
    # scored by fits on the other folds; the largest fold holds 4, so the fewest rows a fit saw is 4
    assert rep["settings"]["folds"] == 3 and rep["n_evaluation"] == 8 and rep["n_calibration"] == 4
    assert {c["effect"] for c in rep["candidates"]} == {"palm", "noise"}
    rwn = rep["radarweightnet"]
    assert rwn["epochs"] == 2 and len(rwn["ci95"]) == 2 and set(rwn["weight_correlation"]) == {"palm", "noise"}
    md = (path.parent / "gap_report.md").read_text()
    assert "## Which" in md and "RadarWeightNet readout" in md
    for line in md.splitlines():  # every figure the markdown shows exists
        if line.startswith("!["):
            assert (path.parent / line.split("(")[1].rstrip(")")).is_file(), line
    db = tmp_path / "logs" / "mlflow" / "mlflow.db"
    with sqlite3.connect(db) as con:
        names = {r[0] for r in con.execute("select key from metrics")}
        tags = dict(con.execute("select key, value from tags"))
    assert "gap/baseline_ssim" in names and "gap/closed_palm" in names
    assert tags["handradar.cause"] == rep["cause"]


def test_fitted_simulator_round_trips_through_train_composition(tmp_path: Path, radar, chain):
    """diagnose.py writes the fitted simulator (calibrated RCS exponent, kept effects with their fitted
    values); train.py composes it with sim=fitted sim.from_report=PATH and builds exactly that simulator."""
    report = {"baseline": {"effects": {"noise": {"snr_db": 12.0}}, "calibration": {"rcs_exponent": 0.25}},
              "after": {"effects": ["sync_offset", "tracking_jitter"],
                        "params": {"sync_offset": {"offset_s": 0.03}, "tracking_jitter": {"sigma_s": 0.02}}}}
    diag_cfg = _compose(["data.root=/nowhere", "sim.effects=[noise]", "+sim.effect_params.noise.snr_db=12"])
    path = tmp_path / "fitted_sim.yaml"
    path.write_text(OmegaConf.to_yaml(fitted_simulator(report, OmegaConf.to_container(diag_cfg.sim, resolve=True))))
    cfg = compose_train(["+experiment=few_shot_5pct", "sim=fitted", f"sim.from_report={path}"])
    sim = SimFactory.from_config(cfg.sim, radar, chain)()
    assert [e.name for e in sim.effects] == ["tracking_jitter", "sync_offset", "noise"]  # pipeline order
    assert sim.rcs_exponent == 0.25 and sim.effect("noise").values() == {"snr_db": 12.0}
    assert sim.effect("sync_offset").values() == pytest.approx({"offset_s": 0.03})
    assert sim.effect("tracking_jitter").values() == pytest.approx({"sigma_s": 0.02})
    assert sim.hand.sections == SimFactory.from_config(diag_cfg.sim, radar, chain)().hand.sections
    bad = _compose(["data.root=/nowhere", "sim=fitted", f"sim.from_report={tmp_path}/missing.yaml"])
    with pytest.raises(FormatError, match="fitted simulator not found"):
        SimFactory.from_config(bad.sim, radar, chain)
    path.write_text("effects: [noise]\nrcs_exponnet: 0.5\n")
    with pytest.raises(FormatError, match="unknown simulator setting"):
        SimFactory.from_config(cfg.sim, radar, chain)
