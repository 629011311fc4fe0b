"""Folders of 1 to 12 recordings through diagnose.py and train.py (issue 55): each answers with the
project's one-line error (exit status 1, stating the minimum) or with a report that names what it
skipped and why, never with a traceback.

The rules behind the sizes: the diagnosis needs 2 rows of each gesture; its RadarWeightNet readout
scores one fold's held-out rows with a paired bootstrap, which needs 2 of them, and a fold holds 2
rows where it holds 2 gestures or where a gesture has more rows than there are folds. A folder of one
gesture is so refused at 1 recording, diagnosed without the readout at 2 and 3 (2 and 3 folds of one
row each), and diagnosed in full from 4; a folder of two gestures is refused up to 3 and diagnosed in
full from 4. train.py's default few-shot split trains on 1 row per gesture, too few for its closed
loop (synth.fit_sim=effects), so every size up to 12 is refused in one line; with split.fraction=0.5
it trains from 6 recordings.

The code paths (rows check, fold choice, the readout's rows) are checked at every size without
simulating; the commands themselves at 1, 2, 3 and 4 recordings (the smallest that runs every step)
in the default suite, and at every size from 1 to 12 in the slow sweep.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from handradar.errors import TooFewRows
from handradar.gap.folds import (
    check_rows,
    cross_folds,
    fold_positions,
    readout_fold,
    readout_skip_reason,
    resolve_folds,
)
from handradar.gap.report import validate_report
from handradar.metrics import bootstrap_gap_closed
from tests.data.writer import Scene, write_recording

REPO = Path(__file__).resolve().parents[2]
SIZES = range(1, 13)
ONE, TWO = ("grasp",), ("grasp", "circle")
# cheap settings: 4-frame windows, one candidate, coarse hand mesh, a 1-epoch readout, no MLflow
COMMON = ["logger=none", "chain.n_columns=8", "hand.sections=8", "hand.rings=9"]
DIAGNOSE = ["progress=false", "diagnose.candidates=[palm]", "diagnose.n_boot=200", "diagnose.rcs_exponents=[1.0]",
            "diagnose.rwn_epochs=1", "diagnose.rwn_hidden=8"]
TRAIN = ["data=recordings", "trainer.max_steps=2", "trainer.enable_progress_bar=false",
         "synth.phases=[{epochs: 1, lr: 5.0e-4, batch_size: 4}]", "synth.fit.n_boot=100",
         "+synth.fit.candidates=[palm]", "+synth.fit.rcs_exponents=[1.0]"]


def labels_of(n: int, gestures: tuple[str, ...]) -> np.ndarray:
    return np.arange(n) % len(gestures)


def refused(labels: np.ndarray) -> bool:
    """The diagnosis's minimum: 2 rows of each gesture."""
    return np.bincount(labels).min() < 2


def readout_runs(labels: np.ndarray, k: int) -> bool:
    """Some fold of k (each holding every gesture) holds 2 rows: 2 gestures, or a gesture with more rows than folds."""
    return len(np.unique(labels)) > 1 or len(labels) > k


@pytest.mark.parametrize("gestures", [ONE, TWO])
def test_every_size_is_refused_in_one_line_or_has_a_readout_fold_or_a_reason(gestures):
    """The exact code paths of every size: the rows check, the folds, the readout's fold and its rows."""
    skipped, full = [], []
    for n in SIZES:
        labels = labels_of(n, gestures)
        if refused(labels):
            with pytest.raises(TooFewRows, match="^too few rows to diagnose: the diagnosis needs at least 2 rows of "
                                                 "each gesture") as err:
                check_rows(labels, "auto", 0.5, 0)
            assert "\n" not in str(err.value)
            continue
        check_rows(labels, "auto", 0.5, 0)
        k = resolve_folds("auto", labels)
        folds = cross_folds(labels, k, 0)
        held_out = [len(f) for f in folds]
        chosen = readout_fold(held_out)
        assert (chosen is not None) == readout_runs(labels, k), (n, held_out)
        if chosen is None:
            assert readout_skip_reason(held_out).startswith("no fold holds the 2 held-out rows")
            skipped.append(n)
            continue
        full.append(n)
        assert held_out[chosen] >= 2 and all(h < 2 for h in held_out[:chosen])  # fold 0 wherever it can
        pos = fold_positions(held_out, chosen)  # the readout's rows in the evaluation arrays (folds in order)
        np.testing.assert_array_equal(np.concatenate(folds)[pos], folds[chosen])
        bootstrap_gap_closed(np.full(len(pos), 0.5), np.full(len(pos), 0.6), n_boot=20)  # what failed on 1 row
    assert (skipped, full[0]) == (([2, 3], 4) if gestures == ONE else ([], 4))
    with pytest.raises(ValueError, match=">= 2 examples"):  # why one row is never handed to the readout
        bootstrap_gap_closed(np.array([0.5]), np.array([0.6]), n_boot=20)


def write_folder(root: Path, n: int, gestures: tuple[str, ...]) -> Path:
    for i in range(n):
        write_recording(root / f"rec{i}", Scene(gesture=gestures[i % len(gestures)], subject=f"s{i % 3}",
                                                velocity_m_s=-0.08 - 0.02 * i, repetition=i))
    return root


def run(script: str, args: list[str], tmp_path: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "src"), str(REPO)])}
    paths = [f"paths.log_dir={tmp_path / 'logs'}", f"paths.cache_dir={tmp_path / 'cache'}"]
    return subprocess.run([sys.executable, str(REPO / script), *paths, *COMMON, *args], capture_output=True,
                          text=True, cwd=tmp_path, env=env, timeout=900)


def one_line_error(done: subprocess.CompletedProcess, start: str) -> None:
    err = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(err) == 1 and err[0].startswith(start), done.stderr[-3000:]


def check_diagnose(tmp_path: Path, n: int, gestures: tuple[str, ...]) -> None:
    root = write_folder(tmp_path / "recordings", n, gestures)
    done = run("diagnose.py", [f"data.root={root}", *DIAGNOSE], tmp_path)
    labels = labels_of(n, gestures)
    assert "Traceback" not in done.stderr
    if refused(labels):
        one_line_error(done, "error: too few rows to diagnose: the diagnosis needs at least 2 rows of each gesture")
        return
    assert done.returncode == 0, done.stderr[-3000:]
    path = Path(done.stdout.strip().splitlines()[-1])  # the report's path is the last line
    rep = json.loads(path.read_text())
    validate_report(rep, n_columns=8)
    md = (path.parent / "gap_report.md").read_text()
    k = rep["settings"]["folds"]
    assert rep["n_evaluation"] == n and k == resolve_folds("auto", labels)
    if readout_runs(labels, k):
        rwn = rep["radarweightnet"]
        assert rep["skipped"] == {} and rwn["evaluation_rows"] >= 2 and "RadarWeightNet readout (" in md
        assert rwn["fold"] == readout_fold([len(f) for f in cross_folds(labels, k, 0)])
    else:
        assert "radarweightnet" not in rep and set(rep["skipped"]) == {"radarweightnet"}
        assert f"- Skipped: the RadarWeightNet readout: {rep['skipped']['radarweightnet']}" in md
        assert rep["skipped"]["radarweightnet"].startswith(f"no fold holds the 2 held-out rows its paired-bootstrap "
                                                           f"CI needs (the {k} folds hold 1")


def check_train(tmp_path: Path, n: int, extra: tuple[str, ...] = ()) -> None:
    root = write_folder(tmp_path / "recordings", n, TWO)
    done = run("train.py", [f"data.root={root}", *TRAIN, *extra], tmp_path)
    assert "Traceback" not in done.stderr
    if done.returncode == 0:  # a trained job: its run folder, with the metrics, is the last line
        assert (Path(done.stdout.strip().splitlines()[-1]) / "metrics.json").is_file()
    elif n < 4:  # the split: 2 gestures with 2 rows each
        one_line_error(done, "error: too few rows for the split")
    else:  # the closed loop on the split's training rows
        one_line_error(done, "error: synth.fit_sim=effects fits the simulator on the split's")


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_diagnose_on_tiny_folders(tmp_path, n):
    """One gesture: refused at 1, the readout skipped (reason in gap_report.json and .md) at 2 and 3, in full at 4."""
    check_diagnose(tmp_path, n, ONE)


def test_train_on_a_tiny_folder(tmp_path):
    """4 recordings of 2 gestures: past the split's minimum, refused by the closed loop's in one line (the
    split's own refusal: tests/runs/test_odd_input.py; every size: the slow sweep)."""
    check_train(tmp_path, 4)


@pytest.mark.slow
@pytest.mark.parametrize("gestures", [ONE, TWO], ids=["one_gesture", "two_gestures"])
@pytest.mark.parametrize("n", SIZES)
def test_diagnose_sweep(tmp_path, n, gestures):
    check_diagnose(tmp_path, n, gestures)


@pytest.mark.slow
@pytest.mark.parametrize("extra", [(), ("split.fraction=0.5",)], ids=["default_split", "half_split"])
@pytest.mark.parametrize("n", SIZES)
def test_train_sweep(tmp_path, n, extra):
    check_train(tmp_path, n, extra)
