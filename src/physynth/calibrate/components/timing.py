"""Component ``timing``: the UWB time offset (grid search), the burst schedule and the late stamps."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ...progress import ProgressCallback
from ...scenario import Scenario
from .._base import Fit, rounded
from ..component import Component
from ..inputs import CalibrationInputs
from ..report import ReportBuilder
from ..uwb_fit import fit_burst_schedule, fit_time_offset


@dataclass(frozen=True, slots=True, kw_only=True)
class TimingFit:
    offset_s: float  # grid-search time offset [s]
    offset_fit: Fit[float]
    burst: Fit[dict[str, float]]

    @property
    def burst_rate_hz(self) -> float:
        return rounded(float(self.burst.params["burst_rate_hz"]), 7)


def fit_timing(inp: CalibrationInputs, report: ReportBuilder, progress: ProgressCallback) -> TimingFit:
    """UWB time offset (robust grid search) and the tag's burst schedule."""
    progress("searching the UWB time offset")
    of = fit_time_offset(inp.traces)
    report.sections["time_offset"] = of.diagnostics
    offset = float(of.params)
    report.param("uwb.time_offset_s", offset, se=of.diagnostics["std_error_s"], n=of.n_samples, summary=True)
    if not of.diagnostics["identifiable"]:
        report.not_identifiable.append("uwb.time_offset_s (residual spread independent of the offset)")
    progress("fitting the burst schedule")
    bf = fit_burst_schedule(inp.traces)
    report.sections["burst_schedule"] = bf.diagnostics
    timing = TimingFit(offset_s=offset, offset_fit=of, burst=bf)
    report.param("uwb.burst_rate_hz", timing.burst_rate_hz, n=bf.n_samples, summary=True)
    report.param("uwb.burst_jitter_s", bf.params["burst_jitter_s"], n=bf.n_samples)
    report.param("uwb.slot_s", bf.params["slot_s"], n=bf.n_samples, note=bf.diagnostics["slot_method"])
    report.param("uwb.burst_phase_s", bf.params["burst_phase_s"], n=bf.n_samples,
                 note=("clock alignment " + ("of the single run" if len(inp.traces) == 1 else "shared by the runs"))
                 if bf.params["burst_phase_s"] is not None
                 else "several runs: drawn per trace")
    late = bf.diagnostics["late_bursts"]
    if late["applied"]:
        report.param("uwb.late_burst_prob", late["prob"], n=late["n_bursts_two_or_more"],
                     note=f"{late['n_late_bursts']} bursts with ranges stamped over {late['min_delay_s'] * 1e3:g} ms "
                          "after their slot")
        report.param("uwb.late_burst_delay_s", late["delay_s"], n=late["n_late_rows"], note="median")
    return timing


def late_burst_params(bf: dict[str, Any]) -> dict[str, float]:
    """The scenario's late-stamp fields (none when calibration kept no late stamps: the defaults)."""
    if not bf["late_burst_prob"]:
        return {}
    return {"late_burst_prob": rounded(bf["late_burst_prob"], 5),
            "late_burst_delay_s": rounded(bf["late_burst_delay_s"], 4)}


def without_late_stamps(scn: Scenario, report: dict[str, Any]) -> Scenario:  # noqa: ARG001
    """``scn`` without late stamps (every burst's ranges stamped in their slot)."""
    return scn.model_copy(update={"uwb": scn.uwb.model_copy(update={"late_burst_prob": 0.0})})


COMPONENT = Component(
    without=without_late_stamps,
    name="timing", data="UWB stamps and ranges against the truth",
    fits="uwb.time_offset_s (grid), uwb.burst_*, uwb.slot_s, uwb.late_burst_*",
    fit=lambda ctx: fit_timing(ctx.inputs, ctx.report, ctx.progress))
