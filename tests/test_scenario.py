"""Scenario files: presets load, YAML round trip, and each kind of bad file gives one clear message."""

from __future__ import annotations

import pytest
import yaml
from helpers import simple_scenario_dict

from physynth.errors import ScenarioError
from physynth.io.scenario_file import load_scenario, safe_load_bounded, save_scenario, scenario_to_yaml


def _write(tmp_path, data, name="s.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return p


def test_preset_yaml_round_trip(tmp_path):
    s = load_scenario("cablecar-descending")
    p = save_scenario(s, tmp_path / "copy.yaml", header="a copy")
    assert load_scenario(p) == s
    assert yaml.safe_load(scenario_to_yaml(s))["name"] == "cablecar-descending"


def test_per_anchor_overrides_merge_with_the_default():
    s = load_scenario("cablecar-descending")
    assert s.channel_for("A103").nlos_prob > s.channel_for("A101").nlos_prob
    assert s.channel_for("A101").los_std_m == s.channel.los_std_m


@pytest.mark.parametrize(("mutate", "expected"), [
    (lambda d: d["motion"].pop("cruise_speed_mps"), r"field motion\.cruise_speed_mps: Field required"),
    (lambda d: d["channel"].__setitem__("rate_hz", -5.0), r"field channel\.rate_hz: .*greater than 0.*-5\.0"),
    (lambda d: d["uwb"].__setitem__("burst_rate_hz", 0), r"field uwb\.burst_rate_hz: .*greater than 0"),
    (lambda d: d.__setitem__("channel_per_anchor", {"A9": {"los_std_m": 0.2}}), r"unknown anchor\(s\) \['A9'\]"),
    (lambda d: d.__setitem__("availability_per_anchor", {"Z": {}}), r"unknown anchor\(s\) \['Z'\]"),
    (lambda d: d["channel"].__setitem__("los_std_m", float("nan")), r"channel\.los_std_m: must be a finite number"),
    (lambda d: d["motion"].__setitem__("cruise_speed_mps", "fast"), r"field motion\.cruise_speed_mps: .*number"),
    (lambda d: d["anchors"][1].__setitem__("pos_enu_m", [1, 2]), r"field anchors\[1\]\.pos_enu_m: .*at least 3"),
    (lambda d: d["anchors"].append({"id": "A1", "pos_enu_m": [0, 0, 0]}), r"duplicate anchor id"),
    (lambda d: d["channel"].__setitem__("nlos_prob", 1.5), r"channel\.nlos_prob: .*less than or equal to 1"),
    (lambda d: d.__setitem__("colour", "red"), r"field colour: Extra inputs are not permitted"),
    (lambda d: d["motion"].__setitem__("cruise_sped_mps", d["motion"].pop("cruise_speed_mps")),
     r"field motion\.cruise_speed_mps is required and motion\.cruise_sped_mps is not a known field \(misspelled\?\)"),
    (lambda d: d.__setitem__("motoin", d.pop("motion")), r"field motion is required and motoin is not a known field"),
    (lambda d: d["channel"].__setitem__("rate_hz", 50.0), r"rate_hz exceeds uwb\.burst_rate_hz"),
])
def test_bad_scenario_files_give_one_clear_line(tmp_path, mutate, expected):
    d = simple_scenario_dict()
    mutate(d)
    p = _write(tmp_path, d)
    with pytest.raises(ScenarioError, match=expected) as err:
        load_scenario(p)
    msg = str(err.value)
    assert "\n" not in msg and str(p) in msg


def test_unreadable_and_unknown_scenarios(tmp_path):
    with pytest.raises(ScenarioError, match="unknown scenario 'nope'"):
        load_scenario("nope")
    with pytest.raises(ScenarioError, match="does not exist"):
        load_scenario(tmp_path / "missing.yaml")
    with pytest.raises(ScenarioError, match="not valid YAML at line"):
        load_scenario(_write(tmp_path, "name: [unclosed\n"))
    with pytest.raises(ScenarioError, match="expected a mapping"):
        load_scenario(_write(tmp_path, "- 1\n- 2\n", "list.yaml"))


def test_a_directory_is_not_a_scenario(tmp_path):
    with pytest.raises(ScenarioError, match="is a directory"):
        load_scenario(tmp_path)


def test_a_repeated_key_is_refused_naming_it_and_its_line(tmp_path):
    """Plain YAML keeps the last of two equal keys silently; a scenario file refuses them."""
    text = scenario_to_yaml(load_scenario("cablecar-descending"))
    lines = text.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("  los_std_m:"))
    lines.insert(at + 1, "  los_std_m: 0.5")
    f = tmp_path / "dup.yaml"
    f.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match=rf"duplicate key 'los_std_m' at line {at + 2} \(first at line {at + 1}\)"):
        load_scenario(f)
    merged = safe_load_bounded("base: &b {x: 1, y: 2}\nother:\n  <<: *b\n  x: 3\n", "merge")
    assert merged["other"] == {"x": 3, "y": 2}  # a key next to a YAML merge (<<) overrides it: no repeat
