"""What the repository publishes names no path of one machine, and the README stays short.

Published records name their data by how to make them (handradar.runs.tables.published: a world and its
command, or a manifest's), never by where they lay on the machine that ran them.
"""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# a home, work or temporary folder of one machine; /path/to/... and DIR are how the docs write a path of yours
MACHINE_PATH = re.compile(r"(?<![\w.~/-])/(?:work|home|root|tmp|Users)/[^\s`'\")\]|,]*")
README_MAX_LINES = 250  # what the tool is, install, first command and own data first; the rest in docs/


def published_files() -> list[Path]:
    """The README and the other top-level markdown, docs/, experiments/*.md and results/: every text file."""
    found = [*REPO.glob("*.md"), *REPO.glob("experiments/*.md"), *REPO.glob("docs/**/*"), *REPO.glob("results/**/*")]
    return sorted(p for p in found if p.is_file() and p.suffix in (".md", ".json", ".csv", ".yaml", ".txt"))


def machine_paths(text: str) -> list[str]:
    return MACHINE_PATH.findall(text)


def test_no_published_file_names_a_path_of_one_machine():
    files = published_files()
    assert REPO / "docs" / "results.md" in files and REPO / "results" / "gap_benchmark" / "default_240.json" in files
    found = {p.relative_to(REPO).as_posix(): hits for p in files if (hits := machine_paths(p.read_text(encoding="utf-8")))}
    assert not found, f"paths of one machine in published files (name the data by how to make them): {found}"


def test_the_check_sees_a_machine_path():
    """Not vacuous: the paths the published records used to carry are found; a placeholder and a URL are not."""
    assert machine_paths("data.root=/work/recs/heldout paths.log_dir=/home/me/logs") == ["/work/recs/heldout",
                                                                                          "/home/me/logs"]
    assert machine_paths("`benchmark.folders=/tmp/x/folders.yaml`") == ["/tmp/x/folders.yaml"]
    assert not machine_paths("data.root=DIR /path/to/handradar/data https://example.org/home/x ~/work/y")


def test_the_readme_stays_short():
    assert len((REPO / "README.md").read_text(encoding="utf-8").splitlines()) <= README_MAX_LINES
