"""Which way imports go (DESIGN.md section 2), checked on the source: any import, at the top of
a module or inside a function, counts.

* ``milestones`` and ``viz`` are leaves: they import nothing of the project but themselves;
* ``drivers`` imports of ``vmp`` only the leaves every source needs (types, the source
  interface, errors, file helpers, the version), and nothing of ``milestones`` or ``viz``;
* the core (``vmp`` but its CLI) imports neither ``drivers`` nor ``viz`` nor the CLI;
* no two modules import each other, directly or round a longer cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("vmp", "milestones", "drivers", "viz")
DRIVER_LEAVES = {"vmp", "vmp.types", "vmp.source", "vmp.errors", "vmp.fileio"}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path, modules: set[str]) -> set[str]:
    """The project modules ``path`` imports (a name imported from a package counts as the
    submodule when it is one)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
        else:
            continue
        for name in names:
            while name and name not in modules:
                name = name.rpartition(".")[0]
            if name:
                out.add(name)
    return out


def _graph() -> dict[str, set[str]]:
    files = [f for p in PACKAGES for f in (ROOT / p).rglob("*.py")]
    modules = {_module_name(f) for f in files}
    graph = {}
    for f in files:
        me = _module_name(f)
        # A package's own __init__ is imported with any of its modules: not an edge.
        graph[me] = {m for m in _imports(f, modules) if m != me and not me.startswith(m + ".")}
    return graph


GRAPH = _graph()


def _top(module: str) -> str:
    return module.split(".")[0]


def _is_cli(module: str) -> bool:
    """The command line: ``vmp.cli`` and ``python -m vmp``."""
    return module in ("vmp.cli", "vmp.__main__") or module.startswith("vmp.cli.")


@pytest.mark.parametrize("leaf", ["milestones", "viz"])
def test_leaves_import_nothing_of_the_project(leaf):
    bad = {(m, i) for m, deps in GRAPH.items() if _top(m) == leaf for i in deps
           if _top(i) != leaf}
    assert not bad, f"{leaf} must stay a leaf: {sorted(bad)}"


def test_drivers_know_nothing_of_mapping():
    bad = {(m, i) for m, deps in GRAPH.items() if _top(m) == "drivers" for i in deps
           if _top(i) != "drivers" and i not in DRIVER_LEAVES}
    assert not bad, f"drivers may import only {sorted(DRIVER_LEAVES)} of vmp: {sorted(bad)}"


def test_the_core_imports_neither_sources_nor_views_nor_the_cli():
    bad = {(m, i) for m, deps in GRAPH.items() if _top(m) == "vmp" and not _is_cli(m)
           for i in deps if _top(i) in ("drivers", "viz") or _is_cli(i)}
    assert not bad, f"the core must not import these: {sorted(bad)}"


def test_no_import_cycles():
    """Tarjan's strongly connected components; any of more than one module is a cycle."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(GRAPH):
        if v not in index:
            visit(v)
    assert not cycles, f"modules that import each other: {cycles}"


def test_the_checks_see_the_imports():
    """The graph is not empty by mistake: known edges are in it."""
    assert "vmp.pipeline" in GRAPH["vmp.run"]
    assert "vmp.types" in GRAPH["drivers.carmen"]
    assert "milestones.manager" in GRAPH["vmp.pipeline"]
    assert "drivers" in GRAPH["vmp.cli.mapping"] or "drivers.open" in GRAPH["vmp.cli.mapping"]
