"""The fit report under construction and the calibration's result (a scenario and its report).

The floor below the pipeline, its components and the IMU-only calibration: each of them writes into
one :class:`ReportBuilder` and returns a :class:`CalibrationResult`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from ..scenario import Scenario
from ._base import jsonable


@dataclass(slots=True)
class ReportBuilder:
    """The fit report under construction: sections, parameters, what is not identifiable, warnings."""

    sections: dict[str, Any] = field(default_factory=dict)
    parameters: dict[str, dict[str, Any]] = field(default_factory=dict)
    not_identifiable: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def param(self, key: str, value: Any, *, se: Any = None, n: int | None = None, note: str | None = None,
              summary: bool = False, interval: Sequence[float] | None = None) -> None:
        """Record one fitted parameter (``interval``: a 90 % credible interval, e.g. of a rate)."""
        item: dict[str, Any] = {"value": value}
        if se is not None:
            item["std_error"] = se
        if interval is not None:
            item["interval_90"] = [float(x) for x in interval]
        if n is not None:
            item["n_samples"] = int(n)
        if note:
            item["note"] = note
        if summary:
            item["summary"] = True
        self.parameters[key] = item

    def to_dict(self) -> dict[str, Any]:
        out = {**self.sections, "parameters": self.parameters, "not_identifiable": self.not_identifiable}
        if self.warnings:
            out["warnings"] = self.warnings
        return jsonable(out)


@dataclass(frozen=True, slots=True, kw_only=True)
class CalibrationResult:
    """A calibrated scenario and its fit report (JSON-able dict)."""

    scenario: Scenario
    report: dict[str, Any]

    def summary_rows(self, *, fields: bool = True) -> list[tuple[str, str, str]]:
        """(parameter, value, uncertainty or samples) rows for a short terminal table: the scenario's fields
        (``fields``; their values as written, the fit's own number beside where it differs) or the fit's
        diagnostics that are no scenario field (``fields=False``)."""
        rows = []
        for key, item in self.report["parameters"].items():
            if item.get("summary") and item.get("field", True) == fields:
                rows.append((key, format_value(item["value"]), _uncertainty(item)))
        return rows


def format_value(v: Any) -> str:
    return " / ".join(_fmt(x) for x in v) if isinstance(v, list) else _fmt(v)


def _uncertainty(item: dict[str, Any]) -> str:
    """The uncertainty column of a summary row: the fit's own number and why the scenario differs, or
    the 90 % interval, the standard error, the sample count or the note."""
    if "fitted" in item:
        return f"fitted {format_value(item['fitted'])}: {item.get('why', '')}"
    if item.get("interval_90") is not None:
        lo, hi = item["interval_90"]
        return f"90 % [{_fmt(lo)}, {_fmt(hi)}]"
    if item.get("std_error") is not None:
        return "+- " + format_value(item["std_error"])
    if item.get("n_samples") is not None:
        return f"n = {item['n_samples']}"
    return item.get("note", "")


def _fmt(x: Any) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.4g}"
    return str(x)
