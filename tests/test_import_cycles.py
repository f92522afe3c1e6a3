"""No import cycle between the files of the package ``physynth`` (and, kept on its own, none between
those of calibrate/, models/, bounds.py and scenario.py).

Every import counts (module level, inside a function, under ``TYPE_CHECKING``): a cycle a lazy import
hides is still two files that each need the other. Records both sides need move down a floor.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
AREAS = ("physynth.calibrate", "physynth.models", "physynth.bounds", "physynth.scenario")


def _module_name(path: Path, src: Path = SRC) -> str:
    parts = list(path.relative_to(src).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(package: Path = SRC / "physynth") -> dict[str, set[str]]:
    """Module -> the modules of the package it imports (``from .x import y`` counts x.y when y is a module).

    ``package``: the package's folder (``physynth`` under ``src/`` unless told)."""
    files = {_module_name(p, package.parent): p for p in package.rglob("*.py")}
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


def test_no_import_cycle_in_the_whole_package():
    # every module of physynth, package __init__ files included: a module that imports its own
    # package's __init__ (``from . import x`` of a name, not a module) while that __init__ imports it
    # is a cycle too
    found = cycles(import_graph())
    assert found == [], "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_a_cycle_through_a_lazy_or_type_checking_import_is_found(tmp_path):
    """The checker itself: a cycle that only a function-level import or a ``TYPE_CHECKING`` block closes
    is reported, so the whole-package test fails when one comes back."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from .b import B\n")
    (pkg / "b.py").write_text("B = 1\n\ndef f():\n    from .a import B as A\n    return A\n")
    (pkg / "sub" / "c.py").write_text("from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n"
                                      "    from ..d import D\n")
    (pkg / "d.py").write_text("from .sub import c\n\nD = 1\n")
    (pkg / "e.py").write_text("from . import a, d\n")  # imports both, part of no cycle
    assert cycles(import_graph(pkg)) == [["pkg.a", "pkg.b"], ["pkg.d", "pkg.sub.c"]]
    (pkg / "b.py").write_text("B = 1\n")
    (pkg / "d.py").write_text("D = 1\n")
    assert cycles(import_graph(pkg)) == []


if __name__ == "__main__":
    for comp in cycles(import_graph()):
        print(" <-> ".join(comp))
