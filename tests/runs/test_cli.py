"""The CLI error handler (handradar.runs.cli.run_cli) in process, and every console entry point's usage line."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from handradar.atomic import atomic_path
from handradar.errors import FormatError
from handradar.runs.cli import Terminated, run_cli

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent


def outcome(job, capsys, cfg=None, **kwargs) -> tuple[int, list[str]]:
    """(exit status, stderr lines) of ``run_cli(job, cfg, usage="tool x=X", **kwargs)``."""
    with pytest.raises(SystemExit) as info:
        run_cli(job, cfg, usage="tool x=X", **kwargs)
    return info.value.code, capsys.readouterr().err.splitlines()


def raise_(exc: BaseException):
    def job():
        raise exc
    return job


def test_success_returns_the_jobs_value(capsys):
    assert run_cli(lambda: 42, usage="tool") == 42
    assert capsys.readouterr().err == ""


def test_bad_input_is_one_line(tmp_path, capsys):
    cfg = OmegaConf.create({"out": str(tmp_path / "x.h5")})
    status, err = outcome(raise_(FormatError(tmp_path / "a.cfg", "expected 3 arguments, found 2", line=4)), capsys,
                          cfg, target="out")
    assert status == 1
    assert err == [f"error: {tmp_path}/a.cfg:4: expected 3 arguments, found 2 (nothing written to {tmp_path}/x.h5)"]
    # a message that introduces a report: the note ends its first line, the report follows untouched
    status, err = outcome(raise_(FormatError("r", "none of the 2 recordings could be ingested:\n  skipped a: b")),
                          capsys, cfg, target="out")
    assert err == [f"error: r: none of the 2 recordings could be ingested (nothing written to {tmp_path}/x.h5):",
                   "  skipped a: b"]
    # other error types only when asked for
    status, err = outcome(raise_(ValueError("numFrames is 0")), capsys, errors=(ValueError,))
    assert (status, err) == (1, ["error: numFrames is 0"])
    with pytest.raises(ValueError):
        run_cli(raise_(ValueError("a bug")), usage="tool")


def test_os_error_names_the_path_and_the_reason(tmp_path, capsys):
    cfg = OmegaConf.create({"out": str(tmp_path / "x.h5"), "resumable_out": str(tmp_path / "recs")})
    status, err = outcome(raise_(PermissionError(13, "Permission denied", "/data/ro")), capsys, cfg, target="out")
    assert (status, err) == (1, [f"error: /data/ro: Permission denied (nothing written to {tmp_path}/x.h5)"])
    status, err = outcome(raise_(OSError(18, "Invalid cross-device link", "/a/.x.part", None, "/b/x")), capsys,
                          cfg, target="resumable_out", resumable=True)
    assert err == [f"error: /a/.x.part -> /b/x: Invalid cross-device link (completed parts are kept in {tmp_path}/recs)"]
    # the target's real problem: atomic_path names the file that stands where a folder is needed
    (tmp_path / "taken").write_text("")

    def write():
        with atomic_path(tmp_path / "taken" / "x.h5") as tmp:
            tmp.write_bytes(b"")

    status, err = outcome(write, capsys)
    assert (status, err) == (1, [f"error: {tmp_path}/taken: Not a directory"])


def test_missing_config_value_prints_usage(capsys):
    cfg = OmegaConf.create({"root": "???", "out": "???", "n": 1})
    status, err = outcome(lambda: cfg.root, capsys, cfg, target="out")
    assert status == 2
    assert err == ["usage: tool x=X", "error: missing value for root, out (give root=... out=...)"]
    # reached through an interpolation (and raised by instantiate in real configs): the ??? key is named
    cfg = OmegaConf.create({"data": {"root": "???", "source": {"root": "${data.root}"}}})
    status, err = outcome(lambda: cfg.data.source.root, capsys, cfg)
    assert (status, err) == (2, ["usage: tool x=X", "error: missing value for data.root (give data.root=...)"])

    def wrapped():
        try:
            return cfg.data.source.root
        except Exception as exc:
            raise RuntimeError("instantiation failed") from exc

    assert outcome(wrapped, capsys, cfg)[0] == 2


def test_ctrl_c_and_sigterm(tmp_path, capsys):
    cfg = OmegaConf.create({"out": str(tmp_path / "x.h5")})
    status, err = outcome(raise_(KeyboardInterrupt()), capsys, cfg, target="out")
    assert (status, err) == (130, [f"interrupted; nothing written to {tmp_path}/x.h5"])
    before = signal.getsignal(signal.SIGTERM)
    written = []

    def job():  # SIGTERM while the output is being written: the temporary file goes, as on Ctrl-C
        with atomic_path(tmp_path / "x.h5") as tmp:
            tmp.write_bytes(b"partial")
            written.append(tmp)
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(30)  # the signal interrupts this at once

    t0 = time.monotonic()
    status, err = outcome(job, capsys, cfg, target="out")
    assert time.monotonic() - t0 < 10
    assert (status, err) == (143, [f"interrupted (SIGTERM); nothing written to {tmp_path}/x.h5"])
    assert written and list(tmp_path.iterdir()) == []
    assert signal.getsignal(signal.SIGTERM) is before  # the handler is only there while the job runs
    assert issubclass(Terminated, KeyboardInterrupt)  # every Ctrl-C clean-up runs on SIGTERM too


def run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize(("command", "usage", "missing"), [
    ([str(BIN / "handradar-ingest")], "handradar-ingest root=DIR out=FILE.h5", "root, out"),
    ([str(BIN / "handradar-world")], "handradar-world out=DIR", "out"),
    ([str(BIN / "handradar-synth"), "source=leap"], "handradar-synth source=sfinge3d|dhg|leap", "source.root, out"),
    ([sys.executable, str(REPO / "train.py"), "data=recordings", "logger=none"], "python train.py", "data.root"),
    ([sys.executable, str(REPO / "diagnose.py")], "python diagnose.py data.root=DIR", "data.root"),
])
def test_every_entry_point_prints_usage_for_a_missing_value(tmp_path, command, usage, missing):
    proc = run([*command, f"paths.log_dir={tmp_path / 'logs'}", f"hydra.run.dir={tmp_path / 'run'}"], tmp_path)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    first, second = proc.stderr.splitlines()[-2:]
    assert first.startswith(f"usage: {usage}")
    assert second.startswith(f"error: missing value for {missing} (give ")


@pytest.mark.parametrize("user_level", [None, "DEBUG"])
def test_a_job_keeps_library_banners_out_of_its_log(tmp_path, capsys, monkeypatch, user_level):
    """run_job (train.py, diagnose.py): Lightning's per-fit banners and MLflow's database set-up lines only
    from WARNING; a MLFLOW_LOGGING_LEVEL the user set is left alone."""
    import logging

    from handradar.cli import run_job

    loggers = [logging.getLogger(n) for n in ("lightning.pytorch", "mlflow")]
    for lg in loggers:
        monkeypatch.setattr(lg, "level", logging.INFO)  # restored after the test
    if user_level is None:
        monkeypatch.delenv("MLFLOW_LOGGING_LEVEL", raising=False)
    else:
        monkeypatch.setenv("MLFLOW_LOGGING_LEVEL", user_level)
    run_job(lambda cfg: tmp_path / "out.json", OmegaConf.create({}), usage="tool")
    assert capsys.readouterr().out.strip() == str(tmp_path / "out.json")
    assert loggers[0].level == logging.WARNING
    assert os.environ["MLFLOW_LOGGING_LEVEL"] == (user_level or "WARNING")
    assert loggers[1].level == (logging.INFO if user_level else logging.WARNING)
    monkeypatch.delenv("MLFLOW_LOGGING_LEVEL")  # the job set it for its process; not for the next test
