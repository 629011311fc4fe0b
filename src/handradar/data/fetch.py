"""External datasets onto this machine: ``handradar-fetch dataset=sfinge3d|dhg|xia2021``.

- ``sfinge3d``: ``git clone --depth 1`` of the dataset's public repository (SFINGE3D/DatasetV1),
  checked for the Dictionary's 13 classes x 36 instances (``Dictionary/<1..13>/<1..36>.txt``, as
  the dataset's README documents them).
- ``dhg``: the DHG-14/28 zip archive (``DHG2016.zip``) downloaded and unpacked (by default only its
  ``.txt`` files: the skeletons and the start/end table, not the depth images), checked against its
  own manifest: ``informations_troncage_sequences.txt`` lists every sequence, each of which must
  have its ``gesture_g/finger_f/subject_s/essai_e/skeleton_world.txt``.
- ``xia2021``: the measured DTI images of Xia et al. (IEEE TGRS 2021), ``git clone --depth 1`` of a
  public mirror of the authors' repository, checked against conf/manifests/xia2021.yaml: every class
  folder of every split its ``rows.layout`` names holds the published number of PNGs (400 per class
  in ``trainset``, 50 in each held-out user's ``Atestset`` and ``Btestset``).

Every fetch is atomic: it works in a temporary folder beside the target (``.<name>.*.part``),
checks it, then renames it onto the target; on any failure (or Ctrl-C) the temporary folder is
removed and the target is not created. A target that already holds a complete copy is left alone
(status "present"); one that exists but is incomplete is an error and is left untouched.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import tempfile
import urllib.error
import urllib.request
import zipfile
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from functools import partial
from pathlib import Path, PurePosixPath

from handradar.config import config_dir
from handradar.errors import FormatError, HandradarError
from handradar.hand.importers import dhg, sfinge3d

DATASETS = ("sfinge3d", "dhg", "xia2021")
SFINGE3D_INSTANCES = 36  # per class, Dictionary/<class>/<1..36>.txt (the dataset's README)
XIA2021_MANIFEST = "manifests/xia2021.yaml"  # under conf/: the layout, split folders and classes checked
XIA2021_PER_CLASS = {"train": 400, "A": 50, "B": 50}  # PNGs per class of each split (the published copy)
GIT_DATASETS = ("sfinge3d", "xia2021")  # fetched with git clone
GIT_TIMEOUT_S = 600.0
HTTP_TIMEOUT_S = 60.0


class FetchError(HandradarError):
    """A dataset could not be fetched (source unreachable, git missing, ...); the message says which."""


@dataclass(frozen=True)
class FetchResult:
    dataset: str
    path: Path
    status: str  # "fetched" or "present" (a complete copy was already there)
    detail: str = ""  # e.g. the cloned commit or the number of sequences

    def report(self) -> str:
        what = "already there" if self.status == "present" else "fetched"
        return f"{self.dataset}: {what} in {self.path}" + (f" ({self.detail})" if self.detail else "")


# ---- layout checks --------------------------------------------------------------------------

def sfinge3d_expected() -> list[str]:
    """Relative paths of the Dictionary files a complete SFINGE3D copy has (13 x 36)."""
    return [f"Dictionary/{c}/{i}.txt" for c in range(1, len(sfinge3d.CLASSES) + 1)
            for i in range(1, SFINGE3D_INSTANCES + 1)]


def _first_few(items: list[str]) -> str:
    return ", ".join(items[:3]) + (f" and {len(items) - 3} more" if len(items) > 3 else "")


def _missing_message(missing: list[str], total: int, expected: str) -> str:
    return f"missing {len(missing)} of {total} files ({_first_few(missing)}); expected {expected}"


def check_sfinge3d(root: str | Path) -> int:
    """Raise FormatError naming what is missing unless ``root`` is a complete copy; return the file count."""
    root = Path(root)
    expected = sfinge3d_expected()
    missing = [rel for rel in expected if not _nonempty_file(root / rel)]
    if missing:
        raise FormatError(root, "not a complete SFINGE3D copy: " + _missing_message(
            missing, len(expected), f"Dictionary/<1..{len(sfinge3d.CLASSES)}>/<1..{SFINGE3D_INSTANCES}>.txt"))
    return len(expected)


def check_dhg(root: str | Path) -> int:
    """Raise FormatError naming what is missing unless every sequence ``root``'s start/end table lists
    has its skeleton file; return the number of sequences."""
    root = Path(root)
    info_path = root / dhg.INFO_FILE
    if not info_path.is_file():
        raise FormatError(root, f"not a DHG-14/28 copy: missing {dhg.INFO_FILE} "
                                "(expected it beside the gesture_<g> folders)")
    listed = dhg.read_info(info_path)
    missing = [f"{key.name}/{dhg.SKELETON_FILES[0]}" for key in listed
               if not any(_nonempty_file(root / key.name / name) for name in dhg.SKELETON_FILES)]
    if missing:
        raise FormatError(root, "not a complete DHG-14/28 copy: " + _missing_message(
            missing, len(listed), f"a skeleton file for every sequence {dhg.INFO_FILE} lists"))
    return len(listed)


def check_xia2021(root: str | Path, per_class: Mapping[str, int] = XIA2021_PER_CLASS) -> int:
    """Raise FormatError naming the class folders that are missing or hold another number of PNGs than
    ``per_class`` (by split of conf/manifests/xia2021.yaml) unless ``root`` is a complete copy of the
    Xia et al. (2021) DTI images; return the number of PNGs checked."""
    from handradar.data.measured import class_files, read_manifest  # imports torch: only when checking xia2021

    root = Path(root)
    m = read_manifest(config_dir() / XIA2021_MANIFEST, root=root)
    wrong, folders, total = [], 0, 0
    for split, split_folder in m.splits.items():
        for cls in m.classes:
            folder, file_glob, files = class_files(m, split_folder, cls)
            rel = folder.relative_to(root).as_posix()
            if files is None:
                wrong.append(f"{rel}/: no such folder")
            elif len(files) != per_class[split]:
                wrong.append(f"{rel}/: {len(files)} {file_glob} files, expected {per_class[split]}")
            folders, total = folders + 1, total + per_class[split]
    if wrong:
        layout = m.layout.replace("{split}", "{" + ",".join(m.splits.values()) + "}").replace("{class}", "<class>")
        counts = ", ".join(f"{per_class[s]} in {f}" for s, f in m.splits.items())
        raise FormatError(root, f"not a complete xia2021 copy: {len(wrong)} of {folders} class folders missing or "
                                f"incomplete ({_first_few(wrong)}); expected {layout} for the {len(m.classes)} "
                                f"classes of conf/{XIA2021_MANIFEST}, per class {counts}")
    return total


def _nonempty_file(path: Path) -> bool:
    return path.is_file() and path.stat().st_size > 0


# ---- atomic placement -----------------------------------------------------------------------

@contextlib.contextmanager
def staging_dir(out: Path) -> Iterator[Path]:
    """An empty temporary folder beside ``out`` (same file system, so the final rename is atomic),
    removed on the way out whatever happens; the caller renames its result onto ``out``."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".part", dir=out.parent))
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _place(folder: Path, out: Path) -> None:
    """Rename the checked ``folder`` onto ``out`` (which must not exist)."""
    try:
        os.rename(folder, out)
    except OSError as exc:
        raise FetchError(f"{out}: cannot move the fetched copy into place: {exc.strerror}") from None


def _already_there(out: Path, check: Callable[[Path], int], dataset: str) -> FetchResult | None:
    """A FetchResult if ``out`` holds a complete copy, None if it does not exist, else FormatError."""
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        return None  # an empty folder is replaced by the rename
    if not out.is_dir():
        raise FormatError(out, f"exists and is not a folder; remove it or pass out=DIR to fetch {dataset} elsewhere")
    try:
        n = check(out)
    except FormatError as exc:
        raise FormatError(out, f"exists but {exc.problem}; move it away (it is left untouched) "
                               f"or pass out=DIR to fetch {dataset} elsewhere") from None
    return FetchResult(dataset, out, "present", f"{n} files checked")


# ---- SFINGE3D and Xia et al.: git clone -----------------------------------------------------

def _git(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "GIT_TERMINAL_PROMPT": "0"}  # an unknown https repository fails, never prompts
    try:
        return subprocess.run(["git", *args], cwd=cwd, env=env, check=False, capture_output=True, text=True,
                              timeout=GIT_TIMEOUT_S)
    except FileNotFoundError:
        raise FetchError(f"git not found on PATH: install git to fetch {' or '.join(GIT_DATASETS)}") from None
    except subprocess.TimeoutExpired:
        raise FetchError(f"git {args[0]} took longer than {GIT_TIMEOUT_S:.0f} s; nothing was kept") from None


def _git_error(stderr: str) -> str:
    """git's first ``fatal:``/``error:`` line (else its last line): the reason, on one line."""
    lines = [ln.strip() for ln in stderr.splitlines() if ln.strip()]
    for ln in lines:
        if ln.startswith(("fatal:", "error:")):
            return ln
    return lines[-1] if lines else "no message from git"


def fetch_git(dataset: str, out: str | Path, url: str, check: Callable[[Path], int], *, holds: str,
              local_copy: str) -> FetchResult:
    """``git clone --depth 1 url`` into ``out``, checked by ``check`` (which returns the file count),
    placed atomically. ``holds``: what the repository must hold, for the error without a URL;
    ``local_copy``: how to use a copy already on this machine, for the error when git fails."""
    out = Path(out).absolute()
    present = _already_there(out, check, dataset)
    if present is not None:
        return present
    if not url:
        raise FetchError(f"{dataset} needs fetch.url=URL (a git repository holding {holds})")
    with staging_dir(out) as tmp:
        clone = tmp / out.name
        done = _git("clone", "--depth", "1", "--quiet", "--", url, str(clone))
        if done.returncode != 0:
            raise FetchError(f"{url}: git clone failed: {_git_error(done.stderr)}; offline? {local_copy}")
        try:
            n = check(clone)
        except FormatError as exc:  # name the repository, not the temporary clone
            raise FormatError(url, exc.problem) from None
        head = _git("rev-parse", "HEAD", cwd=clone).stdout.strip()
        _place(clone, out)
    return FetchResult(dataset, out, "fetched", f"commit {head[:12]}, {n} files checked")


def fetch_sfinge3d(out: str | Path, url: str) -> FetchResult:
    """SFINGE3D's repository cloned into ``out``, checked (see :func:`check_sfinge3d`), placed atomically."""
    return fetch_git("sfinge3d", out, url, check_sfinge3d, holds=f"Dictionary/<1..{len(sfinge3d.CLASSES)}>/",
                     local_copy="clone from a copy with fetch.url=file:///PATH/DatasetV1, or read one in place with "
                                "source.root=DIR (docs/datasets.md)")


def fetch_xia2021(out: str | Path, url: str, *, per_class: Mapping[str, int] = XIA2021_PER_CLASS) -> FetchResult:
    """The Xia et al. (2021) repository cloned into ``out``, checked (see :func:`check_xia2021`), placed atomically."""
    return fetch_git("xia2021", out, url, partial(check_xia2021, per_class=per_class),
                     holds="OpenSource/dataset/<split>/DTI/<class>/",
                     local_copy="clone from a copy with fetch.url=file:///PATH/mm-wave-gesture-dataset, or read "
                                "one in place with data=measured data.root=DIR (docs/datasets.md)")


# ---- DHG-14/28: zip archive -----------------------------------------------------------------

def download(url: str, dest: Path, *, progress: bool = False) -> int:
    """Stream ``url`` (http(s):// or file://) into ``dest``; return the byte count. FetchError on failure."""
    from tqdm import tqdm

    try:
        with urllib.request.urlopen(url, timeout=HTTP_TIMEOUT_S) as resp, open(dest, "wb") as fh:
            total = resp.headers.get("Content-Length")
            n = 0
            with tqdm(total=int(total) if total else None, unit="B", unit_scale=True, desc="download",
                      disable=not progress) as bar:
                while chunk := resp.read(1 << 20):
                    fh.write(chunk)
                    n += len(chunk)
                    bar.update(len(chunk))
    except urllib.error.HTTPError as exc:
        raise FetchError(f"{url}: download failed: HTTP {exc.code} {exc.reason}") from None
    except urllib.error.URLError as exc:
        reason = getattr(exc.reason, "strerror", None) or exc.reason
        raise FetchError(f"{url}: download failed: {reason}") from None
    except (OSError, ValueError) as exc:  # ValueError: not a URL at all
        raise FetchError(f"{url}: download failed: {getattr(exc, 'strerror', None) or exc}") from None
    if total is not None and n != int(total):
        raise FetchError(f"{url}: download cut short: {n} of {total} bytes")
    return n


def unpack_zip(archive: Path, dest: Path, *, source: str, txt_only: bool = True) -> int:
    """Extract ``archive`` into ``dest`` (only ``.txt`` members when ``txt_only``); return the member count.

    Refuses members that would land outside ``dest`` (absolute paths, ``..``).
    """
    try:
        with zipfile.ZipFile(archive) as zf:
            members = [m for m in zf.infolist() if not m.is_dir()]
            for m in members:
                parts = PurePosixPath(m.filename.replace("\\", "/")).parts
                if m.filename.startswith(("/", "\\")) or ".." in parts or (parts and ":" in parts[0]):
                    raise FormatError(source, f"archive member {m.filename!r} would unpack outside the target folder")
            chosen = [m for m in members if not txt_only or m.filename.lower().endswith(".txt")]
            for m in chosen:
                zf.extract(m, dest)
    except zipfile.BadZipFile as exc:
        raise FormatError(source, f"not a readable zip archive ({exc})") from None
    return len(chosen)


def _dhg_root(tree: Path) -> Path:
    """``tree`` or the one folder inside it that holds the dataset (archives often wrap it in one)."""
    if (tree / dhg.INFO_FILE).exists() or any(tree.glob("gesture_*")):
        return tree
    inner = [p for p in tree.iterdir() if p.is_dir()]
    if len(inner) == 1:
        return _dhg_root(inner[0])
    return tree  # check_dhg names what is missing


def fetch_dhg(out: str | Path, url: str | None, *, txt_only: bool = True, progress: bool = False) -> FetchResult:
    """Download the DHG-14/28 zip at ``url``, unpack, check (see :func:`check_dhg`), place atomically."""
    out = Path(out).absolute()
    present = _already_there(out, check_dhg, "dhg")
    if present is not None:
        return present
    if not url:
        raise FetchError("dhg needs fetch.url=URL of the DHG-14/28 archive DHG2016.zip (the dataset's site asks "
                         "you to register first; a downloaded copy works as file:///path/DHG2016.zip); "
                         "see docs/datasets.md")
    with staging_dir(out) as tmp:
        archive = tmp / "archive.zip"
        download(url, archive, progress=progress)
        tree = tmp / "tree"
        unpack_zip(archive, tree, source=url, txt_only=txt_only)
        archive.unlink()
        root = _dhg_root(tree)
        try:
            n = check_dhg(root)
        except FormatError as exc:  # name the archive, not the temporary folder
            inside = root.relative_to(tree).as_posix()
            raise FormatError(url, f"{exc.problem} (in the archive{'' if inside == '.' else f' under {inside}/'})"
                              ) from None
        _place(root, out)
    return FetchResult("dhg", out, "fetched", f"{n} sequences checked")


def fetch(dataset: str, out: str | Path, url: str | None, *, txt_only: bool = True,
          progress: bool = False) -> FetchResult:
    """Fetch ``dataset`` (one of :data:`DATASETS`) into ``out`` from ``url``."""
    if dataset == "sfinge3d":
        return fetch_sfinge3d(out, url or "")
    if dataset == "xia2021":
        return fetch_xia2021(out, url or "")
    if dataset == "dhg":
        return fetch_dhg(out, url, txt_only=txt_only, progress=progress)
    raise FetchError(f"unknown dataset {dataset!r}; expected one of {', '.join(DATASETS)}")
