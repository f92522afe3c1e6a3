"""Scenario files: built-in presets and YAML files, read and written.

Loading validates every field; a bad file gives one :class:`~physynth.errors.ScenarioError` line that
names the file, the field and the reason.
"""

from __future__ import annotations

import math
import os
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from ..errors import ScenarioError
from ..scenario import Scenario, scenario_from_dict, scenario_to_dict
from .atomic import atomic_write_text

PRESET_DIR = "presets"

MAX_YAML_NODES = 200_000
"""Most YAML nodes a scenario file may expand to, aliases counted at every use (no billion laughs)."""
MAX_YAML_BYTES = 20_000_000
"""Largest scenario file read [bytes]."""


def _expanded_size(node: yaml.Node, source: str) -> int:
    """Number of nodes of ``node`` with every alias expanded; refuse cycles and more than MAX_YAML_NODES."""
    memo: dict[int, int] = {}
    active: set[int] = set()

    def size(n: yaml.Node) -> int:
        key = id(n)
        if key in memo:
            return memo[key]
        if key in active:
            raise ScenarioError(f"scenario {source}: a YAML alias refers to itself (a recursive structure)")
        active.add(key)
        total = 1
        if isinstance(n, yaml.SequenceNode):
            for child in n.value:
                total += size(child)
                if total > MAX_YAML_NODES:
                    break
        elif isinstance(n, yaml.MappingNode):
            for k, v in n.value:
                total += size(k) + size(v)
                if total > MAX_YAML_NODES:
                    break
        active.discard(key)
        memo[key] = total
        if total > MAX_YAML_NODES:
            raise ScenarioError(f"scenario {source}: the YAML expands to more than {MAX_YAML_NODES:,} values "
                                "(nested aliases?); a scenario is far smaller")
        return total

    return size(node)


class _UniqueKeyLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # libyaml when PyYAML has it: ~10x faster
    """The safe loader, refusing a mapping that repeats a key (plain YAML keeps the last one silently)."""

    source = "<text>"

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, yaml.MappingNode):
            first_line: dict[Any, int] = {}
            for key_node, _ in node.value:  # before merge keys (<<) are flattened: a key may override them
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                line = key_node.start_mark.line + 1
                try:
                    if key in first_line:
                        raise ScenarioError(f"scenario {self.source}: duplicate key '{key}' at line {line} "
                                            f"(first at line {first_line[key]}); give each key once")
                    first_line[key] = line
                except TypeError:  # an unhashable key: the constructor below says so
                    pass
        return super().construct_mapping(node, deep=deep)


def safe_load_bounded(text: str, source: str) -> Any:
    """``yaml.safe_load`` that refuses recursive aliases, repeated keys and documents expanding past
    MAX_YAML_NODES."""
    if len(text) > MAX_YAML_BYTES:
        raise ScenarioError(f"scenario {source}: the file is larger than {MAX_YAML_BYTES / 1e6:g} MB")
    loader = _UniqueKeyLoader(text)
    loader.source = source
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded_size(node, source)
        return loader.construct_document(node)
    finally:
        loader.dispose()


def list_presets() -> list[str]:
    """Names of the built-in scenario presets."""
    files = resources.files("physynth").joinpath(PRESET_DIR).iterdir()
    return sorted(f.name[:-5] for f in files if f.name.endswith(".yaml"))


def _nan_guard(obj: Any, where: str = "") -> None:
    """YAML ``.nan``/``.inf`` anywhere (including free-form provenance) is refused early and clearly."""
    if isinstance(obj, float) and not math.isfinite(obj):
        raise ScenarioError(f"field {where or '<top>'}: must be a finite number (got {obj})")
    if isinstance(obj, dict):
        for k, v in obj.items():
            _nan_guard(v, f"{where}.{k}" if where else str(k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            _nan_guard(v, f"{where}[{i}]")


def load_scenario(name_or_path: str | os.PathLike | Scenario | dict[str, Any]) -> Scenario:
    """A preset by name, a scenario YAML file by path, or a mapping (as a scenario file holds it,
    :func:`physynth.scenario.scenario_from_dict`); a :class:`Scenario` is returned as it is.

    Raises
    ------
    ScenarioError
        One line naming the file or mapping, the field and the reason; or an argument of another type.
    """
    if isinstance(name_or_path, Scenario):
        return name_or_path
    if isinstance(name_or_path, dict):
        return _from_mapping(name_or_path, "<dict>")
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise ScenarioError(f"a scenario is a preset name, a scenario file, a mapping or a Scenario, got "
                            f"{type(name_or_path).__name__}")
    text: str
    source = str(name_or_path)
    p = Path(name_or_path)
    if str(name_or_path) in list_presets():
        text = resources.files("physynth").joinpath(PRESET_DIR, f"{name_or_path}.yaml").read_text("utf-8")
        source = f"preset '{name_or_path}'"
    elif p.suffix.lower() in (".yaml", ".yml", ".json") or p.exists():
        if p.is_dir():
            raise ScenarioError(f"scenario {p} is a directory, not a scenario file")
        if not p.is_file():
            raise ScenarioError(f"scenario file {p} does not exist")
        try:
            text = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ScenarioError(f"cannot read scenario file {p}: {exc}") from None
    else:
        raise ScenarioError(f"unknown scenario '{name_or_path}': not a preset ({', '.join(list_presets())}) "
                            "and not a file")
    try:
        data = safe_load_bounded(text, source)
    except RecursionError:
        raise ScenarioError(f"scenario {source}: the YAML is nested too deeply") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise ScenarioError(f"scenario {source}: not valid YAML{at}") from None
    return _from_mapping(data, source)


def _from_mapping(data: Any, source: str) -> Scenario:
    """The scenario of a mapping read from ``source``; non-finite numbers anywhere are refused first."""
    try:
        _nan_guard(data)
    except ScenarioError as exc:
        raise ScenarioError(f"scenario {source}: {exc}") from None
    return scenario_from_dict(data, source)


def mapping_to_yaml(data: dict[str, Any]) -> str:
    """A scenario mapping as YAML, in the layout of the shipped presets (keys in model order)."""
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)


def scenario_to_yaml(scn: Scenario) -> str:
    return mapping_to_yaml(scenario_to_dict(scn))


def save_scenario(scn: Scenario, path: str | Path, header: str = "") -> Path:
    """Write a scenario as YAML, atomically."""
    text = "".join(f"# {line}\n" for line in header.splitlines()) + scenario_to_yaml(scn)
    atomic_write_text(Path(path), text)
    return Path(path)
