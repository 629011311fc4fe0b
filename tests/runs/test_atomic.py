"""Atomic output: the target appears whole or not at all; leftovers of killed runs are removed."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys

import pytest

from handradar.atomic import (
    _host,
    atomic_path,
    atomic_write_text,
    file_lock,
    remove_stale_parts,
)


def dead_pid() -> int:
    """The id of a process that has ended (and been reaped)."""
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(proc.stdout)


def test_success_and_failure(tmp_path):
    atomic_write_text(tmp_path / "a.txt", "done")
    assert (tmp_path / "a.txt").read_text() == "done"
    with pytest.raises(RuntimeError), atomic_path(tmp_path / "b.txt") as tmp:
        assert tmp.name.startswith(f".b.txt.{os.getpid()}@{_host()}.") and tmp.suffix == ".part"
        tmp.write_text("half")
        raise RuntimeError
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_stale_temporary_files_of_the_target_are_removed(tmp_path):
    host = _host()
    dead = dead_pid()
    stale = tmp_path / f".x.h5.{dead}@{host}.abc123.part"
    live = tmp_path / f".x.h5.{os.getpid()}@{host}.def456.part"  # a concurrent writer of the same target
    foreign = tmp_path / f".x.h5.{dead}@another-host.ghi789.part"  # a shared disk: cannot tell, keep it
    legacy = tmp_path / ".x.h5.jkl012.part"  # no owner recorded
    other_target = tmp_path / f".y.h5.{dead}@{host}.mno345.part"
    for p in (stale, live, foreign, legacy, other_target):
        p.write_bytes(b"partial")
    assert remove_stale_parts(tmp_path / "x.h5") == [stale]
    atomic_write_text(tmp_path / "y.h5", "whole")  # a run writing y.h5 clears y.h5's leftovers only
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [live.name, foreign.name, legacy.name, "y.h5"])


def test_target_names_with_glob_characters(tmp_path):
    dead = dead_pid()
    mine = tmp_path / f".run[1].h5.{dead}@{_host()}.abc.part"
    near = tmp_path / f".run1.h5.{dead}@{_host()}.abc.part"  # what the unescaped pattern run[1] would match
    mine.write_bytes(b"")
    near.write_bytes(b"")
    atomic_write_text(tmp_path / "run[1].h5", "whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([near.name, "run[1].h5"])


def test_unwritable_places_name_the_folder(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(NotADirectoryError) as info:
        atomic_write_text(tmp_path / "file" / "deeper" / "x.txt", "")
    assert info.value.filename == str(tmp_path / "file")


def test_a_busy_lock_raises_the_given_error_instead_of_waiting(tmp_path):
    lock = tmp_path / "state.lock"
    with open(lock, "a") as holder:  # another holder: flock conflicts across open file descriptions
        fcntl.flock(holder, fcntl.LOCK_EX)
        with pytest.raises(RuntimeError, match="^another job runs$"), file_lock(lock, busy_error="another job runs"):
            pass
        fcntl.flock(holder, fcntl.LOCK_UN)
    ran = []
    with file_lock(lock, busy_error="another job runs"):  # free again: taken
        ran.append(True)
    assert ran == [True]
