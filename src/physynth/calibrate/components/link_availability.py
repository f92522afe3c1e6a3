"""Component ``link_availability``: link range, attempt rate, dropouts, outages per anchor, tag outages
and long outages as fitted (:func:`physynth.calibrate.availability_fit.fit_availability`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..availability_fit import fit_availability
from ..component import Component
from ..inputs import CalibrationInputs
from ..report import ReportBuilder
from .ranging import RangingFit
from .timing import TimingFit


@dataclass(frozen=True, slots=True, kw_only=True)
class AvailabilityFit:
    per_anchor: dict[str, dict[str, Any]]
    tag: dict[str, Any]
    long_outages: dict[str, Any] = field(default_factory=dict)


def fit_link_availability(inp: CalibrationInputs, ranging: RangingFit, timing: TimingFit,
                          report: ReportBuilder) -> AvailabilityFit:
    """Link range, attempt rate, dropout and outages per anchor, and tag outages, pooled over runs."""
    af = fit_availability(inp.traces, ranging.offset_s, timing.burst_rate_hz, inp.anchor_ids)
    av, tag, long_ = af.params["per_anchor"], af.params["tag"], af.params["long_outages"]
    report.sections["availability"] = {"per_anchor": av, "tag_outages": tag, "long_outages": long_,
                                       **af.diagnostics}
    return AvailabilityFit(per_anchor=av, tag=tag, long_outages=long_)


COMPONENT = Component(
    name="link_availability", needs=("ranging", "timing"), step="fitting availability (link range, dropouts, outages)",
    data="every ranging attempt (recorded or inferred from the burst schedule) with its true range",
    fits="per-anchor link range, attempt rate, dropout and outage fits; tag and long outages (assembled later)",
    fit=lambda ctx: fit_link_availability(ctx.inputs, ctx.fitted["ranging"], ctx.fitted["timing"], ctx.report))
