"""Component ``ranging``: per-anchor LOS/NLOS errors pooled over runs, the refined time offset, the
run-to-run lags, offsets and range-law tilts and the tag antenna pattern (and the static sweeps' slope).

The order inside is the fit's: mixtures at the grid offset, the offset refined on their LOS rows, the
runs' own lags, the runs' offsets and tilts and the pattern, then the mixtures again with all of them
removed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from ...records import untrusted_truth
from ...scenario import Scenario
from .._base import CalibrationError
from ..anchor_channels import Channels, fit_channels
from ..component import CalibrationContext, Component
from ..inputs import CalibrationInputs
from ..report import ReportBuilder
from ..run_lag import fit_run_lags, refine_time_offset
from ..uwb_fit import GROSS_RESIDUAL_M, gross_residual_count
from .run_offsets import report_run_slopes, run_offset_table, run_slope_table
from .tag_pattern import tag_pattern_step
from .timing import TimingFit


@dataclass(frozen=True, slots=True, kw_only=True)
class RangingFit:
    offset_s: float  # final time offset [s]
    offset_se_s: float
    channels: Channels
    refinement: dict[str, Any] | None
    fixed_slope: float | None
    run_offset_std_m: float
    run_anchor_offset_std_m: float
    range_bias_law: str = "log"
    offset_std_s: float = 0.0  # run-to-run spread of the lag [s]
    tag_pattern_m: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)  # uwb.tag_pattern_m (zeros: none kept)
    run_slope_std_m: float = 0.0  # run-to-run tilt of the range law [m per decade]
    run_anchor_slope_std_m: float = 0.0
    run_slope_ref_range_m: float = 10.0
    static: dict[str, Any] | None = None  # the static sweeps' range-bias fit, when given

    @property
    def slope_key(self) -> str:
        """The channel field the range term is fitted to."""
        return "range_bias_per_decade_m" if self.range_bias_law == "log" else "range_bias_per_m"


def fit_ranging(inp: CalibrationInputs, timing: TimingFit, *, static: dict[str, Any] | None,
                range_bias: Literal["dynamic", "static"], report: ReportBuilder,
                law: str = "log", tag_pattern: bool = False, run_slopes: bool = False,
                trusted_truth: bool = False) -> RangingFit:
    """Per-anchor LOS/NLOS mixtures pooled over runs, the refined time offset and run-to-run offsets.

    ``law``: how the LOS mean grows with the range (:data:`~physynth.calibrate.uwb_fit.RANGE_BIAS_LAWS`).
    ``tag_pattern``: apply the tag antenna pattern the fit keeps (always fitted and reported).
    ``run_slopes``: remove and generate the run-to-run tilts of the range law (:func:`run_slope_table`;
    always fitted and reported).
    ``trusted_truth``: fit the mixtures on the ranges whose truth the recording trusts
    (``records.TRUTH_UNTRUSTED_KEY``) and take only those as LOS ranging rows (the share is always reported).
    """
    trs, labels, ids = inp.traces, inp.labels, inp.anchor_ids
    report.sections["truth_quality"] = {"trusted_truth": bool(trusted_truth), "untrusted_share_of_truth": {
        lab: float(np.mean(untrusted_truth(t.meta, t.truth.t_s))) for t, lab in zip(trs, labels, strict=True)}}
    if range_bias == "static" and static is None:
        raise CalibrationError("range_bias='static' needs static_sweeps (the Static_measurements folder)")
    key = "range_bias_per_decade_m" if law == "log" else "range_bias_per_m"
    fixed_slope = static[key] if (static is not None and range_bias == "static") else None
    of = timing.offset_fit
    offset = timing.offset_s
    gross = {lab: gross_residual_count(t, offset) for t, lab in zip(trs, labels, strict=True)}
    report.sections["gross_residuals"] = {"per_run": gross, "limits_m": list(GROSS_RESIDUAL_M)}
    if any(gross.values()):
        report.warnings.append(f"{sum(gross.values())} range(s) lie outside {GROSS_RESIDUAL_M[0]:g} .. "
                               f"{GROSS_RESIDUAL_M[1]:g} m of the truth's distance (a radio's error code, a "
                               "corrupt value): left out of every ranging fit")
    chan = fit_channels(trs, offset, ids, fixed_slope, labels, law=law, trusted_truth=trusted_truth)
    ref = refine_time_offset(chan.per_anchor_rows, chan.los_masks(), chan.per_anchor_run, chan.per_anchor_t)
    tsec = report.sections["time_offset"]
    tsec["grid_offset_s"] = offset
    tsec["refinement"] = ref
    refined = bool(of.diagnostics["identifiable"] and ref is not None)
    if refined:
        offset = offset + ref["correction_s"]
        se_off = float(np.hypot(ref["std_error_s"], of.diagnostics["std_error_s"] if len(trs) >= 2 else 0.0))
        tsec["offset_s"] = offset
        tsec["std_error_s"] = se_off
        report.param("uwb.time_offset_s", offset, se=se_off, n=of.n_samples, summary=True,
                     note="grid search on the robust spread, refined by least squares on the LOS rows")
    else:
        se_off = float(of.diagnostics["std_error_s"])
    lags: float | list[float] = offset
    lag_std = 0.0
    spread = fit_run_lags(chan.per_anchor_rows, chan.los_masks(), chan.per_anchor_run, len(trs),
                          t_of_row=chan.per_anchor_t)
    tsec["run_spread"] = _lag_spread_section(spread, labels, timing.offset_s)
    if spread is not None and spread["significant"] and of.diagnostics["identifiable"]:
        # the centre stays the pooled estimate above; each run is taken at it plus its own deviation
        dev = spread["correction_s"] - spread["mean_correction_s"]
        lags = [offset if np.isnan(d) else offset + float(d) for d in dev]
        lag_std = spread["spread_s"]
        tsec["run_spread"]["lags_used_s"] = dict(zip(labels, lags, strict=True))
        report.param("uwb.time_offset_std_s", lag_std, n=len(trs), summary=True,
                     note="run-to-run spread of the lag (DerSimonian-Laird over the runs' own lags)")
        chan = fit_channels(trs, lags, ids, fixed_slope, labels, law=law,  # each run at its own lag
                             trusted_truth=trusted_truth)
    elif len(trs) >= 2:
        report.param("uwb.time_offset_std_s", 0.0, n=len(trs),
                     note="the runs' lags do not differ beyond their errors (Cochran's Q)")
    run_offsets, off_diag = run_offset_table(trs, labels, chan)
    report.sections["run_offsets"] = off_diag
    tilts, slope_diag = run_slope_table(trs, labels, chan, law)
    slope_diag["applied"] = bool(run_slopes and slope_diag["identifiable"] and slope_diag["significant"])
    report.sections["run_slopes"] = slope_diag
    if not slope_diag["applied"]:
        tilts = {}
    pattern = tag_pattern_step(chan, report, apply=tag_pattern)  # each sequence's level and range law projected out
    if refined or run_offsets or tilts or any(pattern):  # again: each run's offsets and tilts, the pattern removed
        chan = fit_channels(trs, lags if lag_std > 0 else offset, ids, fixed_slope, labels,
                             run_offsets=run_offsets, law=law, tag_pattern=pattern, run_slopes=tilts,
                             trusted_truth=trusted_truth)
    if off_diag["identifiable"]:
        s_run, s_anchor = off_diag["run_offset_std_m"], off_diag["run_anchor_offset_std_m"]
        note = "run-to-run spread of the per-run mean LOS residual (two-way random effects)"
        report.param("uwb.run_offset_std_m", s_run, n=off_diag["n_runs"], note=note, summary=True)
        report.param("uwb.run_anchor_offset_std_m", s_anchor, n=off_diag["n_runs"] * off_diag["n_anchors"],
                     note=note, summary=True)
    else:
        s_run = s_anchor = 0.0
        report.not_identifiable.append("uwb.run_offset_std_m, uwb.run_anchor_offset_std_m (one run; 0 kept)")
    slope_std = report_run_slopes(slope_diag, report)
    report.not_identifiable.extend(chan.notes)
    return RangingFit(offset_s=offset, offset_se_s=se_off, channels=chan, refinement=ref, fixed_slope=fixed_slope,
                      run_offset_std_m=s_run, run_anchor_offset_std_m=s_anchor, range_bias_law=law,
                      offset_std_s=lag_std, tag_pattern_m=pattern, **slope_std)


def _lag_spread_section(spread: dict[str, Any] | None, labels: Sequence[str], grid_offset_s: float
                        ) -> dict[str, Any]:
    """The report's ``time_offset.run_spread``: each run's own lag with its standard error, the spread."""
    if spread is None:
        return {"identifiable": False, "why": "fewer than two runs with LOS rows whose range rate changes"}
    w = 1.0 / (spread["std_error_s"] ** 2 + spread["spread_s"] ** 2)
    ok = np.isfinite(w)
    return {"identifiable": True,
            "per_run_s": {lab: (None if np.isnan(d) else grid_offset_s + float(d))
                          for lab, d in zip(labels, spread["correction_s"], strict=True)},
            "per_run_std_error_s": {lab: (None if np.isnan(e) else float(e))
                                    for lab, e in zip(labels, spread["std_error_s"], strict=True)},
            "spread_s": spread["spread_s"], "mean_s": grid_offset_s + spread["mean_correction_s"],
            "mean_std_error_s": float(1.0 / np.sqrt(np.sum(w[ok]))),
            "cochran_q": spread["q"], "dof": spread["dof"], "p_value": spread["p_value"],
            "significant": spread["significant"], "variance_inflation": spread.get("variance_inflation"),
            "variance_dof": spread.get("variance_dof"),
            "method": ("per-run lag corrections regressed on -range rate over the LOS rows ((run, anchor) means "
                       "and per-anchor range terms removed); each run's error from a delete-one-block jackknife "
                       "over blocks in time, its ratio to the independent-rows error pooled over the runs; "
                       "DerSimonian-Laird spread, Cochran's Q against an F distribution at 1 %")}


def _fit(ctx: CalibrationContext) -> RangingFit:
    o = ctx.options
    static = None
    if o.static_sweeps is not None:
        from ..static_bias import fit_static_range_bias

        static = fit_static_range_bias(o.static_sweeps)
        ctx.report.sections["static_range_bias"] = static
    ranging = fit_ranging(ctx.inputs, ctx.fitted["timing"], static=static, range_bias=o.range_bias, report=ctx.report,
                          law=o.range_bias_law, tag_pattern=o.tag_pattern, run_slopes=o.run_slopes,
                          trusted_truth=o.trusted_truth)
    return replace(ranging, static=static)


RUN_TO_RUN_FIELDS = ("time_offset_std_s", "run_offset_std_m", "run_anchor_offset_std_m", "run_slope_std_m",
                     "run_anchor_slope_std_m")
"""The run-to-run spreads the ranging component fits: the lag, the ranging offsets and the range-law tilts."""


def without_run_to_run(scn: Scenario, report: dict[str, Any]) -> Scenario:  # noqa: ARG001
    """``scn`` with every run alike: no run-to-run spread of the lag, the ranging offsets or the tilts."""
    return scn.model_copy(update={"uwb": scn.uwb.model_copy(update=dict.fromkeys(RUN_TO_RUN_FIELDS, 0.0))})


COMPONENT = Component(
    without=without_run_to_run,
    name="ranging", needs=("timing",), step="fitting LOS/NLOS ranging errors per anchor", fit=_fit,
    data="UWB ranges against the truth's distance, per anchor and run (and the static sweeps when given)",
    fits=("channel_per_anchor LOS/NLOS errors, uwb.time_offset_s (refined), uwb.time_offset_std_s, "
          "uwb.run_*offset_std_m, uwb.run_*slope_std_m, uwb.tag_pattern_m, static.*"))
