"""The whole calibration: traces (or dataset directories) -> a Scenario and a JSON fit report.

:func:`calibrate` checks the recordings (:func:`~physynth.calibrate.inputs.prepare_inputs` ->
:class:`~physynth.calibrate.inputs.CalibrationInputs`), then fits the components of
:data:`COMPONENTS` in dependency order (:class:`~physynth.calibrate.component.Component`: each one
physical effect or part of the scenario, a module of :mod:`physynth.calibrate.components`, reading the
results of the components before it), and composes the scenario from their results
(:func:`build_scenario`).

Every component writes what it fitted into one :class:`~physynth.calibrate.report.ReportBuilder`:
every parameter with its standard error or the number of samples behind it, the diagnostics that
support it and the list of what could not be identified; the report's ``components`` section says,
per component, whether it was fitted. At the end the report's parameters are held to the scenario as
written (:func:`~physynth.calibrate.report_fields.reconcile_parameters`: a field's value is the one
written, the fit's own number beside it where they differ) and the options that changed nothing are
noted. The scenario is in the generator's own format, so it feeds ``physynth generate``.

A new component: a module in ``components/`` with a ``COMPONENT`` and one line in :data:`COMPONENTS`
(docs/design.md, "Adding a calibration component").
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

from .. import __version__
from ..progress import ProgressCallback, no_progress
from ..records import Trace
from ..scenario import ChannelOverride, ImuParams, Scenario, UwbParams
from ._base import CalibrationError, as_trace_list, jsonable, rounded
from .component import CalibrationContext, CalibrationOptions, Component, check_order, run_components
from .components import (
    antenna_sway,
    availability,
    channels,
    geometry,
    imu,
    link_availability,
    link_budget,
    nlos_episodes,
    ranging,
    tag_nlos,
    timing,
)
from .components.antenna_sway import sway_params
from .components.availability import AvailabilitySet
from .components.channels import ChannelSet
from .components.geometry import GeometryFit
from .components.ranging import RangingFit
from .components.timing import TimingFit, late_burst_params
from .geometry import AnchorPolicy, PathKind
from .inputs import CalibrationInputs, is_imu_only, prepare_inputs
from .report import CalibrationResult, ReportBuilder
from .report_fields import reconcile_parameters, unused_option_notes
from .uwb_fit import RANGE_BIAS_LAWS

COMPONENTS: tuple[Component, ...] = (
    geometry.COMPONENT,  # path, run-to-run deformation, motion, jitter
    timing.COMPONENT,  # UWB time offset (grid), burst schedule, late stamps
    ranging.COMPONENT,  # LOS/NLOS mixtures, refined offset, run lags, run offsets and tilts, tag pattern
    link_availability.COMPONENT,  # link range, dropouts, outages as fitted
    nlos_episodes.COMPONENT,  # NLOS episode lengths per mode
    antenna_sway.COMPONENT,  # slow ranging error common to the anchors
    tag_nlos.COMPONENT,  # tag-side NLOS
    channels.COMPONENT,  # per-anchor and pooled channels
    availability.COMPONENT,  # dropouts, outages, tag and long outages with their posteriors
    link_budget.COMPONENT,  # link budget (link_budget=True with static sweeps)
    imu.COMPONENT,  # IMU noise
)
"""The calibration's components in dependency order (each needs only components before it)."""
check_order(COMPONENTS)


def build_scenario(name: str, inp: CalibrationInputs, geometry: GeometryFit, timing: TimingFit,
                   ranging: RangingFit, channels: ChannelSet, availability: AvailabilitySet, imu: ImuParams,
                   *, sources: Sequence[str], created_utc: str, report: ReportBuilder) -> Scenario:
    """The calibrated scenario, composed from the fitted parameter objects (the components' results)."""
    bf = timing.burst.params
    phase = bf["burst_phase_s"]
    uwb = UwbParams(burst_rate_hz=timing.burst_rate_hz, burst_jitter_s=rounded(bf["burst_jitter_s"], 4),
                    burst_phase_s=None if phase is None else rounded(phase, 5),
                    slot_s=rounded(bf["slot_s"], 5), time_offset_s=rounded(ranging.offset_s, 5),
                    time_offset_std_s=rounded(ranging.offset_std_s, 5),
                    nlos_dwell_s=rounded(channels.nlos_dwell_s, 4), zones=[],
                    run_offset_std_m=rounded(ranging.run_offset_std_m, 4),
                    run_anchor_offset_std_m=rounded(ranging.run_anchor_offset_std_m, 4),
                    run_slope_std_m=rounded(ranging.run_slope_std_m, 4),
                    run_anchor_slope_std_m=rounded(ranging.run_anchor_slope_std_m, 4),
                    run_slope_ref_range_m=rounded(ranging.run_slope_ref_range_m, 3),
                    **sway_params(channels.sway), tag_pattern_m=list(ranging.tag_pattern_m),
                    tag_nlos_prob=rounded(channels.tag_nlos["prob"], 4) if channels.tag_nlos["applied"] else 0.0,
                    **late_burst_params(bf))
    report.not_identifiable.append("uwb.zones (NLOS zones along the path are not fitted)")
    provenance = {
        "calibrated_by": f"physynth {__version__}",
        "created_utc": created_utc,
        "datasets": list(sources),
        "recordings": inp.labels,
        "imu_only_recordings": inp.imu_only_labels,
        "command": "physynth calibrate",
    }
    if len(inp.layout["layouts"]) > 1:
        provenance["anchor_layout"] = {"policy": inp.layout["policy"],
                                       "generation_layout": inp.layout["generation_layout"],
                                       "layouts": inp.layout["layouts"]}
    return Scenario(
        name=name,
        description=(f"Calibrated by physynth {__version__} on {len(inp.traces)} recording(s): "
                     + ", ".join(inp.labels)),
        path=geometry.path,
        motion=geometry.motion,
        imu=imu,
        uwb=uwb,
        anchors=inp.anchors,
        channel=channels.pooled,
        channel_per_anchor={a: ChannelOverride(**dict(c)) for a, c in channels.per_anchor.items()},
        availability=availability.pooled,
        availability_per_anchor=availability.per_anchor,
        provenance=jsonable(provenance),
    )


# ---------------------------------------------------------------- the whole calibration
N_STEPS = 8


def _check_options(static_sweeps: str | os.PathLike | None, range_bias: str, range_bias_law: str,
                   link_budget: bool) -> None:
    """The option mistakes :func:`calibrate` refuses before any fitting."""
    if link_budget and static_sweeps is None:
        raise CalibrationError("link_budget=True needs static_sweeps (the Static_measurements folder)")
    if range_bias == "static" and static_sweeps is None:
        raise CalibrationError("range_bias='static' needs static_sweeps (the Static_measurements folder)")
    if range_bias_law not in RANGE_BIAS_LAWS:
        raise CalibrationError(f"unknown range-bias law {range_bias_law!r} (choose from {', '.join(RANGE_BIAS_LAWS)})")
    if static_sweeps is not None and not Path(static_sweeps).is_dir():
        raise CalibrationError(f"static sweeps folder {static_sweeps} does not exist")


def calibrate(traces: Trace | Sequence[Trace], *, name: str = "calibrated", path_kind: PathKind = "auto",
              anchor_policy: AnchorPolicy = "per-run", layout_from: int | str | None = None,
              static_sweeps: str | os.PathLike | None = None, range_bias: Literal["dynamic", "static"] = "dynamic",
              range_bias_law: Literal["log", "linear"] = "log",
              sources: Sequence[str] | None = None, long_outages: bool = False, tag_pattern: bool = False,
              run_slopes: bool = False, link_budget: bool = False, trusted_truth: bool = False,
              progress: ProgressCallback | None = None) -> CalibrationResult:
    """Calibrate a scenario on one or several recordings (real or synthetic Traces).

    Parameters
    ----------
    traces
        Recordings with ground truth and UWB rows (and optionally IMU samples), pooled.
    path_kind
        ``auto`` (polynomial for a cable-like path, else waypoints), ``polynomial`` or ``waypoints``.
    anchor_policy
        ``per-run`` (default): runs may place the anchors differently (each run's residuals against
        its own layout; channel parameters per anchor id pooled over the runs; the run-to-run ranging
        offsets become ``uwb.run_offset_std_m`` / ``uwb.run_anchor_offset_std_m``); the scenario
        generates with the layout of ``layout_from`` and records the others in its provenance.
        ``strict``: an anchor id placed differently by two recordings is an error. ``first``: the
        same as ``per-run`` without ``layout_from`` (the first recording's layout, each anchor it lacks
        at its first position elsewhere); every policy fits each run against its own layout.
    layout_from
        Index or label of the recording whose anchor layout the scenario generates with (``per-run``).
    static_sweeps
        Optional Hanyang ``Static_measurements`` folder: the range-proportional bias is also fitted on
        the static sweeps (reported), and used for every anchor when ``range_bias="static"``.
    range_bias_law
        How the LOS mean error grows with the true range r: ``log`` (default), gamma log10(r / 1 m),
        the received-power bias (``channel.range_bias_per_decade_m``); ``linear``, beta r, a clock-scale
        error (``channel.range_bias_per_m``, the former model).
    sources
        Names of the datasets the traces came from (provenance).
    long_outages
        Generate the long outages (``availability.long_outage_*``) the fit identifies (always fitted and
        reported); off by default: on the shared Hanyang runs they belong to one anchor placement and
        worsen the leave-one-out age of information (docs/calibration.md, "Long outages").
    tag_pattern
        Generate the tag antenna pattern (``uwb.tag_pattern_m``) when the fit keeps it, and fit the
        channels to the residuals with it removed. It is always fitted and reported; off by default
        because on the shared Hanyang walks (all along one route) applying it worsened the left-out
        runs' KS and the tracking study (docs/calibration.md, "Where the anchors lie from the walker").
    run_slopes
        Generate the run-to-run tilts of the range law (``uwb.run_slope_std_m``, ``uwb.run_anchor_slope_std_m``;
        several runs) the fit finds, and fit the channels with each run's tilt removed (always fitted and
        reported); off by default: on the shared Hanyang walks it made one left-out run's KS and the
        tracking study worse (docs/calibration.md, "Run-to-run tilts of the range law").
    link_budget
        Give every anchor a link budget (needs ``static_sweeps``; ``link_budget.link_budget_for_runs``), the
        dropouts lowered by its mean loss. Off by default (docs/calibration.md, "Fades from the anchor's height").
    trusted_truth
        Fit the ranging channel on the ranges whose truth the recording trusts (outside its
        ``truth_untrusted_s`` spans). Off by default (docs/calibration.md, "Where the truth itself errs").
    progress
        ``progress(message, done, total)`` before each step (:mod:`physynth.progress`).
    """
    _check_options(static_sweeps, range_bias, range_bias_law, link_budget)
    options = {"anchor_policy": anchor_policy, "layout_from": layout_from, "static_sweeps": static_sweeps,
               "range_bias": range_bias, "range_bias_law": range_bias_law, "long_outages": long_outages,
               "tag_pattern": tag_pattern, "run_slopes": run_slopes, "link_budget": link_budget,
               "trusted_truth": trusted_truth}
    trs = as_trace_list(traces)
    if trs and all(is_imu_only(t) for t in trs):  # IMU recordings only: IMU models, path and motion, no anchors
        from .imu_only import calibrate_imu_only

        res = calibrate_imu_only(trs, name=name, path_kind=path_kind, sources=sources, progress=progress)
        return _held_to_scenario(res, unused_option_notes(options, uwb=False, n_runs=0, untrusted_truth=False))
    res = _calibrate_uwb(trs, name=name, sources=sources, progress=progress, path_kind=path_kind,
                         **options)
    shares = res.report["truth_quality"]["untrusted_share_of_truth"].values()
    return _held_to_scenario(res, unused_option_notes(options, uwb=True, n_runs=len(res.report["recordings"]),
                                                      untrusted_truth=any(x > 0 for x in shares)))


def _held_to_scenario(res: CalibrationResult, notes: Sequence[str]) -> CalibrationResult:
    """``res`` with its report's parameters held to the scenario written
    (:func:`~physynth.calibrate.report_fields.reconcile_parameters`) and ``notes`` among its warnings."""
    reconcile_parameters(res.report, res.scenario.model_dump(mode="json"))
    if notes:
        res.report.setdefault("warnings", []).extend(notes)
    return res


def _calibrate_uwb(trs: list[Trace], *, name: str, sources: Sequence[str] | None, progress: ProgressCallback | None,
                   **options: Any) -> CalibrationResult:
    """:func:`calibrate`'s components on recordings of which some have UWB ranges (its report as fitted)."""
    say = progress or no_progress
    step = iter(range(N_STEPS))

    def tick(message: str, *_: Any) -> None:
        say(message, next(step, N_STEPS - 1), N_STEPS)

    opts = CalibrationOptions(**options)
    rep = ReportBuilder()
    tick("checking the recordings")
    inp = prepare_inputs(trs, anchor_policy=opts.anchor_policy, layout_from=opts.layout_from, report=rep)
    rep.sections["sources"] = list(sources or [])
    ctx = CalibrationContext(inputs=inp, options=opts, report=rep, progress=tick)
    components = run_components(COMPONENTS, ctx)
    f = ctx.fitted
    channels, availability = f["channels"], f["availability"]
    if "link_budget" in f:
        channels, availability = f["link_budget"].channels, f["link_budget"].availability
    scn = build_scenario(name, inp, f["geometry"], f["timing"], f["ranging"], channels, availability, f["imu"],
                         sources=list(sources or []), created_utc=rep.sections["created_utc"], report=rep)
    rep.sections["components"] = components
    return CalibrationResult(scenario=scn, report=rep.to_dict())
