"""Config comments stay short: at most two lines each, the reasoning in docs (docs/configuration.md)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from handradar.config import config_dir, experiments_dir

FILES = sorted(Path(config_dir()).rglob("*.yaml")) + sorted((experiments_dir() / "experiment").glob("*.yaml"))
MAX_LINES = 2


def comments(text: str) -> list[tuple[int, int]]:
    """(first line, number of lines) of each comment: a line with a ``#`` comment and the comment-only
    lines that continue it; Hydra's ``# @package`` directive is no comment."""
    out: list[list[int]] = []
    current: list[int] | None = None
    for n, line in enumerate(text.splitlines(), 1):
        if line.startswith("# @package"):
            current = None
            continue
        only = re.match(r"\s*#", line) is not None
        if only and current is not None:
            current[1] += 1
        elif only or re.search(r"\s#(\s|$)", line):
            current = [n, 1]
            out.append(current)
        else:
            current = None
    return [(a, b) for a, b in out]


def test_comment_blocks_are_counted_as_written():
    text = "# @package _global_\n# one\n# two\nkey: 1   # three\n         # four\n         # five\nurl: a#b\nx: 2 # six\n"
    assert comments(text) == [(2, 2), (4, 3), (8, 1)]


@pytest.mark.parametrize("path", FILES, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_config_comments_are_at_most_two_lines(path: Path):
    long = [f"line {n}: {k} lines" for n, k in comments(path.read_text()) if k > MAX_LINES]
    assert not long, f"{path}: comments longer than {MAX_LINES} lines ({'; '.join(long)}); move the reasoning to docs"


def _anchors(doc: Path) -> set[str]:
    """GitHub's heading anchors of a markdown file: lower case, punctuation dropped, spaces as dashes."""
    heads = re.findall(r"^#+ (.+)$", doc.read_text(), flags=re.M)
    return {re.sub(r"[^\w\- ]", "", h).strip().lower().replace(" ", "-") for h in heads}


def test_every_doc_link_in_a_config_comment_resolves():
    repo = Path(config_dir()).parent
    links = {(p, m.group(1), m.group(2)) for p in FILES for m in re.finditer(r"(docs/[\w/.-]+\.md)#([\w-]+)", p.read_text())}
    assert links  # the comments do point into the docs
    broken = [f"{p.name}: {doc}#{anchor}" for p, doc, anchor in sorted(links)
              if not (repo / doc).is_file() or anchor not in _anchors(repo / doc)]
    assert not broken, f"links to no heading: {broken}"
