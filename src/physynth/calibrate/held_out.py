"""Held-out evidence per optional calibration component, inside the calibration's own runs.

A component with an optional effect (``Component.without`` in
:data:`physynth.calibrate.pipeline.COMPONENTS`: late stamps, run-to-run spreads, antenna sway, tag-side
NLOS, the link budget) earns its place when generating the effect brings the synthetic traces closer to a
run the calibration did not see. :func:`held_out_evidence` measures that by leaving each input run out in
turn: calibrate on the others, generate ``n`` traces of the scenario transferred onto the left-out run
(path, motion and anchors from it, as ``physynth validate --transfer``) and compare them with it, once as
calibrated and once with each component's effect taken out (the same seed both times). The gain on a
measure is the deviation without the component minus the deviation with it (:data:`MEASURES`: KS x 100,
the UWB >= 1 and mean AoI relative deviations in %, the absolute signed-median difference in cm);
positive: the component brings the traces closer to the left-out run.

The decision (:data:`DROP_RULE`): a component is dropped when its combined gain, the mean over the
held-out runs of its gain averaged over the four measures, is negative; kept otherwise; ``no evidence``
(kept as calibrated) when no held-out calibration generated it (not fitted, or nothing to take out).

:func:`calibrate_selected` is :func:`~physynth.calibrate.pipeline.calibrate` with a selection: the evidence
on the input runs, then the calibration on all of them with the dropped components taken out; its report's
``components`` section gives each component's evidence and decision. ``tools/component_evidence.py`` prints
the evidence on the shared Hanyang runs and ``tools/loo_hanyang.py --select-components evidence``
measures the selection itself on runs it never saw.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, TypeVar

import numpy as np

from ..progress import ProgressCallback, no_progress
from ..records import Trace
from ..scenario import Scenario
from ._base import CalibrationError, as_trace_list, trace_label
from .component import Component
from .geometry import transfer_scenario
from .pipeline import COMPONENTS, calibrate
from .report import CalibrationResult
from .report_fields import same_number, written_value

T = TypeVar("T")

MEASURES = ("KS x 100", "UWB>=1 dev. %", "mean AoI dev. %", "|median diff.| cm")
"""The validation's deviations from a held-out run the evidence compares (smaller: closer)."""
SELECT_CHOICES = ("all", "evidence")
"""How :func:`calibrate_selected` chooses the components (``select_components``): ``all`` (every one, as
calibrated) or ``evidence``."""
DROP_RULE = ("drop a component when its combined gain (the mean over the held-out runs of its gain averaged "
             "over the four measures: KS x 100, UWB>=1 dev. %, mean AoI dev. %, |median diff.| cm) is negative; "
             "keep it otherwise, and when no held-out calibration generated it (no evidence)")
STEP = "held-out evidence"
"""The counted progress message of :func:`held_out_evidence` (one unit per calibration and validation)."""
DEFAULT_N = 20
DEFAULT_SEED = 1


def leave_one_out(items: Sequence[T], order: Sequence[int] | None = None) -> Iterator[tuple[int, T, list[T]]]:
    """Each item in turn (those of ``order``, indices; default all): ``(index, item, the others in their
    order)``: the one leave-one-out loop of the calibration's evidence and of the maintainers' tools."""
    for k in range(len(items)) if order is None else order:
        yield k, items[k], [x for j, x in enumerate(items) if j != k]


def optional_components(names: Sequence[str] | None = None) -> tuple[Component, ...]:
    """The components with an optional effect (``without``), in calibration order; ``names``: only these
    (an unknown or non-optional name is a :class:`CalibrationError` naming the parameter)."""
    optional = tuple(c for c in COMPONENTS if c.without is not None)
    if names is None:
        return optional
    known = {c.name for c in optional}
    bad = [n for n in names if n not in known]
    if bad:
        raise CalibrationError(f"components: {', '.join(bad)} is not an optional component "
                               f"(choose from {', '.join(sorted(known))})")
    return tuple(c for c in optional if c.name in names)


def deviations(rep: Any) -> np.ndarray:
    """A validation report's deviations from the real run, in the units of :data:`MEASURES`."""
    c = rep.comparison
    return np.array([100.0 * rep.ks_statistic, abs(c["uwb_ge1_frac"]["deviation"]), abs(c["mean_aoi_s"]["deviation"]),
                     100.0 * abs(c["residual_median_m"]["deviation"])])


def validate_on(scenario: Scenario, real: Trace, *, n: int, seed: int) -> Any:
    """``scenario`` transferred onto the run ``real`` and compared with it on ``n`` generated traces of root
    seed ``seed``: what ``physynth validate --real RUN --scenario S --transfer`` computes (a
    :class:`~physynth.validate.compare.ValidationReport`)."""
    from ..generate import compile_scenario, generate_traces
    from ..validate.compare import anchor_ids, check_real, compare, transfer_record

    check_real([real], f"run {trace_label(real, 0)}")
    moved = transfer_scenario(scenario, [real])
    ids = anchor_ids([real])
    synth = generate_traces(compile_scenario(moved), n, seed=seed)
    return compare([real], synth, rate_hz=float(moved.grid_rate_hz), transfer=transfer_record(scenario, moved, "", ids),
                   inputs={"synthetic": {"n_traces": n, "root_seed": seed}})


@dataclass(slots=True)
class ComponentEvidence:
    """One component's held-out evidence: per left-out run its gains (one per measure) or why none."""

    name: str
    gains: dict[str, list[float]] = field(default_factory=dict)  # left-out run -> gain per measure
    skipped: dict[str, str] = field(default_factory=dict)  # left-out run -> why no gain there

    @property
    def mean_gain(self) -> list[float] | None:
        """Per measure, the mean gain over the held-out runs (None: no run had the effect)."""
        return [float(x) for x in np.mean(list(self.gains.values()), axis=0)] if self.gains else None

    @property
    def combined(self) -> float | None:
        """The mean over the held-out runs of the gain averaged over the measures (the decision's number)."""
        return None if self.mean_gain is None else float(np.mean(self.mean_gain))

    @property
    def decision(self) -> Literal["keep", "drop", "no evidence"]:
        """:data:`DROP_RULE` applied."""
        if self.combined is None:
            return "no evidence"
        return "drop" if self.combined < 0 else "keep"

    def to_dict(self) -> dict[str, Any]:
        return {"per_run": {run: dict(zip(MEASURES, map(float, g), strict=True)) for run, g in self.gains.items()},
                "skipped": dict(self.skipped),
                "mean_gain": None if self.mean_gain is None else dict(zip(MEASURES, self.mean_gain, strict=True)),
                "combined_gain": self.combined, "decision": self.decision}


@dataclass(slots=True)
class HeldOutEvidence:
    """:func:`held_out_evidence`'s result: per component its evidence, per left-out run the deviations
    of the scenario as calibrated."""

    components: dict[str, ComponentEvidence]
    runs: list[str]
    deviations: dict[str, list[float]]  # left-out run -> deviations with every component
    n: int
    seed: int

    @property
    def dropped(self) -> list[str]:
        """The components :data:`DROP_RULE` drops, in calibration order."""
        return [name for name, ev in self.components.items() if ev.decision == "drop"]

    def to_dict(self) -> dict[str, Any]:
        return {"rule": DROP_RULE, "measures": list(MEASURES), "n_traces": self.n, "seed": self.seed,
                "held_out_runs": list(self.runs),
                "deviations_as_calibrated": {r: dict(zip(MEASURES, d, strict=True))
                                             for r, d in self.deviations.items()},
                "components": {name: ev.to_dict() for name, ev in self.components.items()}}


def _labels(trs: Sequence[Trace], labels: Sequence[str] | None) -> list[str]:
    if labels is not None:
        if len(labels) != len(trs):
            raise CalibrationError(f"labels: {len(labels)} given for {len(trs)} runs")
        return list(labels)
    out = [trace_label(t, k) for k, t in enumerate(trs)]
    return out if len(set(out)) == len(out) else [f"{x} [{k}]" for k, x in enumerate(out)]


def held_out_evidence(traces: Sequence[Trace], *, n: int = DEFAULT_N, seed: int = DEFAULT_SEED,
                      left_out: Sequence[int] | None = None, components: Sequence[str] | None = None,
                      labels: Sequence[str] | None = None, progress: ProgressCallback | None = None,
                      on_run: Any = None, **options: Any) -> HeldOutEvidence:
    """Each optional component's held-out evidence inside the runs ``traces`` (leave one run out).

    Parameters
    ----------
    traces
        The runs (at least 2, each with truth and UWB ranges); each is left out in turn.
    n, seed
        Synthetic traces per validation and their root seed (the same for the scenario with and without
        a component, so the gain is not the seed's noise).
    left_out
        Indices of the runs to leave out (default: every one).
    components
        Names of the optional components to measure (default: every one).
    labels
        The runs' names in the result (default: their ``label``).
    progress
        ``progress(message, done, total)``: :data:`STEP` counted, one unit per calibration and per
        validation; a line without a count as each run is left out.
    on_run
        ``on_run(label, result, deviations, gains)`` after each left-out run (``gains``: component name ->
        gain array, or the reason there is none); the tools print their rows from it.
    **options
        :func:`~physynth.calibrate.pipeline.calibrate`'s options for every calibration (``link_budget``,
        ``static_sweeps``, ...).

    Raises
    ------
    CalibrationError
        Fewer than 2 runs (``traces``), ``n < 1``, an unknown component or run index.
    """
    trs = as_trace_list(traces)
    if len(trs) < 2:
        raise CalibrationError(f"traces: held-out evidence needs at least 2 runs (one left out, the others "
                               f"calibrated), got {len(trs)}")
    if int(n) < 1:
        raise CalibrationError(f"n: the number of synthetic traces per validation must be at least 1, got {n}")
    chosen = optional_components(components)
    names = _labels(trs, labels)
    order = list(range(len(trs))) if left_out is None else [int(k) for k in left_out]
    if any(not 0 <= k < len(trs) for k in order):
        raise CalibrationError(f"left_out: run indices must lie in 0..{len(trs) - 1}, got {list(left_out or [])}")
    say = progress or no_progress
    total, done = len(order) * (2 + len(chosen)), 0
    result = HeldOutEvidence(components={c.name: ComponentEvidence(c.name) for c in chosen},
                             runs=[names[k] for k in order], deviations={}, n=int(n), seed=int(seed))
    for k, _, others in leave_one_out(trs, order):
        left = names[k]
        say(f"held-out evidence: leaving out {left}")
        say(STEP, done, total)
        res = calibrate(others, name="held-out", **options)
        done += 1
        say(STEP, done, total)
        with_dev = deviations(validate_on(res.scenario, trs[k], n=n, seed=seed))
        done += 1
        say(STEP, done, total)
        result.deviations[left] = [float(x) for x in with_dev]
        run_gains: dict[str, Any] = {}
        for comp in chosen:
            ev = result.components[comp.name]
            entry = res.report["components"][comp.name]
            without = comp.without(res.scenario, res.report) if entry["fitted"] else None
            if without is None or without == res.scenario:
                why = f"not fitted: {entry.get('why')}" if without is None else "nothing generated to take out"
                ev.skipped[left] = run_gains[comp.name] = why
            else:
                gain = deviations(validate_on(without, trs[k], n=n, seed=seed)) - with_dev
                ev.gains[left] = [float(x) for x in gain]
                run_gains[comp.name] = gain
            done += 1
            say(STEP, done, total)
        if on_run is not None:
            on_run(left, res, with_dev, run_gains)
    return result


def take_out(result: CalibrationResult, names: Sequence[str]) -> CalibrationResult:
    """``result`` with the optional effects of the components ``names`` taken out of its scenario
    (``Component.without``, in calibration order), its report's parameters held to the scenario again."""
    scn = result.scenario
    for comp in optional_components(list(names)):
        scn = comp.without(scn, result.report)
    report = result.report
    written = scn.model_dump(mode="json")
    for key, item in report.get("parameters", {}).items():
        is_field, value = written_value(written, key)
        if is_field and not same_number(item["value"], value):
            item.setdefault("fitted", item["value"])
            item["why"] = f"taken out by the component selection ({', '.join(names)}: held-out evidence)"
            item["value"] = value
    return CalibrationResult(scenario=scn, report=report)


def check_selection(select_components: str, evidence_traces: int) -> None:
    """Refuse an unknown ``select_components`` or ``evidence_traces < 1`` (:class:`CalibrationError` naming
    the parameter); checked before anything is read or fitted."""
    if select_components not in SELECT_CHOICES:
        raise CalibrationError(f"select_components: unknown component selection {select_components!r} (choose "
                               f"from {', '.join(SELECT_CHOICES)})")
    if isinstance(evidence_traces, bool) or not isinstance(evidence_traces, (int, np.integer)) or evidence_traces < 1:
        raise CalibrationError(f"evidence_traces: synthetic traces per validation must be an integer of at least 1, "
                               f"got {evidence_traces!r}")


def calibrate_selected(traces: Trace | Sequence[Trace], *, select_components: str = "evidence",
                       evidence_traces: int = DEFAULT_N, evidence_seed: int = DEFAULT_SEED,
                       progress: ProgressCallback | None = None, **options: Any) -> CalibrationResult:
    """:func:`~physynth.calibrate.pipeline.calibrate` with its optional components chosen by
    ``select_components``.

    ``all``: every component as calibrated (exactly :func:`calibrate`). ``evidence``: the held-out evidence
    on the input runs first (:func:`held_out_evidence` with ``n=evidence_traces``, ``seed=evidence_seed``;
    needs at least 2 runs), then the calibration on all runs with the components :data:`DROP_RULE` drops
    taken out (:func:`take_out`). The report's ``components`` section gives each optional component's
    ``held_out`` evidence and whether it is ``selected``; ``component_selection`` the rule, the sizes, the
    deviations as calibrated and the components taken out. ``options``: :func:`calibrate`'s (``name``,
    ``sources``, ``link_budget``, ...).

    Raises
    ------
    CalibrationError
        An unknown ``select_components``, ``evidence_traces < 1``, fewer than 2 runs with ``evidence``.
    """
    check_selection(select_components, evidence_traces)
    if select_components == "all":
        return calibrate(traces, progress=progress, **options)
    trs = as_trace_list(traces)
    if len(trs) < 2:
        raise CalibrationError(f"select_components='evidence' needs at least 2 runs, one left out in turn and "
                               f"the others calibrated (got {len(trs)})")
    fit_options = {k: v for k, v in options.items() if k not in ("name", "sources")}
    evidence = held_out_evidence(trs, n=evidence_traces, seed=evidence_seed, progress=progress, **fit_options)
    res = take_out(calibrate(trs, progress=progress, **options), evidence.dropped)
    section = res.report["components"]
    for name, ev in evidence.components.items():
        section[name]["held_out"] = ev.to_dict()
        section[name]["selected"] = ev.decision != "drop"
    info = evidence.to_dict()
    del info["components"]
    res.report["component_selection"] = {"select_components": select_components, **info,
                                         "taken_out": evidence.dropped}
    return res
