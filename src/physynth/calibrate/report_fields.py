"""The fit report held to the scenario it describes, in one place, after every fit.

The fits record what they fitted; the scenario they build sometimes holds something else: the LOS std
keeps only the white rest when the antenna sway takes its share, a process seen too rarely or switched
off is not generated, the link budget lowers the dropouts, the path's length is measured by the
generator. :func:`reconcile_parameters` compares every ``parameters`` entry of a report with the
scenario as written (``Scenario.model_dump(mode="json")``, what the YAML file holds):

- a key that names a value of the written scenario is a *field* (``"field": true``) and its ``value``
  is the value written; where the fit gave another number beyond rounding, that number is kept as
  ``fitted`` and ``why`` says in a few words why the scenario differs;
- any other key (a goodness of fit, the static sweeps' slope, a per-anchor fit the scenario pools, a
  per-anchor override left unset) is a fit diagnostic, ``"field": false``, its value as fitted.

:func:`unused_option_notes` names the options that change nothing for the recordings given, so that
none is accepted silently. Both speak in parameter words; the command line maps them to its options.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from typing import Any

ROUNDING_REL = 5e-3
"""Relative difference up to which a fitted number and the number written are the same number rounded
(the scenario writes 3 to 7 significant digits)."""

_OVERRIDES = ("channel_per_anchor", "availability_per_anchor")
"""Sections of per-anchor overrides: a value left unset (null) there is not written (the shared value applies)."""


def _lookup(node: Any, parts: list[str]) -> tuple[bool, Any]:
    """(found, value) of a dotted key in the written scenario (anchor ids may hold dots)."""
    if not parts:
        return True, node
    if isinstance(node, Mapping):
        for k in range(len(parts), 0, -1):
            name = ".".join(parts[:k])
            if name in node:
                found, value = _lookup(node[name], parts[k:])
                if found:
                    return True, value
    return False, None


def written_value(written: Mapping[str, Any], key: str) -> tuple[bool, Any]:
    """(is a field, value written) of a report key in the written scenario. A per-anchor override left
    unset is not a field; a mode list is given as the report gives it, (weight, mean_m, std_m) rows."""
    found, value = _lookup(written, key.split("."))
    if not found or (value is None and key.split(".", 1)[0] in _OVERRIDES):
        return False, None
    if key.endswith("nlos_modes") and isinstance(value, list) and all(isinstance(m, Mapping) for m in value):
        value = [[m["weight"], m["mean_m"], m["std_m"]] for m in value]
    return True, value


def same_number(a: Any, b: Any) -> bool:
    """Whether a fitted value and a written one are the same (numbers up to :data:`ROUNDING_REL`)."""
    if isinstance(a, bool) or isinstance(b, bool) or a is None or b is None:
        return a == b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return a == b or abs(a - b) <= ROUNDING_REL * max(abs(a), abs(b))
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same_number(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def _sway_reason(match: re.Match, report: Mapping[str, Any], fitted: Any) -> str | None:
    sway = report.get("antenna_sway") or {}
    if not sway.get("identifiable"):
        return None
    return (f"split with the antenna sway, which takes {sway['slow_share']:.0%} of the LOS variance; this is the "
            "white rest")


def _link_budget_reason(match: re.Match, report: Mapping[str, Any], fitted: Any) -> str | None:
    lb = report.get("link_budget") or {}
    aid = match.group(1)
    before = (lb.get("dropout_prob_before") or {}).get(aid)
    detection = (lb.get("mean_detection_per_anchor") or {}).get(aid)
    if not lb.get("applied") or before is None or detection is None:
        return None
    whose = "the dropout" if same_number(before, fitted) else "the dropout pooled over the anchors"
    return f"set by the link budget: {whose}, {before:.4g}, less its losses (mean detection {detection:.4f})"


def _tag_outage_reason(match: re.Match, report: Mapping[str, Any], fitted: Any) -> str | None:
    tag = (report.get("availability") or {}).get("tag_outages") or {}
    return None if tag.get("events", tag.get("n_outages")) else "no tag outage seen: not generated"


_REASONS: tuple[tuple[re.Pattern, Callable[[re.Match, Mapping[str, Any], Any], str | None]], ...] = (
    (re.compile(r"(?:^|\.)los_std_m$"), _sway_reason),
    (re.compile(r"^availability_per_anchor\.(.+)\.dropout_prob$"), _link_budget_reason),
    (re.compile(r"^availability\.tag_outage_onset_prob$"), _tag_outage_reason),
    (re.compile(r"^availability\.long_outage_"), lambda m, r, f: "not generated unless long_outages=True"),
    (re.compile(r"^path\.length_m$"), lambda m, r, f: "the generator measures it along the path (null)"),
)
"""Why a scenario field differs from its fit, by key; the first rule that has an answer gives it."""


def _why(key: str, fitted: Any, written: Any, report: Mapping[str, Any]) -> str:
    for pattern, reason in _REASONS:
        match = pattern.search(key)
        if match and (text := reason(match, report, fitted)):
            return text
    if written is None:
        return "written as null"
    if written == 0 or (isinstance(written, list) and not any(written)):
        return "not generated"
    return "the scenario holds the value written"


def reconcile_parameters(report: dict[str, Any], written: Mapping[str, Any]) -> dict[str, Any]:
    """``report["parameters"]`` held to the scenario ``written`` (its ``model_dump(mode="json")``), in
    place: every entry marked ``field``; a field's ``value`` the value written, the fit's own number
    kept as ``fitted`` with ``why`` where they differ beyond rounding. Returns the report."""
    for key, item in report.get("parameters", {}).items():
        is_field, value = written_value(written, key)
        item["field"] = is_field
        if not is_field:
            continue
        if not same_number(item["value"], value):
            item["fitted"] = item["value"]
            item["why"] = _why(key, item["fitted"], value, report)
        item["value"] = value
    return report


_UWB_OPTIONS: tuple[tuple[str, Callable[[Any], bool], Callable[[Any], str]], ...] = (
    ("static_sweeps", lambda v: v is not None, lambda v: "static_sweeps"),
    ("link_budget", bool, lambda v: "link_budget=True"),
    ("range_bias", lambda v: v == "static", lambda v: "range_bias='static'"),
    ("range_bias_law", lambda v: v not in (None, "log"), lambda v: f"range_bias_law={v!r}"),
    ("trusted_truth", bool, lambda v: "trusted_truth=True"),
    ("run_slopes", bool, lambda v: "run_slopes=True"),
    ("tag_pattern", bool, lambda v: "tag_pattern=True"),
    ("long_outages", bool, lambda v: "long_outages=True"),
    ("anchor_policy", lambda v: v not in (None, "per-run"), lambda v: f"anchor_policy={v!r}"),
    ("layout_from", lambda v: v is not None, lambda v: "layout_from"),
)
"""The UWB options of :func:`physynth.calibrate.calibrate`: (parameter, set?, how a note names it)."""


def unused_option_notes(options: Mapping[str, Any], *, uwb: bool, n_runs: int, untrusted_truth: bool) -> list[str]:
    """One note for each option in ``options`` (``calibrate``'s keyword arguments) that changes nothing
    for these recordings: ``uwb`` whether any has UWB ranges, ``n_runs`` how many have, and
    ``untrusted_truth`` whether any marks part of its truth as untrusted."""
    set_ = [(name, words(options[name])) for name, is_set, words in _UWB_OPTIONS if is_set(options.get(name))]
    if not uwb:
        return [f"{words} has no effect: the recordings have no UWB ranges (IMU only), so no UWB part is fitted"
                for _, words in set_]
    notes = []
    if options.get("run_slopes") and n_runs < 2:
        notes.append("run_slopes=True has no effect with one run: run-to-run tilts of the range law need several "
                     "runs")
    if options.get("trusted_truth") and not untrusted_truth:
        notes.append("trusted_truth=True has no effect: no recording marks any of its truth as untrusted, so "
                     "every range was used")
    return notes
