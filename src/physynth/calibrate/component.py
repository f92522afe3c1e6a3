"""One component of the calibrated model: what it needs, how it is fitted, and whether it was.

A component is one physical effect (or one part of the scenario) the calibration fits: the path and
motion, the UWB timing, the ranging errors, the antenna sway, the link budget, the IMU noise, ... It
says what of the recordings it reads (``data``), declares the components whose results it reads
(``needs``), fits on a :class:`CalibrationContext` (the checked inputs, the options, the report and
the results of the components before it) and returns its result (a record of parameters); it writes
its own section and parameters into the report. :data:`physynth.calibrate.pipeline.COMPONENTS` lists
them in dependency order; the report's ``components`` section says, per component, what it fits, what
it reads and whether it was fitted (when not, why).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from ..progress import ProgressCallback
from ..scenario import Scenario
from .geometry import AnchorPolicy, PathKind
from .inputs import CalibrationInputs
from .report import ReportBuilder


@dataclass(frozen=True, slots=True, kw_only=True)
class CalibrationOptions:
    """The options of :func:`physynth.calibrate.calibrate` that steer the components."""

    path_kind: PathKind = "auto"
    anchor_policy: AnchorPolicy = "per-run"
    layout_from: int | str | None = None
    static_sweeps: str | os.PathLike | None = None
    range_bias: Literal["dynamic", "static"] = "dynamic"
    range_bias_law: Literal["log", "linear"] = "log"
    long_outages: bool = False
    tag_pattern: bool = False
    run_slopes: bool = False
    link_budget: bool = False
    trusted_truth: bool = False


@dataclass(slots=True, kw_only=True)
class CalibrationContext:
    """What a component fits on: the inputs, the options, the report, the results before it."""

    inputs: CalibrationInputs
    options: CalibrationOptions
    report: ReportBuilder
    progress: ProgressCallback
    fitted: dict[str, Any] = field(default_factory=dict)  # component name -> its result
    not_fitted: dict[str, str] = field(default_factory=dict)  # component name -> why it was not fitted

    def skip(self, name: str, why: str) -> None:
        """Mark component ``name`` as not fitted (no data for it), with the reason (its result: defaults)."""
        self.not_fitted[name] = why


def always(ctx: CalibrationContext) -> str | None:  # noqa: ARG001
    """A component that always runs."""
    return None


@dataclass(frozen=True, slots=True, kw_only=True)
class Component:
    """One component of the calibration.

    ``name``: its key in the results and in the report's ``components`` section; ``fits``: the
    scenario fields (or the effect) it fits, one line; ``data``: what of the recordings it reads, one
    line; ``needs``: the components whose results it reads
    (they come before it in the list); ``fit(ctx)`` -> its result, its report section and parameters
    written into ``ctx.report``; ``step``: the progress message said before it runs (None: it says its
    own); ``off(ctx)`` -> why it does not run for these options (None: it runs); ``without(scenario,
    report)`` -> the calibrated scenario with the component's optional effect taken out (its fields
    at the values that switch it off; None: the component is no optional effect), what the held-out
    evidence compares against (:func:`physynth.calibrate.held_out.held_out_evidence`, which
    ``tools/component_evidence.py`` and ``physynth calibrate --select-components evidence`` run).
    """

    name: str
    fits: str
    data: str
    fit: Callable[[CalibrationContext], Any]
    needs: tuple[str, ...] = ()
    step: str | None = None
    off: Callable[[CalibrationContext], str | None] = always
    without: Callable[[Scenario, dict[str, Any]], Scenario] | None = None


def run_components(components: tuple[Component, ...], ctx: CalibrationContext) -> dict[str, dict[str, Any]]:
    """Fit ``components`` in order into ``ctx.fitted``; returns the report's ``components`` section."""
    section: dict[str, dict[str, Any]] = {}
    for comp in components:
        missing = [n for n in comp.needs if n not in ctx.fitted]
        if missing:
            raise RuntimeError(f"component {comp.name} needs {', '.join(missing)}, which come after it or are off")
        why = comp.off(ctx)
        if why is None:
            if comp.step is not None:
                ctx.progress(comp.step)
            ctx.fitted[comp.name] = comp.fit(ctx)
            why = ctx.not_fitted.get(comp.name)
        section[comp.name] = {"fits": comp.fits, "data": comp.data, "fitted": why is None,
                              **({"why": why} if why else {})}
    return section


def check_order(components: tuple[Component, ...]) -> None:
    """Raise ValueError when a component needs one that does not come before it (or names twice)."""
    seen: set[str] = set()
    for comp in components:
        if comp.name in seen:
            raise ValueError(f"component {comp.name} listed twice")
        late = [n for n in comp.needs if n not in seen]
        if late:
            raise ValueError(f"component {comp.name} needs {', '.join(late)}, which must come before it")
        seen.add(comp.name)
