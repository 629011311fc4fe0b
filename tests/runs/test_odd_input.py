"""Clear answers on small or odd input (issue 43, item 3): boolean options, arguments Hydra cannot
read, and train.py / diagnose.py on too few recordings. Each case is written to fail on purpose."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import handradar.config  # noqa: F401  (registers the ${hr_root:} resolver used by the config tree)
from handradar.cli import run_job
from handradar.cli.ingest import USAGE as INGEST_USAGE
from handradar.cli.ingest import main as ingest_main
from handradar.config import VERSION_BASE, config_dir

from handradar.data.datasets import RecordingsFolder
from handradar.data.ingest import ingest
from handradar.data.splits import make_split
from handradar.errors import TooFewRows, UsageError
from handradar.gap.folds import check_rows
from handradar.gap.job import run as diagnose_run
from handradar.runs.cli import bool_option, run_cli, shell_quoted, unparsable_override
from handradar.tasks.train import run as train_run
from handradar.vocab import GESTURES
from tests.data.writer import Scene, write_recording

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
ENV = {**os.environ, "PYTHONPATH": str(REPO / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}


def run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(argv, cwd=cwd, env=ENV, capture_output=True, text=True, timeout=300)


# ---- boolean options ---------------------------------------------------------------------------
def test_boolean_options_accept_true_or_false_only():
    for value, expected in ((True, True), (False, False), ("true", True), ("False", False), (np.bool_(True), True)):
        assert bool_option("strict", value) is expected
    for value in ("off", "on", "yes", "no", "1", "", 0, 1, None, 0.0):
        with pytest.raises(UsageError, match=f"^strict must be true or false, found {value!r}$"):
            bool_option("strict", value)


def test_ingest_refuses_a_flag_that_is_not_true_or_false(tmp_path, short_chain):
    write_recording(tmp_path / "recs" / "a", Scene())
    for key in ("strict", "allow_truncated", "iq_swap", "doppler_flip", "check"):
        with pytest.raises(UsageError, match=f"^{key} must be true or false, found 'off'$"):
            ingest(tmp_path / "recs", tmp_path / "d.h5", short_chain, progress=False, **{key: "off"})
    assert not (tmp_path / "d.h5").exists()
    with pytest.raises(UsageError, match="^iq_swap must be true or false, found 'off'$"):  # data=recordings
        RecordingsFolder(tmp_path / "recs", short_chain, tmp_path / "cache", iq_swap="off")


def test_a_usage_error_prints_the_usage_line_and_exits_2(capsys):
    def job():
        raise UsageError("allow_truncated must be true or false, found 'off'")

    with pytest.raises(SystemExit) as info:
        run_cli(job, OmegaConf.create({}), usage="tool x=X")
    assert info.value.code == 2
    assert capsys.readouterr().err.splitlines() == ["usage: tool x=X",
                                                    "error: allow_truncated must be true or false, found 'off'"]


def test_cli_allow_truncated_off_is_a_usage_error(tmp_path, capsys):
    write_recording(tmp_path / "recs" / "a", Scene())
    with initialize_config_dir(config_dir=str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("ingest", overrides=[f"root={tmp_path / 'recs'}", f"out={tmp_path / 'd.h5'}", "allow_truncated=off"])
    with pytest.raises(SystemExit) as info:
        ingest_main(cfg)  # the entry point with its config composed as on the command line
    assert info.value.code == 2
    assert capsys.readouterr().err.splitlines() == [f"usage: {INGEST_USAGE}",
                                                    "error: allow_truncated must be true or false, found 'off'"]
    assert not (tmp_path / "d.h5").exists()


# ---- arguments Hydra's override lexer cannot read ----------------------------------------------
def test_an_unreadable_override_gets_a_quoting_hint():
    line = unparsable_override(["out=x.h5", "root=/data/café"])
    assert line == ("cannot read the argument 'root=/data/café' (Hydra reads an unquoted value of ASCII letters, "
                    "digits and a few signs only); quote the value for Hydra inside the shell's quotes: "
                    "\"root='/data/café'\"")
    assert "Hydra's override grammar" in unparsable_override(["root=/data/take (2)"])
    # what parses is left alone: sweeps, flags with values, appended groups, quoted values
    assert unparsable_override(["-m", "seed=1,2", "--cfg", "job", "+experiment=few_shot_5pct",
                                "root='/data/café'", "root=/data/my dir"]) is None
    assert shell_quoted("root=it's") == "'root=\"it's\"'"


def test_cli_unquoted_path_hint_and_the_hinted_form_parses(tmp_path):
    folder = tmp_path / "café"
    argv = [str(BIN / "handradar-ingest"), f"root={folder}", f"out={tmp_path / 'd.h5'}",
            f"hydra.run.dir={tmp_path / 'hydra'}"]
    proc = run(argv, tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    usage, error = proc.stderr.splitlines()
    assert usage.startswith("usage: handradar-ingest root=DIR")
    assert error.startswith(f"error: cannot read the argument 'root={folder}' (")
    assert error.endswith(f"quote the value for Hydra inside the shell's quotes: \"root='{folder}'\"")
    # the hint's form, as the shell hands it over, gets past Hydra to ingest's own answer
    argv[1] = f"root='{folder}'"
    proc = run(argv, tmp_path)
    assert proc.returncode == 1 and proc.stderr.splitlines()[-1].startswith(f"error: {folder}: no such directory")


# ---- too few rows ------------------------------------------------------------------------------
def test_a_split_of_too_few_rows_states_the_minimum():
    spec = {"kind": "few_shot", "fraction": 0.05, "test": "fixed"}
    with pytest.raises(TooFewRows, match=r"training needs at least 2 gestures with at least 2 rows each \(1 to train "
                                         r"on, 1 to test on\); the data hold 3 rows: grasp 1, circle 1, slide 1 "):
        make_split(spec, np.array([GESTURES.index(g) for g in ("grasp", "circle", "slide")]), {}, seed=1)
    with pytest.raises(TooFewRows, match="trains on 1 rows of 1 gesture"):  # one gesture: nothing to tell apart
        make_split(spec, np.zeros(6, dtype=np.int64), {}, seed=1)
    split = make_split(spec, np.array([0, 0, 1, 1]), {}, seed=1)  # the minimum passes
    assert len(split.train) == 2 and len(split.test) == 2
    meta = {"angle_deg": np.array([0.0, 0.0, 30.0, 30.0])}
    with pytest.raises(TooFewRows, match="in-distribution rows of at least 2 gestures"):
        make_split({"kind": "ood", "ood": "angle"}, np.array([0, 0, 1, 1]), meta, seed=1)


def test_the_diagnosis_states_its_minimum():
    three = np.array([GESTURES.index(g) for g in ("grasp", "circle", "slide")])
    with pytest.raises(TooFewRows, match=r"^too few rows to diagnose: the diagnosis needs at least 2 rows of each "
                                         r"gesture .*the data hold 3 rows: grasp 1, circle 1, slide 1, which leave 2 "
                                         r"calibration and 1 evaluation rows with folds=auto$"):
        check_rows(three, "auto", 0.5, 0)
    check_rows(np.array([0, 0, 1, 1]), "auto", 0.5, 0)  # 2 per gesture: cross-fitted, every row scored
    check_rows(np.array([0, 0]), "auto", 0.5, 0)
    with pytest.raises(TooFewRows, match="leave 1 calibration and 1 evaluation rows with folds=1"):
        check_rows(np.array([0, 0]), 1, 0.5, 0)
    with pytest.raises(TooFewRows, match="diagnose.folds = 3 exceeds the 2 rows of class"):
        check_rows(np.array([0, 0, 1, 1]), 3, 0.5, 0)


def test_diagnose_and_train_on_three_recordings_state_the_minimum(tmp_path, capsys):
    """Each entry point's job through its error handler (handradar.cli.run_job), as diagnose.py and
    train.py run it: one line, exit status 1, before any fit (the diagnosis used to fail after its
    calibration, train.py inside its split)."""
    for g in ("grasp", "circle", "slide"):
        write_recording(tmp_path / "recs" / g, Scene(gesture=g))
    common = [f"data.root={tmp_path / 'recs'}", f"paths.cache_dir={tmp_path / 'cache'}",
              f"paths.log_dir={tmp_path / 'logs'}", "logger=none"]
    with initialize_config_dir(config_dir=str(config_dir()), version_base=VERSION_BASE):
        jobs = {"diagnose": (diagnose_run, compose("diagnose", overrides=common)),
                "train": (lambda cfg: train_run(cfg, run_dir=tmp_path / "run"),
                          compose("train", overrides=["data=recordings", *common]))}
    lines = {}
    for name, (job, cfg) in jobs.items():
        with pytest.raises(SystemExit) as info:
            run_job(job, cfg, usage=name)
        err = capsys.readouterr().err.splitlines()
        assert info.value.code == 1 and len(err) == 1, err
        lines[name] = err[0]
    assert lines["diagnose"] == (
        "error: too few rows to diagnose: the diagnosis needs at least 2 rows of each gesture (with diagnose.folds="
        "auto; one calibration/evaluation split needs 1 calibration and 2 evaluation rows); the data hold 3 rows: "
        "grasp 1, circle 1, slide 1, which leave 2 calibration and 1 evaluation rows with folds=auto")
    assert lines["train"] == (
        "error: too few rows for the split {'kind': 'few_shot', 'fraction': 0.05, 'test': 'fixed', 'test_fraction': "
        "0.2, 'test_seed': 0}: training needs at least 2 gestures with at least 2 rows each (1 to train on, 1 to "
        "test on); the data hold 3 rows: grasp 1, circle 1, slide 1 (the split trains on 0 rows of 0 gesture(s) "
        "and tests on 3)")
