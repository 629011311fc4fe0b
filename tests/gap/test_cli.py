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
from handradar.gap.benchmark import OUTPUT_KEYS, benchmark_world
from handradar.gap.report import fitted_simulator, validate_report
from handradar.runs.hydra import command_line, group_choice
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
    overrides = ["+experiment=gap_benchmark", "world=heldout2", "benchmark.size=36", "diagnose.folds=1",
                 "diagnose.coherences=[1.0,0.5]", "benchmark.state_dir=/tmp/st", "benchmark.record_dir=/tmp/r",
                 "progress=false"]
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("diagnose", overrides=overrides, return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)
    try:
        cmd = command_line("diagnose.py", OUTPUT_KEYS)
        world = group_choice("world")  # names the benchmark's record (heldout2_36.json) and its MLflow run
    finally:
        HydraConfig.instance().cfg = None  # other tests run outside a Hydra job
    assert cmd == ("python diagnose.py +experiment=gap_benchmark world=heldout2 benchmark.size=36 "
                   "diagnose.folds=1 'diagnose.coherences=[1.0,0.5]'")
    assert world == "heldout2" and group_choice("world") is None  # outside a Hydra job: not known


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
    # every (world, size): the same frozen diagnosis; only the world's physics and the size's recordings change
    runs = {(w, n): _compose(["+experiment=gap_benchmark", f"world={w}", f"benchmark.size={n}"])
            for w in ("default", "heldout", "heldout2", "heldout3") for n in (240, 36)}
    for (w, n), c in runs.items():
        OmegaConf.resolve(c)
        assert c.diagnose == b.diagnose and c.sim == b.sim and c.hand == b.hand and c.benchmark.cases == b.benchmark.cases
        assert c.job == b.job and c.benchmark.strengths == b.benchmark.strengths
    assert b.diagnose.folds == "auto"  # 36 rows are cross-fitted by the frozen setting itself, not by the size
    worlds = {k: benchmark_world(c) for k, c in runs.items()}
    for (w, n), world in worlds.items():
        assert len(world["gestures"]) * world["subjects"] * len(world["angles_deg"]) * world["repetitions"] == n
        assert {k: v for k, v in world.items() if k not in ("gestures", "subjects", "repetitions")} == \
               {k: v for k, v in worlds[(w, 240)].items() if k not in ("gestures", "subjects", "repetitions")}
        assert (world["subjects"], world["repetitions"]) == ((4, 2) if n == 240 else (2, 1))
    # the four worlds' physics differ pairwise on every axis the diagnosis could have been tuned to
    names = ("default", "heldout", "heldout2", "heldout3")
    for i, a in enumerate(names):
        for other in names[i + 1:]:
            wa, wb = worlds[(a, 36)], worlds[(other, 36)]
            assert wa["seed"] != wb["seed"] and wa["scene"] != wb["scene"] and wa["effects"] != wb["effects"]
            assert wa["kinematics"] != wb["kinematics"] and wa["leap"] != wb["leap"]


def test_diagnose_command_on_recordings_fast(tmp_path):
    """The fast version of the test below: 8 recordings of the independent writer (a rigid hand whose
    centre is one point reflector, moving along boresight), 4-frame windows, one split, one
    candidate, no RadarWeightNet, no MLflow. The writer's single reflector at the hand centre is what
    the palm effect adds to the bones: palm is named and closes most of the gap (measured +0.979
    [+0.964, +0.988]; noise, when a candidate too, -0.10), and the fitted simulator keeps it."""
    root = tmp_path / "recordings"
    for i in range(8):
        write_recording(root / f"rec{i}", Scene(gesture=("grasp", "circle")[i % 2], subject=f"s{i % 3}",
                                                velocity_m_s=-0.08 - 0.02 * i, repetition=i))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "src"), str(REPO)])}
    args = [sys.executable, str(REPO / "diagnose.py"), f"data.root={root}", f"paths.log_dir={tmp_path / 'logs'}",
            f"paths.cache_dir={tmp_path / 'cache'}", "progress=false", "logger=none", "chain.n_columns=8",
            "diagnose.candidates=[palm]", "diagnose.folds=1", "diagnose.fit_rows=null", "diagnose.n_boot=200",
            "diagnose.radarweightnet=false", "diagnose.rcs_exponents=[1.0]", "hand.sections=8", "hand.rings=9"]
    done = subprocess.run(args, capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    path = Path(done.stdout.strip().splitlines()[-1])  # the report's path is the last line
    assert path.name == "gap_report.json" and path.is_file()
    rep = json.loads(path.read_text())
    validate_report(rep, n_columns=8)
    assert rep["settings"]["folds"] == 1 and (rep["n_calibration"], rep["n_evaluation"]) == (4, 4)
    palm = next(c for c in rep["candidates"] if c["effect"] == "palm")
    assert rep["cause"] == "palm" and palm["gap_closed"] > 0.5 and palm["ci95"][0] > 0.5, rep["candidates"]
    assert OmegaConf.load(path.parent / "fitted_sim.yaml").effects == ["palm"]
    md = (path.parent / "gap_report.md").read_text()
    assert "**Cause: palm**" in md
    figures = [line.split("(")[1].rstrip(")") for line in md.splitlines() if line.startswith("![")]
    assert figures and all((path.parent / f).is_file() for f in figures)


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


def test_a_fitted_simulator_written_before_a_setting_was_removed_still_reads(tmp_path: Path, radar, chain):
    """fitted_sim.yaml files of earlier versions hold bone_extent / doppler_spread at their off value: they read
    as the same simulator; the same keys at any other value are refused, naming them."""
    path = tmp_path / "fitted_sim.yaml"
    path.write_text("effects: [noise]\nrcs_exponent: 0.5\nbone_extent: 0.0\ndoppler_spread: 0.0\n")
    cfg = compose_train(["+experiment=few_shot_5pct", "sim=fitted", f"sim.from_report={path}"])
    sim = SimFactory.from_config(cfg.sim, radar, chain)()
    path.write_text("effects: [noise]\nrcs_exponent: 0.5\n")
    assert sim.key() == SimFactory.from_config(cfg.sim, radar, chain)().key()
    path.write_text("effects: [noise]\nbone_extent: 0.5\n")
    with pytest.raises(FormatError, match=r"unknown simulator setting\(s\) \['bone_extent'\]"):
        SimFactory.from_config(cfg.sim, radar, chain)
