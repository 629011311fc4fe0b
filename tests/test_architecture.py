"""The layering of docs/architecture.md holds: imports point down, no rings, local imports explained; the
scripts of experiments/ and benchmarks/ import each other in no ring either.

The layer table and the list of modules allowed function-local imports are read from the document
itself, so the document and this test cannot drift apart.
"""

from __future__ import annotations

import ast
import re
from collections import defaultdict
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src" / "handradar"
DOC = REPO / "docs" / "architecture.md"


def _table(marker: str) -> list[list[str]]:
    """Rows (cells) of the markdown table that follows ``<!-- marker ... -->`` in the document."""
    text = DOC.read_text()
    start = text.index(f"<!-- {marker}")
    rows = []
    for line in text[start:].splitlines()[1:]:
        if not line.startswith("|"):
            if rows:
                break
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if set(cells[0]) <= {"-"} or cells[0] in ("layer", "module"):
            continue
        rows.append(cells)
    return rows


def layers() -> dict[str, int]:
    """{top-level package or module: layer}."""
    out = {}
    for cells in _table("layers"):
        for name in re.findall(r"`([a-z_]+)`", cells[1]):
            out[name] = int(cells[0])
    return out


def local_import_modules() -> set[str]:
    return {re.findall(r"`([a-z_.]+)`", cells[0])[0] for cells in _table("local-imports")}


def module_name(path: Path, base: Path = SRC.parent) -> str:
    parts = path.relative_to(base).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path, me: str | None = None, base: Path = SRC.parent,
            roots: tuple[str, ...] = ("handradar",)) -> list[tuple[str, bool, int]]:
    """(imported module of the packages ``roots`` under ``base``, inside a function?, line) of every import in
    the file of module ``me``."""
    tree = ast.parse(path.read_text())
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
    me = me or module_name(path, base)
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:  # relative import: resolve against this module's package
                base = me.split(".") if path.name == "__init__.py" else me.split(".")[:-1]
                base = base[: len(base) - node.level + 1]
                names = [".".join([*base, node.module] if node.module else base)]
            else:
                names = [node.module or ""]
            # `from handradar.x import y` may import the submodule handradar.x.y
            names = [f"{names[0]}.{a.name}" if (base / f"{names[0]}.{a.name}".replace(".", "/")).with_suffix(".py").is_file()
                     or (base / f"{names[0]}.{a.name}".replace(".", "/")).is_dir() else names[0]
                     for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        p, local = node, False
        while p in parents:
            p = parents[p]
            if isinstance(p, (ast.FunctionDef, ast.AsyncFunctionDef)):
                local = True
                break
        out += [(n, local, node.lineno) for n in names if n in roots or n.startswith(tuple(f"{r}." for r in roots))]
    return out


MODULES = {module_name(p): p for p in sorted(SRC.rglob("*.py"))}
SCRIPT_PACKAGES = ("experiments", "benchmarks")  # python -m experiments.tables etc., from the repository root
SCRIPTS = {module_name(p, REPO): p for d in SCRIPT_PACKAGES for p in sorted((REPO / d).rglob("*.py"))}


def import_graph(modules: dict[str, Path], base: Path = SRC.parent,
                 roots: tuple[str, ...] = ("handradar",)) -> dict[str, set[str]]:
    """{module: the modules it imports, at the top or inside a function}; a package's ``__init__`` importing a
    sibling package's ``__init__`` is not an edge."""
    graph: dict[str, set[str]] = defaultdict(set)
    for m, p in modules.items():
        for t, _, _ in imports(p, m, base, roots):
            target = t
            while target not in modules and "." in target:  # `handradar.x.Name` -> module handradar.x
                target = target.rsplit(".", 1)[0]
            if target in modules and target != m and not modules[m].name == "__init__.py" == modules[target].name:
                graph[m].add(target)
    return graph


def ring(graph: dict[str, set[str]]) -> list[str] | None:
    """An import ring of ``graph`` (its modules in order, the first repeated at the end), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for nxt in sorted(graph.get(n, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[n] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def top(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def test_every_package_has_a_layer():
    known = layers()
    missing = sorted({top(m) for m in MODULES if top(m)} - set(known))
    assert not missing, f"packages missing from the layer table of {DOC.name}: {missing}"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_point_down(module: str):
    known = layers()
    me = top(module)
    bad = []
    for target, _, line in imports(MODULES[module], module):
        other = top(target)
        if other in ("", me):
            continue
        if other not in known:
            bad.append(f"line {line}: {target} (no layer)")
        elif known[other] > known[me] or (known[other] == known[me] and known[me] != 0):
            bad.append(f"line {line}: {target} (layer {known[other]}) from layer {known[me]}")
    assert not bad, f"{module} imports upward or sideways: {bad}"


def test_function_local_imports_are_explained():
    allowed = local_import_modules()
    unexplained = sorted({f"{m}:{line} -> {t}" for m, p in MODULES.items() for t, local, line in imports(p, m)
                          if local and m not in allowed})
    assert not unexplained, f"function-local handradar imports not explained in {DOC.name}: {unexplained}"


def test_no_import_rings():
    graph = import_graph(MODULES)
    # package-level: a ring between packages breaks the layering even if modules do not form one
    packages: dict[str, set[str]] = defaultdict(set)
    for a, targets in graph.items():
        packages[top(a)] |= {top(b) for b in targets if top(b) != top(a)}
    for g in (graph, packages):
        found = ring(g)
        assert found is None, f"import ring: {' -> '.join(found)}"


def test_no_import_rings_among_experiments_and_benchmarks():
    assert {"experiments.tables", "experiments.data_efficiency", "benchmarks.common"} <= set(SCRIPTS)
    found = ring(import_graph(SCRIPTS, REPO, SCRIPT_PACKAGES))
    assert found is None, f"import ring: {' -> '.join(found)}"


def test_the_ring_check_sees_a_function_level_ring(tmp_path: Path):
    """Not vacuous: two scripts importing each other, one of them inside a function, form a ring."""
    (tmp_path / "experiments").mkdir()
    (tmp_path / "experiments" / "a.py").write_text("from experiments.b import g\n")
    (tmp_path / "experiments" / "b.py").write_text("def g():\n    from experiments.a import f\n")
    probes = {module_name(p, tmp_path): p for p in sorted((tmp_path / "experiments").glob("*.py"))}
    assert ring(import_graph(probes, tmp_path, SCRIPT_PACKAGES)) == ["experiments.a", "experiments.b", "experiments.a"]


def test_the_checker_sees_an_upward_import(tmp_path: Path):
    """The rules are not vacuous: a layer-3 module importing layer 9 is reported."""
    known = layers()
    assert known["data"] < known["gap"] and known["errors"] == 0 and known["cli"] == max(known.values())
    fake = tmp_path / "_upward_probe.py"
    fake.write_text("from handradar.gap import job\n\n\ndef f():\n    from handradar.tasks import train\n")
    try:
        found = imports(fake, "handradar.data._upward_probe")
        assert ("handradar.gap.job", False, 1) in found and ("handradar.tasks.train", True, 5) in found
        MODULES["handradar.data._upward_probe"] = fake
        with pytest.raises(AssertionError, match="imports upward"):
            test_imports_point_down("handradar.data._upward_probe")
        with pytest.raises(AssertionError, match="not explained"):
            test_function_local_imports_are_explained()
    finally:
        MODULES.pop("handradar.data._upward_probe", None)


MAX_MODULE_LINES = 800  # one idea per file: a module past this holds several (split it by idea)


def test_no_module_over_the_line_limit():
    long = {str(p.relative_to(REPO)): n for p in SRC.rglob("*.py")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"
