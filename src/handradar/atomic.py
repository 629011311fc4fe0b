"""Atomic file output: write to a temporary file beside the target, then os.replace.

An interrupted run (exception, Ctrl-C, SIGTERM through :mod:`handradar.runs.cli`) never leaves a
partial file at the target path. A killed run (SIGKILL, power loss) leaves its temporary file
``.{name}.{pid}@{host}.{random}.part``; the next write of the same target removes it once its
process is gone (see :func:`remove_stale_parts`). :func:`file_lock` serialises processes that
build the same file. Outputs get the permissions a plain ``open(path, "w")`` would give: 0666
less the umask.
"""

from __future__ import annotations

import contextlib
import errno
import glob
import os
import re
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path


def _host() -> str:
    """This machine's name, reduced to characters that are safe in a file name and free of dots."""
    return re.sub(r"[^A-Za-z0-9_-]", "_", socket.gethostname()) or "localhost"


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    except OverflowError:  # not a pid at all
        return False
    return True


def remove_stale_parts(path: str | Path) -> list[Path]:
    """Remove the temporary files of ``path`` left by killed runs; return them.

    A temporary file is stale when it was made on this host by a process that no longer exists.
    Files of live processes (a concurrent run writing the same target, e.g. two jobs of a sweep
    building one cache) and files from other hosts on a shared disk are left alone.
    """
    path = Path(path)
    pattern = re.compile(re.escape(f".{path.name}.") + r"(\d+)@([A-Za-z0-9_-]+)\.[^.]+\.part")
    removed = []
    for name in glob.glob(glob.escape(str(path.parent / f".{path.name}.")) + "*.part"):
        m = pattern.fullmatch(Path(name).name)
        if m is None or m.group(2) != _host() or _alive(int(m.group(1))):
            continue
        with contextlib.suppress(FileNotFoundError):  # another run removed it first
            Path(name).unlink()
            removed.append(Path(name))
    return removed


def current_umask() -> int:
    """The process's umask, read from /proc (Linux) without changing it; elsewhere set and restored."""
    with contextlib.suppress(OSError, ValueError, StopIteration):
        with open("/proc/self/status") as fh:
            return int(next(line for line in fh if line.startswith("Umask:")).split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def output_mode() -> int:
    """Permission bits of every output: what ``open(path, "w")`` gives a new file, 0666 less the umask
    (mkstemp's 0600 would hide datasets and reports from a group that shares them)."""
    return 0o666 & ~current_umask()


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; move it onto ``path`` on success only.

    OSError names the folder when the folder cannot be made or written (not the temporary file).
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):  # the folder, or one above it, is a file: name that file
        blocker = next((p for p in (path.parent, *path.parent.parents) if p.exists() and not p.is_dir()), path.parent)
        raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(blocker)) from None
    remove_stale_parts(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}@{_host()}.", suffix=".part", dir=path.parent)
    except OSError as exc:  # e.g. a read-only folder
        raise OSError(exc.errno, exc.strerror, str(path.parent)) from None
    with contextlib.suppress(OSError):  # mkstemp makes 0600; writers open the temporary file in place
        os.fchmod(fd, output_mode())  # (a file system without modes keeps its own)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        tmp_path.unlink(missing_ok=True)


@contextlib.contextmanager
def file_lock(path: str | Path | None, *, busy_error: str | None = None) -> Iterator[None]:
    """Hold an exclusive ``fcntl.flock`` on ``path`` (created if missing) for the block; None: no lock.

    Serialises processes that build the same file (two jobs of a sweep filling one cache, writers
    of one SQLite database). ``busy_error``: do not wait; raise ``RuntimeError(busy_error)`` if
    another process holds the lock (one live job per state folder). POSIX only, like the shared
    file systems it is meant for.
    """
    if path is None:
        yield
        return
    import fcntl

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX if busy_error is None else fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RuntimeError(busy_error) from None
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))
