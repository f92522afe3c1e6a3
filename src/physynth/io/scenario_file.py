"""Scenario files: built-in presets and YAML files, read and written.

Loading validates every field; a bad file gives one :class:`~physynth.errors.ScenarioError` line that
names the file, the field and the reason.
"""

from __future__ import annotations

import math
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from ..errors import ScenarioError
from ..scenario import Scenario, scenario_from_dict, scenario_to_dict
from .atomic import atomic_write_text

PRESET_DIR = "presets"


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


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A preset by name, or a scenario YAML file by path."""
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
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise ScenarioError(f"scenario {source}: not valid YAML{at}") from None
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
