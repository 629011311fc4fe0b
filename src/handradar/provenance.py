"""Provenance: code version and config hashes that key caches and tag outputs; the command that wrote a data folder."""

from __future__ import annotations

import functools
import hashlib
import json
import re
import subprocess
from pathlib import Path

import numpy as np

from handradar import __version__
from handradar.atomic import atomic_write_text

REPO_ROOT = Path(__file__).resolve().parents[2]


@functools.cache
def code_version() -> str:
    """``<package version>+g<git sha>[.dirty]`` when run from a git checkout, else the version."""
    try:
        sha = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=REPO_ROOT, capture_output=True,
                             text=True, timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO_ROOT,
                               capture_output=True, text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return __version__
    return f"{__version__}+g{sha}{'.dirty' if dirty else ''}"


def source_digest(root: Path) -> str:
    """A digest (16 hex digits) of the Python source under ``root``: names and contents of its ``*.py`` files."""
    h = hashlib.sha256()
    for f in sorted(Path(root).rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:16]


@functools.cache
def package_digest() -> str:
    """:func:`source_digest` of the handradar package: what a resumable result keyed by the code depends on.
    Unlike the commit, it ignores commits to docs, tests and experiments, and it still tells two versions
    apart outside a git checkout."""
    return source_digest(Path(__file__).resolve().parent)


def commit_of(version: str) -> str:
    """The short (7-digit) git commit in a ``<version>+g<sha>[.dirty]`` code version (``.dirty`` kept),
    else the version itself."""
    m = re.search(r"\+g([0-9a-f]+)(\.dirty)?", version or "")
    return (m.group(1)[:7] + (m.group(2) or "")) if m else (version or "unknown")


def _canonical(obj: object) -> object:
    if hasattr(obj, "__canonical__"):  # a value that hashes as an earlier form did (earlier cache keys hold)
        return obj.__canonical__()
    if hasattr(obj, "__dataclass_fields__"):  # a field added later with metadata {"hash_if_set": True} counts when set
        return {k: _canonical(getattr(obj, k)) for k, f in obj.__dataclass_fields__.items()
                if k != "source" and not (f.metadata.get("hash_if_set") and getattr(obj, k) is None)}
    if isinstance(obj, dict):
        return {str(k): _canonical(v) for k, v in sorted(obj.items(), key=lambda kv: str(kv[0]))}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    if isinstance(obj, float):
        return float(f"{obj:.12g}")
    return obj


def config_hash(*parts: object) -> str:
    """Stable 16-hex-digit hash of dataclasses, dicts, lists and scalars."""
    text = json.dumps([_canonical(p) for p in parts], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def array_digest(*arrays: np.ndarray) -> str:
    """SHA-256 (16 hex digits) of arrays' dtypes, shapes and bytes: cache keys of array data."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


@functools.cache
def machine() -> str:
    """What ran a job, without naming the host: architecture, CPU count and GPU, e.g.
    ``x86_64, 2 CPUs, no GPU`` or ``x86_64, 16 CPUs, NVIDIA H100 80GB HBM3``."""
    import os
    import platform

    gpu = "no GPU"
    try:
        import torch

        if torch.cuda.is_available():
            gpu = torch.cuda.get_device_name(0)
    except Exception:  # a broken CUDA install must not stop a job from being recorded
        pass
    return f"{platform.machine() or 'unknown'}, {os.cpu_count() or '?'} CPUs, {gpu}"


SOURCE_FILE = "source.txt"  # in a data folder: the command that wrote it (docs/architecture.md, "Recording format")


def write_source(folder: str | Path, command: str) -> None:
    """Record in ``folder`` the command that wrote it, so that a published result names its data by how to
    make them, not by where they lie (handradar.runs.tables.published)."""
    atomic_write_text(Path(folder) / SOURCE_FILE, command.strip() + "\n")


def read_source(folder: str | Path) -> str | None:
    """The command that wrote ``folder`` (:func:`write_source`); None where it was not recorded."""
    path = Path(folder).expanduser() / SOURCE_FILE
    if not path.is_file():
        return None
    return path.read_text(encoding="utf-8").strip() or None
