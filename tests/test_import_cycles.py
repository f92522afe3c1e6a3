"""No import cycle between the files of calibrate/, models/, bounds.py and scenario.py.

Every import counts (module level, inside a function, under ``TYPE_CHECKING``): a cycle a lazy import
hides is still two files that each need the other. Records both sides need move down a floor.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
AREAS = ("physynth.calibrate", "physynth.models", "physynth.bounds", "physynth.scenario")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """Module -> the modules of the package it imports (``from .x import y`` counts x.y when y is a module)."""
    files = {_module_name(p): p for p in (SRC / "physynth").rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for mod, path in files.items():
        pkg = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                base = (pkg[:len(pkg) - node.level + 1] if node.level else [])
                target = ".".join(base + ([node.module] if node.module else []))
                for alias in node.names:
                    sub = f"{target}.{alias.name}"
                    deps.add(sub if sub in files else target)
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names)
        graph[mod] = {d for d in deps if d in files and d != mod}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _in_area(mod: str) -> bool:
    return any(mod == a or mod.startswith(a + ".") for a in AREAS)


def test_no_import_cycle_in_calibrate_models_bounds_scenario():
    graph = import_graph()
    # a package's __init__ re-exports its modules: it is not a cycle for a module to import a sibling
    # through the package, so the package nodes are left out
    inits = {m for m in graph if (SRC / Path(*m.split("."))).is_dir()}
    area = {m: {d for d in deps if _in_area(d) and d not in inits} for m, deps in graph.items()
            if _in_area(m) and m not in inits}
    assert cycles(area) == []


if __name__ == "__main__":
    for comp in cycles(import_graph()):
        print(" <-> ".join(comp))
