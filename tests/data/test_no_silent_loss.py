"""Ingest loses no recording without a word and never destroys its input (issue 43, item 2).

Each test writes the bad case on purpose with the suite's independent writer (tests/data/writer.py).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import h5py
import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from handradar.cli.ingest import main as ingest_main
from handradar.config import VERSION_BASE, config_dir
from handradar.data.datasets import RecordingsFolder
from handradar.data.hdf5 import open_writer, read_meta_group, validate
from handradar.data.ingest import ingest
from handradar.data.recording import find_meta_less_folders, find_recordings, scan
from handradar.errors import FormatError, printable
from handradar.vocab import GESTURES
from tests.data.test_ingest import run_cli
from tests.data.writer import Scene, write_recording


def files_of(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# ---- out= inside the input ---------------------------------------------------------------------
def test_output_inside_the_input_is_refused_and_the_input_kept(tmp_path, short_chain):
    root = tmp_path / "recs"
    rec = write_recording(root / "a", Scene())
    outside = write_recording(tmp_path / "elsewhere" / "b", Scene(gesture="circle"))
    (root / "b").symlink_to(outside)  # a linked recording is input too
    before = files_of(tmp_path)
    cases = {rec / "adc_data.bin": f"{rec}/adc_data.bin: is an input file (under {root})",
             root / "x.h5": f"{root}/x.h5: lies inside the input (under {root})",
             rec: f"{rec}: the output path is a directory",
             outside / "x.h5": f"{outside}/x.h5: lies inside the input (under {root}/b)"}
    for out, message in cases.items():
        with pytest.raises(FormatError) as info:
            ingest(root, out, short_chain, progress=False)
        assert str(info.value).startswith(message), str(info.value)
    assert files_of(tmp_path) == before  # nothing replaced, nothing added


def test_cli_output_onto_a_recordings_capture_fails_in_one_line(tmp_path, capsys):
    root = tmp_path / "recs"
    rec = write_recording(root / "a", Scene())
    capture = (rec / "adc_data.bin").read_bytes()
    with initialize_config_dir(config_dir=str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("ingest", overrides=[f"root={root}", f"out={rec / 'adc_data.bin'}"])
    with pytest.raises(SystemExit) as info:
        ingest_main(cfg)  # the entry point with its config composed as on the command line
    assert info.value.code == 1
    assert capsys.readouterr().err.splitlines() == [
        f"error: {rec}/adc_data.bin: is an input file (under {root}); write the dataset outside the recordings "
        f"folder {root} (nothing written to {rec}/adc_data.bin)"]
    assert (rec / "adc_data.bin").read_bytes() == capture


def test_output_ending_in_a_slash_names_a_folder_and_is_refused(tmp_path, short_chain):
    root = tmp_path / "recs"
    write_recording(root / "a", Scene())
    with pytest.raises(FormatError, match=f"^{tmp_path}/dir/: names a folder .it ends in '/'.; give the dataset's "
                                          f"file name, such as {tmp_path}/dir/dataset.h5$"):
        ingest(root, f"{tmp_path}/dir/", short_chain, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recs"]  # no file named dir, no folder either


# ---- symbolic links ----------------------------------------------------------------------------
def test_symlinked_recordings_are_followed_and_each_folder_searched_once(tmp_path, short_chain):
    root = tmp_path / "recs"
    write_recording(root / "a", Scene())
    write_recording(tmp_path / "elsewhere" / "b", Scene(gesture="circle"))
    write_recording(tmp_path / "elsewhere" / "half", Scene()).joinpath("meta.json").unlink()
    (root / "linked").symlink_to(tmp_path / "elsewhere")  # two recordings and a meta-less folder behind a link
    (root / "again").symlink_to(root / "a")  # the same recording reached twice
    (root / "a" / "loop").symlink_to(root)  # a loop: must end
    (root / "dangling").symlink_to(tmp_path / "gone")  # a link to nothing: ignored

    found = scan(root)
    assert found.recordings == [root / "a", root / "linked" / "b"]
    assert found.meta_less == [root / "linked" / "half"] == find_meta_less_folders(root)
    assert found.repeats == [(root / "again", root / "a", 1)] and found.unreadable == []
    assert find_recordings(root) == found.recordings

    summary = ingest(root, tmp_path / "d.h5", short_chain, progress=False)
    assert (summary.found, summary.written) == (4, 2)
    reasons = dict(summary.skipped)
    assert reasons["again"] == (f"{root}/again: the same folder as a, reached again through a symbolic link; "
                                "its 1 recording(s) are ingested once, as a")
    assert reasons["linked/half"].startswith(f"{root}/linked/half/meta.json: no such file")
    assert list(read_meta_group(tmp_path / "d.h5")["recording"]) == ["a", "linked/b"]


def test_a_root_that_is_a_file_says_so(tmp_path, short_chain):
    f = write_recording(tmp_path / "a", Scene()) / "meta.json"
    for call in (lambda: find_recordings(f), lambda: ingest(f, tmp_path / "d.h5", short_chain, progress=False)):
        with pytest.raises(FormatError, match=f"^{f}: is a file, not a directory; give the folder that holds the "
                                              "recording folders$"):
            call()
    with pytest.raises(FormatError, match=f"^{tmp_path / 'nope'}: no such directory$"):
        find_recordings(tmp_path / "nope")
    with pytest.raises(FormatError, match=f"^{f}: is a file, not a folder .data.root: the folder that holds"):
        RecordingsFolder(f, short_chain, tmp_path / "cache").path()  # data=recordings data.root=FILE


# ---- unreadable folders and files --------------------------------------------------------------
def test_cli_unreadable_folder_and_capture_skip_only_their_recordings(tmp_path):
    """Run unprivileged (tests/unprivileged.py): root reads through any mode bits."""
    root = tmp_path / "recs"
    write_recording(root / "good", Scene())
    locked = write_recording(root / "locked" / "r", Scene(gesture="circle")).parent
    noread = write_recording(root / "noread", Scene(gesture="slide"))
    (noread / "adc_data.bin").chmod(0)
    locked.chmod(0)
    try:
        proc = run_cli(f"root={root}", f"out={tmp_path / 'd.h5'}", cwd=tmp_path, unprivileged=True)
    finally:
        locked.chmod(0o755)
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stdout.splitlines() if not line.startswith("[")]  # not the log lines
    assert lines[0] == "ingested 1 of 3 recordings; skipped 2"
    assert f"  skipped locked: {locked}: cannot read the folder (Permission denied); the recordings in it, if any, " \
           "are skipped" in lines
    assert f"  skipped noread: {noread}/adc_data.bin: cannot read: Permission denied" in lines
    assert list(read_meta_group(tmp_path / "d.h5")["recording"]) == ["good"]


def test_strict_stops_at_an_unreadable_folder(tmp_path, short_chain, monkeypatch):
    root = tmp_path / "recs"
    write_recording(root / "good", Scene())
    real_scandir = os.scandir

    def scandir(path):  # the folder the OS refuses to list, without needing an unprivileged user
        if Path(path).name == "locked":
            raise PermissionError(13, "Permission denied", str(path))
        return real_scandir(path)

    (root / "locked").mkdir()
    monkeypatch.setattr(os, "scandir", scandir)
    with pytest.raises(FormatError, match=f"^{root}/locked: cannot read the folder .Permission denied."):
        ingest(root, tmp_path / "d.h5", short_chain, strict=True, progress=False)
    assert not (tmp_path / "d.h5").exists()
    with pytest.raises(FormatError, match=f"^{root}: cannot read the folder: Permission denied$"):
        monkeypatch.setattr(os, "scandir", lambda path: scandir(Path(path) / "locked"))
        find_recordings(root)


# ---- names that are not UTF-8 ------------------------------------------------------------------
def test_a_folder_name_that_is_not_utf8_keeps_every_recording(tmp_path, short_chain, caplog):
    root = tmp_path / "recs"
    write_recording(root / "good", Scene())
    bad = Path(os.fsdecode(os.fsencode(root) + b"/caf\xe9"))  # Latin-1, not UTF-8
    write_recording(bad, Scene(gesture="circle"))
    summary = ingest(root, tmp_path / "d.h5", short_chain, progress=False)
    assert summary.written == 2 and validate(tmp_path / "d.h5") == 2
    assert list(read_meta_group(tmp_path / "d.h5")["recording"]) == ["caf\\xe9", "good"]
    assert summary.report().encode("utf-8")  # printable on a UTF-8 console
    assert f"{root}/caf\\xe9: the name is not valid UTF-8; its recording is stored as caf\\xe9" in caplog.text


def test_printable_escapes_only_what_utf8_cannot_hold():
    assert printable("café/ok") == "café/ok"
    assert printable(os.fsdecode(b"caf\xe9")) == "caf\\xe9"
    assert printable("lone \ud800") == "lone \\ud800"  # a surrogate from JSON, no escaped byte


def test_the_writer_stores_a_text_that_is_not_utf8(tmp_path, radar, chain):
    with open_writer(tmp_path / "d.h5", classes=GESTURES, radar=radar, chain=chain, skeleton_rate_hz=10.0,
                     n_steps=2, config_hash="h") as w:
        w.append(np.zeros((64, 32), np.float32), 0, np.zeros((2, 2, 21, 3), np.float32), np.ones((2, 2), bool),
                 0.0, {"subject": "s\udce9"})
    with h5py.File(tmp_path / "d.h5") as h5:
        assert h5["meta/subject"][0].decode() == "s\\xe9"


# ---- permissions of the outputs ----------------------------------------------------------------
@pytest.mark.parametrize("umask", [0o022, 0o027, 0o002])
def test_outputs_honour_the_umask(tmp_path, short_chain, umask):
    write_recording(tmp_path / "recs" / "a", Scene())
    old = os.umask(umask)
    try:
        ingest(tmp_path / "recs", tmp_path / "out" / "d.h5", short_chain, progress=False)
    finally:
        os.umask(old)
    for name in ("d.h5", "d.checks.json"):
        assert stat.S_IMODE((tmp_path / "out" / name).stat().st_mode) == 0o666 & ~umask, name
