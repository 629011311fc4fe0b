"""Hydra/OmegaConf glue: resolvers, the config folder, and conversion helpers."""

from __future__ import annotations

import os
from pathlib import Path

from omegaconf import OmegaConf

from handradar.errors import FormatError
from handradar.provenance import REPO_ROOT

VERSION_BASE = "1.3"


def config_dir() -> Path:
    """The ``conf/`` folder: $HANDRADAR_CONF, else the checkout this package is installed from."""
    path = Path(os.environ.get("HANDRADAR_CONF", REPO_ROOT / "conf"))
    if not (path / "train.yaml").is_file() and not (path / "ingest.yaml").is_file():
        raise FileNotFoundError(f"handradar config folder not found at {path}: install the package in "
                                "editable mode from its checkout (make install) or set HANDRADAR_CONF")
    return path


def experiments_dir() -> Path:
    return config_dir().parent / "experiments"


def first_dir(*candidates: str) -> str:
    """The first candidate that is an existing folder, else the first (so errors name where to put it)."""
    return next((c for c in candidates if Path(c).is_dir()), candidates[0])


def read_yaml(path: str | Path) -> object:
    """A YAML file's content as plain containers, interpolations resolved; a syntax error is one FormatError
    line naming the file, the line and the parser's problem."""
    try:
        return OmegaConf.to_container(OmegaConf.load(path), resolve=True)
    except Exception as exc:  # yaml's MarkedYAMLError, or omegaconf's wrappers of it
        mark = getattr(exc, "problem_mark", None)
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        raise FormatError(path, f"not readable as YAML: {problem}",
                          line=None if mark is None else mark.line + 1) from None


def register_resolvers() -> None:
    if not OmegaConf.has_resolver("hr_root"):
        OmegaConf.register_new_resolver("hr_root", lambda: str(REPO_ROOT))
    if not OmegaConf.has_resolver("hr_first_dir"):
        OmegaConf.register_new_resolver("hr_first_dir", first_dir)


register_resolvers()
