"""handradar-fetch: SFINGE3D and Xia et al.'s DTI images from local git mirrors, DHG from a local zip
(file:// URLs), the broken cases (unreachable, wrong layout, target in the way) with one-line errors
and no leftover folders, and the sfinge3d root rule of conf/source/sfinge3d.yaml."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from handradar.config import config_dir, read_yaml
from handradar.data.fetch import (
    XIA2021_PER_CLASS,
    FetchError,
    check_sfinge3d,
    check_xia2021,
    fetch,
    fetch_xia2021,
    sfinge3d_expected,
)
from handradar.data.measured import list_rows, read_manifest
from handradar.data.skeletons import iter_source
from handradar.errors import FormatError
from handradar.hand.importers.sfinge3d import sfinge3d_files
from tests.conftest import SHARED
from tests.hand.template import moving_hand
from tests.hand.test_dhg import write_sequence

REAL = ("Dictionary/6/1.txt", "Dictionary/10/2.txt")  # real instances among the tiny ones


def tiny_instance(k: int) -> str:
    """Two frames of 20 joints x (position, unit quaternion): a file the layout check accepts."""
    row = ";".join(f"{0.01 * k:.2f};0;0;0;0;0;1" for _ in range(20)) + ";\n"
    return row * 2


def git(*args: str, cwd: Path) -> None:
    subprocess.run(["git", "-c", "user.name=test", "-c", "user.email=test@example.org", *args], cwd=cwd,
                   check=True, capture_output=True)


def make_mirror(folder: Path, sfinge3d_dir: Path, *, drop: tuple[str, ...] = ()) -> str:
    """A git repository with the SFINGE3D layout (README + 13 x 36 Dictionary files); its file:// URL."""
    folder.mkdir(parents=True)
    (folder / "README.md").write_text("# Dataset V1 (test mirror)\n")
    for k, rel in enumerate(sfinge3d_expected()):
        if rel in drop:
            continue
        path = folder / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        src = sfinge3d_dir / rel
        path.write_text(src.read_text() if rel in REAL else tiny_instance(k))
    return commit_all(folder)


def commit_all(folder: Path) -> str:
    """``folder`` made a git repository with everything in it committed; its file:// URL."""
    git("init", "-q", cwd=folder)
    git("add", "-A", cwd=folder)
    git("commit", "-q", "-m", "mirror", cwd=folder)
    return folder.as_uri()


def leftovers(parent: Path) -> list[str]:
    """Hidden entries (temporary .<name>.*.part folders) in ``parent``, if it exists."""
    return sorted(p.name for p in parent.iterdir() if p.name.startswith(".")) if parent.exists() else []


@pytest.fixture(scope="module")
def mirror(tmp_path_factory, sfinge3d_dir) -> tuple[Path, str]:
    folder = tmp_path_factory.mktemp("mirror") / "DatasetV1"
    return folder, make_mirror(folder, sfinge3d_dir)


def test_sfinge3d_from_a_git_mirror(mirror, tmp_path):
    folder, url = mirror
    out = tmp_path / "data" / "sfinge3d"
    result = fetch("sfinge3d", out, url)
    assert result.status == "fetched" and result.path == out
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=folder, check=True, capture_output=True, text=True).stdout
    assert result.detail.startswith(f"commit {head[:12]}")
    assert check_sfinge3d(out) == 468 == len(sfinge3d_files(out))
    for rel in sfinge3d_expected():
        assert (out / rel).read_bytes() == (folder / rel).read_bytes()
    items = list(iter_source("sfinge3d", out, errors=[]))  # the real instances import through the source
    assert {it.name for it in items} >= {"6/1", "10/2"}
    assert leftovers(out.parent) == []

    inode = out.stat().st_ino
    again = fetch("sfinge3d", out, "file:///nowhere/at/all")  # complete: the URL is not even tried
    assert again.status == "present" and "already there" in again.report()
    assert out.stat().st_ino == inode and leftovers(out.parent) == []


def test_sfinge3d_into_an_empty_folder(mirror, tmp_path):
    out = tmp_path / "sfinge3d"
    out.mkdir()
    assert fetch("sfinge3d", out, mirror[1]).status == "fetched"
    assert check_sfinge3d(out) == 468


@pytest.mark.parametrize(("dataset", "hint"), [
    ("sfinge3d", "fetch.url=file:///PATH/DatasetV1, or read one in place with source.root=DIR (docs/datasets.md)"),
    ("xia2021", "fetch.url=file:///PATH/mm-wave-gesture-dataset, or read one in place with data=measured "
                "data.root=DIR (docs/datasets.md)")])
def test_git_unreachable(tmp_path, dataset, hint):
    """Offline (git fails): one line naming the URL and git's reason, and how to use a local copy."""
    out = tmp_path / "data" / dataset
    url = (tmp_path / "no-such-repo").as_uri()
    with pytest.raises(FetchError) as info:
        fetch(dataset, out, url)
    msg = str(info.value)
    assert msg.startswith(f"{url}: git clone failed: fatal:") and "\n" not in msg
    assert msg.endswith(f"; offline? clone from a copy with {hint}")
    assert not out.exists() and leftovers(out.parent) == []
    with pytest.raises(FetchError, match=rf"^{dataset} needs fetch.url=URL \(a git repository holding "):
        fetch(dataset, out, None)


def test_sfinge3d_wrong_layout(tmp_path, sfinge3d_dir):
    url = make_mirror(tmp_path / "broken", sfinge3d_dir, drop=("Dictionary/13/36.txt", "Dictionary/2/5.txt"))
    out = tmp_path / "data" / "sfinge3d"
    with pytest.raises(FormatError) as info:
        fetch("sfinge3d", out, url)
    msg = str(info.value)
    assert msg == (f"{url}: not a complete SFINGE3D copy: missing 2 of 468 files (Dictionary/2/5.txt, "
                   "Dictionary/13/36.txt); expected Dictionary/<1..13>/<1..36>.txt")
    assert not out.exists() and leftovers(out.parent) == []


def test_sfinge3d_target_in_the_way(mirror, tmp_path):
    out = tmp_path / "sfinge3d"
    (out / "Dictionary" / "1").mkdir(parents=True)
    (out / "Dictionary" / "1" / "1.txt").write_text(tiny_instance(0))
    with pytest.raises(FormatError) as info:
        fetch("sfinge3d", out, mirror[1])
    msg = str(info.value)
    assert msg.startswith(f"{out}: exists but not a complete SFINGE3D copy: missing 467 of 468 files "
                          "(Dictionary/1/2.txt, ") and "left untouched" in msg and "\n" not in msg
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [
        "Dictionary", "Dictionary/1", "Dictionary/1/1.txt"]
    assert leftovers(tmp_path) == []


def run_cli(*overrides: str, tmp_path: Path) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "handradar.cli.fetch", f"paths.log_dir={tmp_path}/logs", *overrides]
    return subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=300, env={**os.environ})


def cli_fetches(dataset: str, url: str, out: Path, tmp_path: Path) -> str:
    """``handradar-fetch dataset=... fetch.url=url out=out`` succeeds, printing its report then ``out``; the report."""
    done = run_cli(f"dataset={dataset}", f"fetch.url={url}", f"out={out}", tmp_path=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.strip().splitlines()
    assert lines[-1] == str(out) and lines[-2].startswith(f"{dataset}: fetched in {out} (commit ")
    return lines[-2]


def test_cli(mirror, tmp_path):
    out = tmp_path / "data" / "sf"
    cli_fetches("sfinge3d", mirror[1], out, tmp_path)
    again = run_cli(f"fetch.url={mirror[1]}", f"out={out}", tmp_path=tmp_path)
    assert again.returncode == 0 and f"sfinge3d: already there in {out}" in again.stdout

    bad = tmp_path / "nothing"
    for args, fragment in ((("dataset=sfinge3d", f"fetch.url={bad.as_uri()}", f"out={bad}"), "git clone failed"),
                           (("dataset=xia2021", f"fetch.url={bad.as_uri()}", f"out={bad}"), "data.root=DIR"),
                           (("dataset=dhg", f"out={bad}"), "dhg needs fetch.url=URL"),
                           (("dataset=kinect",), "unknown dataset 'kinect'")):
        done = run_cli(*args, tmp_path=tmp_path)
        assert done.returncode == 1, done.stderr
        assert done.stderr.count("\n") == 1 and done.stderr.startswith("error: ") and fragment in done.stderr
    assert not bad.exists() and leftovers(tmp_path) == []


# ---- Xia et al. (TGRS 2021) -----------------------------------------------------------------

XIA_SPLITS = {"train": "trainset", "A": "Atestset", "B": "Btestset"}
XIA_CLASSES = ("non-gesture", "palm up", "palm down", "palm left", "palm right", "finger double-click",
               "finger circle", "forefinger-thumb open-close")
XIA_SHARED = SHARED / "data" / "xia2021"
XIA_MANIFEST = Path(config_dir()) / "manifests" / "xia2021.yaml"
TINY = {"train": 2, "A": 1, "B": 1}  # PNGs per class of the tiny stand-in


def xia_folder(split: str, cls: str) -> str:
    return f"OpenSource/dataset/{XIA_SPLITS[split]}/DTI/{cls}"


def make_xia_mirror(folder: Path, *, drop: tuple[str, ...] = (), short: tuple[str, ...] = ()) -> str:
    """A git repository with the dataset's layout and TINY 4 x 4 PNGs per class folder, less the folders
    in ``drop`` and one PNG less in those in ``short``; its file:// URL."""
    from PIL import Image

    folder.mkdir(parents=True)
    (folder / "README.md").write_text("# mm-wave gesture dataset (test mirror)\n")
    for split, n in TINY.items():
        for c, cls in enumerate(XIA_CLASSES):
            rel = xia_folder(split, cls)
            if rel in drop:
                continue
            (folder / rel).mkdir(parents=True)
            for i in range(n - (rel in short)):
                pixels = np.full((4, 4), 10 * c + i, dtype=np.uint8)
                Image.fromarray(pixels).save(folder / rel / f"{cls}{i + 1}.png")
    return commit_all(folder)


@pytest.fixture(scope="module")
def xia_mirror(tmp_path_factory) -> tuple[Path, str]:
    folder = tmp_path_factory.mktemp("xia") / "mm-wave-gesture-dataset"
    return folder, make_xia_mirror(folder)


def test_xia2021_from_a_git_mirror(xia_mirror, tmp_path):
    folder, url = xia_mirror
    out = tmp_path / "data" / "xia2021"
    result = fetch_xia2021(out, url, per_class=TINY)
    assert result.status == "fetched" and result.path == out
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=folder, check=True, capture_output=True, text=True).stdout
    assert result.detail == f"commit {head[:12]}, 32 files checked"
    pngs = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*.png"))
    assert len(pngs) == 32 and sorted(p.relative_to(out).as_posix() for p in out.rglob("*.png")) == pngs
    assert all((out / rel).read_bytes() == (folder / rel).read_bytes() for rel in pngs)
    rows = list_rows(read_manifest(XIA_MANIFEST, root=out))  # the measured preset reads the fetched copy
    assert [(s, y) for s, y, _ in rows] == [(s, y) for s in TINY for y in range(8) for _ in range(TINY[s])]
    assert leftovers(out.parent) == []

    inode = out.stat().st_ino
    again = fetch_xia2021(out, "file:///nowhere/at/all", per_class=TINY)  # complete: the URL is not tried
    assert again.status == "present" and again.report() == f"xia2021: already there in {out} (32 files checked)"
    assert out.stat().st_ino == inode and leftovers(out.parent) == []


def test_xia2021_counts_are_the_published_ones(xia_mirror):
    """The default check wants 400 PNGs per class in trainset and 50 in Atestset and Btestset."""
    assert XIA2021_PER_CLASS == {"train": 400, "A": 50, "B": 50}
    with pytest.raises(FormatError) as info:
        check_xia2021(xia_mirror[0])
    assert str(info.value) == (
        f"{xia_mirror[0]}: not a complete xia2021 copy: 24 of 24 class folders missing or incomplete "
        "(OpenSource/dataset/trainset/DTI/non-gesture/: 2 *.png files, expected 400, "
        "OpenSource/dataset/trainset/DTI/palm up/: 2 *.png files, expected 400, "
        "OpenSource/dataset/trainset/DTI/palm down/: 2 *.png files, expected 400 and 21 more); "
        "expected OpenSource/dataset/{trainset,Atestset,Btestset}/DTI/<class>/*.png for the 8 classes of "
        "conf/manifests/xia2021.yaml, per class 400 in trainset, 50 in Atestset, 50 in Btestset")


@pytest.mark.skipif(not (XIA_SHARED / "OpenSource").is_dir(), reason="Xia et al.'s DTI images are in ../shared only")
def test_xia2021_check_passes_the_real_copy():
    assert check_xia2021(XIA_SHARED) == 4000 == 8 * (400 + 50 + 50)


def test_xia2021_incomplete(tmp_path):
    url = make_xia_mirror(tmp_path / "broken", drop=(xia_folder("B", "finger circle"),),
                          short=(xia_folder("train", "palm left"),))
    out = tmp_path / "data" / "xia2021"
    with pytest.raises(FormatError) as info:
        fetch_xia2021(out, url, per_class=TINY)
    assert str(info.value) == (
        f"{url}: not a complete xia2021 copy: 2 of 24 class folders missing or incomplete "
        "(OpenSource/dataset/trainset/DTI/palm left/: 1 *.png files, expected 2, "
        "OpenSource/dataset/Btestset/DTI/finger circle/: no such folder); "
        "expected OpenSource/dataset/{trainset,Atestset,Btestset}/DTI/<class>/*.png for the 8 classes of "
        "conf/manifests/xia2021.yaml, per class 2 in trainset, 1 in Atestset, 1 in Btestset")
    assert not out.exists() and leftovers(out.parent) == []


def test_xia2021_target_in_the_way(xia_mirror, tmp_path):
    out = tmp_path / "xia2021"
    (out / xia_folder("train", "palm up")).mkdir(parents=True)
    before = sorted(p.relative_to(out).as_posix() for p in out.rglob("*"))
    with pytest.raises(FormatError) as info:
        fetch_xia2021(out, xia_mirror[1], per_class=TINY)
    msg = str(info.value)
    assert msg.startswith(f"{out}: exists but not a complete xia2021 copy: 24 of 24 class folders missing or "
                          "incomplete (OpenSource/dataset/trainset/DTI/non-gesture/: no such folder, "
                          "OpenSource/dataset/trainset/DTI/palm up/: 0 *.png files, expected 2, ")
    assert "left untouched" in msg and "out=DIR to fetch xia2021 elsewhere" in msg and "\n" not in msg
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == before and leftovers(tmp_path) == []


def test_xia2021_defaults_meet_the_manifest(tmp_path):
    """handradar-fetch dataset=xia2021 clones the public mirror into the folder the manifest reads first."""
    repo = tmp_path / "checkout"
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("fetch", overrides=["dataset=xia2021", f"paths.root_dir={repo}"])
    assert cfg.fetch.url == "https://github.com/dmahurin/mm-wave-gesture-dataset.git"
    first_root = read_yaml(XIA_MANIFEST)["root"][0]
    assert Path(cfg.out) == repo / "data" / "xia2021" and (XIA_MANIFEST.parent / first_root).resolve() == (
        Path(config_dir()).parent / "data" / "xia2021").resolve()


@pytest.fixture(scope="module")
def xia_real_mirror(tmp_path_factory) -> str:
    """A git repository holding a copy of ../shared/data/xia2021 (the published layout, 4000 PNGs)."""
    if not (XIA_SHARED / "OpenSource").is_dir():  # CI has ../shared; a user's clone does not
        message = f"Xia et al.'s DTI images not found in {XIA_SHARED}"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    folder = tmp_path_factory.mktemp("xia_real") / "mm-wave-gesture-dataset"
    shutil.copytree(XIA_SHARED, folder)
    return commit_all(folder)


def test_xia2021_cli(xia_real_mirror, tmp_path):
    """The real layout through the command, checked with the published counts (400/50/50 a class)."""
    out = tmp_path / "data" / "xia2021"
    assert cli_fetches("xia2021", xia_real_mirror, out, tmp_path).endswith(", 4000 files checked)")
    assert len(list_rows(read_manifest(XIA_MANIFEST, root=out))) == 4000 and leftovers(out.parent) == []


# ---- DHG ------------------------------------------------------------------------------------

INFO = "1 1 1 1 5 30\n3 2 2 4 1 40\n"


def make_dhg_zip(tmp_path: Path, *, drop_second: bool = False, prefix: str = "DHG2016/") -> Path:
    """A zip of two DHG sequences (+ a depth image and the start/end table) under ``prefix``."""
    src = tmp_path / "src"
    write_sequence(src, 1, 1, 1, 1, moving_hand(40, 1 / 30))
    if not drop_second:
        write_sequence(src, 3, 2, 2, 4, moving_hand(40, 1 / 30))
    (src / "gesture_1/finger_1/subject_1/essai_1/depth_1.png").write_bytes(b"\x89PNG not really")
    (src / "informations_troncage_sequences.txt").write_text(INFO)
    archive = tmp_path / "DHG2016.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for p in sorted(src.rglob("*")):
            if p.is_file():
                zf.write(p, prefix + p.relative_to(src).as_posix())
    return archive


def test_dhg_from_a_zip(tmp_path):
    archive = make_dhg_zip(tmp_path)
    out = tmp_path / "data" / "dhg"
    result = fetch("dhg", out, archive.as_uri())
    assert result.status == "fetched" and result.detail == "2 sequences checked"
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*.*")) == [
        "gesture_1/finger_1/subject_1/essai_1/skeleton_world.txt",
        "gesture_3/finger_2/subject_2/essai_4/skeleton_world.txt",
        "informations_troncage_sequences.txt"]  # the DHG2016/ wrapper is gone, no depth image
    items = list(iter_source("dhg", out, n_classes=28))
    assert [(it.name, it.label, it.sequence.n_steps) for it in items] == [
        ("gesture_1/finger_1/subject_1/essai_1", 0, 26), ("gesture_3/finger_2/subject_2/essai_4", 5, 40)]
    assert leftovers(out.parent) == []
    assert fetch("dhg", out, None).status == "present"  # complete: no URL needed

    full = tmp_path / "with_depth"
    fetch("dhg", full, make_dhg_zip(tmp_path / "again", prefix="").as_uri(), txt_only=False)
    assert (full / "gesture_1/finger_1/subject_1/essai_1/depth_1.png").is_file()


@pytest.mark.parametrize("case", ["missing_sequence", "not_a_zip", "unreachable", "no_url", "outside"])
def test_dhg_broken(tmp_path, case):
    out = tmp_path / "data" / "dhg"
    if case == "missing_sequence":
        url = make_dhg_zip(tmp_path, drop_second=True).as_uri()
        expected = (FormatError, (f"{url}: not a complete DHG-14/28 copy: missing 1 of 2 files "
                                  "(gesture_3/finger_2/subject_2/essai_4/skeleton_world.txt); expected a skeleton "
                                  "file for every sequence informations_troncage_sequences.txt lists "
                                  "(in the archive under DHG2016/)"))
    elif case == "not_a_zip":
        (tmp_path / "page.html").write_text("<html>please register</html>")
        url = (tmp_path / "page.html").as_uri()
        expected = (FormatError, f"{url}: not a readable zip archive (File is not a zip file)")
    elif case == "unreachable":
        url = (tmp_path / "gone.zip").as_uri()
        expected = (FetchError, f"{url}: download failed: No such file or directory")
    elif case == "no_url":
        url = None
        expected = (FetchError, "dhg needs fetch.url=URL")
    else:
        archive = tmp_path / "evil.zip"
        with zipfile.ZipFile(archive, "w") as zf:
            zf.writestr("../escaped.txt", "1 1 1 1 1 2\n")
        url = archive.as_uri()
        expected = (FormatError, f"{url}: archive member '../escaped.txt' would unpack outside the target folder")
    with pytest.raises(expected[0]) as info:
        fetch("dhg", out, url)
    assert str(info.value).startswith(expected[1]) and "\n" not in str(info.value)
    assert not out.exists() and leftovers(out.parent) == [] and not (tmp_path / "data" / "escaped.txt").exists()


# ---- where the sources read ----------------------------------------------------------------

def sfinge3d_root(repo: Path) -> str:
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("synth", overrides=[f"paths.root_dir={repo}"])
    return cfg.source.root


def test_sfinge3d_root_rule(tmp_path):
    repo = tmp_path / "checkout"
    fetched, shared = repo / "data" / "sfinge3d", tmp_path / "shared" / "data" / "sfinge3d"
    repo.mkdir()
    assert Path(sfinge3d_root(repo)) == fetched  # neither: where make fetch-data puts it
    shared.mkdir(parents=True)
    assert Path(sfinge3d_root(repo)).resolve() == shared  # the CI's copy
    fetched.mkdir(parents=True)
    assert Path(sfinge3d_root(repo)) == fetched  # a fetched copy wins


def test_synth_names_the_missing_dhg_folder(tmp_path):
    """handradar-synth source=dhg on a checkout without data/dhg: one line naming it and the fetch."""
    repo = tmp_path / "checkout"
    repo.mkdir()
    cmd = [sys.executable, "-m", "handradar.cli.synth", "source=dhg", f"paths.root_dir={repo}", f"out={tmp_path}/d.h5"]
    done = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=300)
    assert done.returncode == 1, done.stderr[-2000:]
    assert done.stderr.startswith(f"error: {repo}/data/dhg: no such folder: the dhg skeletons are read from here")
    assert done.stderr.count("\n") == 1 and "handradar-fetch dataset=dhg fetch.url=URL" in done.stderr
    assert not (tmp_path / "d.h5").exists()
