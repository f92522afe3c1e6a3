"""Every Sphinx-style cross-reference to the package in the sources names something that exists.

Scans each ``.py`` under ``src/physynth`` for ``:mod:``, ``:func:``, ``:class:``, ``:meth:``, ``:data:``,
``:attr:`` and ``:exc:`` roles whose target starts with ``physynth.`` (a leading ``~`` allowed) or is relative
(``.name``: against the module the text is in, then against its package, as a relative import reads it), and
resolves each: the longest prefix that imports as a module, then ``getattr`` for the rest (a class's fields
that are not class attributes, as pydantic's and annotated ones, count). A reference to a module of an earlier
layout (``physynth.uwb`` for ``physynth.models.uwb``) or to a renamed function fails here, with its file and
line.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "physynth"
ROLE = re.compile(r":(mod|func|class|meth|data|attr|exc):`([^`]+)`")


def _target(text: str) -> str:
    """The target of a role's text: ``title <target>`` -> target; without ``~`` and a trailing ``()``."""
    m = re.search(r"<([^>]+)>\s*$", text)
    target = (m.group(1) if m else text).strip().lstrip("~")
    return target[:-2] if target.endswith("()") else target


def _module_name(path: Path, src: Path) -> str:
    parts = list(path.relative_to(src).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _has_member(obj: object, name: str) -> tuple[bool, object]:
    """``obj.name`` as getattr finds it, or a field a class declares without a class attribute."""
    try:
        return True, getattr(obj, name)
    except AttributeError:
        pass
    if isinstance(obj, type):
        for klass in obj.__mro__:
            if name in (getattr(klass, "model_fields", None) or {}) or name in vars(klass).get("__annotations__", {}):
                return True, None
    return False, None


def resolve(target: str) -> str | None:
    """None when ``target`` (dotted, absolute) names an importable module or an object in one; else why not."""
    parts = target.split(".")
    for n in range(len(parts), 0, -1):
        name = ".".join(parts[:n])
        try:
            obj: object = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name is not None and not name.startswith(exc.name) and not exc.name.startswith(name):
                return f"importing {name} fails: {exc}"  # a missing dependency, not a missing module
            continue
        for i, attr in enumerate(parts[n:], n):
            found, obj = _has_member(obj, attr)
            if not found:
                return f"{'.'.join(parts[:i])} has no {attr!r}"
            if obj is None:  # a declared field: nothing further to look into
                return None if i == len(parts) - 1 else f"{'.'.join(parts[:i + 1])} is a field"
        return None
    return f"no module {parts[0]}"


def _candidates(target: str, module: str, is_package: bool) -> list[str]:
    """Absolute targets a relative one may mean: the module itself, then its package (Python's reading)."""
    rel = target.lstrip(".")
    package = module if is_package else module.rpartition(".")[0]
    for _ in range(len(target) - len(rel) - 1):  # ``..x``: one package up per extra dot
        package = package.rpartition(".")[0]
    return list(dict.fromkeys([f"{module}.{rel}", f"{package}.{rel}"]))


def bad_references(root: Path, src: Path) -> list[str]:
    """``file:line: :role:`target` -- why`` for each reference under ``root`` that does not resolve."""
    bad = []
    for path in sorted(root.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        module = _module_name(path, src)
        for m in ROLE.finditer(text):
            target = _target(m.group(2))
            if target.startswith("physynth."):
                why = resolve(target)
            elif target.startswith("."):
                whys = [resolve(t) for t in _candidates(target, module, path.name == "__init__.py")]
                why = None if None in whys else whys[-1]
            else:
                continue
            if why is not None:
                line = text.count("\n", 0, m.start()) + 1
                bad.append(f"{path.relative_to(src.parent)}:{line}: {m.group(0)} -- {why}")
    return bad


def test_every_reference_to_the_package_resolves():
    bad = bad_references(PACKAGE, SRC)
    assert not bad, f"{len(bad)} docstring references do not resolve:\n" + "\n".join(bad)


def test_a_wrong_reference_is_reported(tmp_path, monkeypatch):
    pkg = tmp_path / "physynth_refcheck_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text('"""See :mod:`.sub` and :func:`.sub.there`."""\n', encoding="utf-8")
    (pkg / "sub.py").write_text(
        '"""Fine: :func:`physynth.data.fetch`, :class:`~physynth.records.Trace`, :func:`there`,\n'
        ':meth:`physynth.data.Dataset.registry`, :attr:`physynth.data.Dataset.name`, :func:`.there`.\n\n'
        'Wrong: :func:`physynth.data.no_such_function`, :mod:`physynth.uwb`, :func:`.nowhere`,\n'
        ':meth:`physynth.data.Dataset.no_method`.\n"""\n\n\ndef there():\n    pass\n', encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    bad = bad_references(pkg, tmp_path)
    where = f"{tmp_path.name}/physynth_refcheck_pkg/sub.py"
    assert [b.split(" -- ")[0] for b in bad] == [
        f"{where}:4: :func:`physynth.data.no_such_function`",
        f"{where}:4: :mod:`physynth.uwb`",
        f"{where}:4: :func:`.nowhere`",
        f"{where}:5: :meth:`physynth.data.Dataset.no_method`",
    ], bad
    assert "physynth.data has no 'no_such_function'" in bad[0]
