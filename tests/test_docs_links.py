"""Every relative link in the README and the docs resolves: the file exists and, for `file.md#anchor`,
the anchor is one of that file's headings (GitHub's slugs). Links inside code blocks are not links."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^\s*(```|~~~)")


def documents() -> list[Path]:
    """The project's hand-written and generated markdown: top-level files, docs/, experiments/."""
    found = [*REPO.glob("*.md"), *REPO.glob("docs/**/*.md"), *REPO.glob("experiments/**/*.md")]
    return sorted(p for p in found if p.is_file())


def prose(text: str) -> str:
    """``text`` without fenced code blocks and inline code spans (neither holds links)."""
    out, fenced = [], False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            out.append(re.sub(r"`[^`]*`", "", line))
    return "\n".join(out)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces -> hyphens."""
    text = re.sub(r"[`*_]|<[^>]+>", "", heading.strip()).lower()
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)  # a link in a heading keeps its text
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a markdown file, with GitHub's -1, -2 suffixes for repeated headings."""
    seen: dict[str, int] = {}
    out = set()
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line):
            fenced = not fenced
        if fenced or not line.startswith("#"):
            continue
        base = slug(line.lstrip("#"))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def broken_links(path: Path) -> list[str]:
    problems = []
    for target in LINK.findall(prose(path.read_text(encoding="utf-8"))):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        dest = (path.parent / file_part).resolve() if file_part else path
        if not dest.exists():
            problems.append(f"{target}: no such file {dest.relative_to(REPO) if dest.is_relative_to(REPO) else dest}")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            problems.append(f"{target}: no heading with anchor #{anchor} in {dest.relative_to(REPO)}")
    return problems


@pytest.mark.parametrize("path", documents(), ids=lambda p: str(p.relative_to(REPO)))
def test_relative_links_resolve(path):
    assert broken_links(path) == [], path.relative_to(REPO)


def test_the_checker_catches_a_missing_file_and_a_missing_anchor(tmp_path):
    (tmp_path / "a.md").write_text("# A user's folder: cross-fitted\n\n## Repeated\n\n## Repeated\n")
    doc = tmp_path / "b.md"
    doc.write_text("[ok](a.md#a-users-folder-cross-fitted) [ok](a.md#repeated-1) [ok](#local) [web](https://x.org)\n"
                   "# Local\n```\n[not a link](missing.md)\n```\n"
                   "[gone](missing.md) [bad anchor](a.md#nope) ![img](fig.png)\n")
    global REPO
    saved, REPO = REPO, tmp_path
    try:
        problems = broken_links(doc)
    finally:
        REPO = saved
    assert len(problems) == 3, problems
    assert problems[0].startswith("missing.md: no such file") and "#nope" in problems[1] and "fig.png" in problems[2]


def test_readme_shows_what_the_docs_promise():
    """The README links the documents it hands the reasoning to, and its first figure exists."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    for doc in ("docs/gap_diagnosis.md", "docs/gap_validation.md", "docs/world_effects.md", "docs/results.md",
                "docs/gap_report.md", "docs/datasets.md", "docs/architecture.md", "CHANGELOG.md", "CITATION.cff"):
        assert f"]({doc}" in text, doc
    assert "docs/figures/hero.png" in text and (REPO / "docs" / "figures" / "hero.png").is_file()
