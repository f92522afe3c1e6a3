"""Component ``link_budget`` (``link_budget=True`` with static sweeps): every anchor's link budget, the
dropouts lowered by the losses it now makes (:mod:`physynth.calibrate.link_budget`)."""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import Any

from ...models.availability import AvailabilityOverride
from ...scenario import Scenario, scenario_from_dict
from .._base import rounded
from ..component import CalibrationContext, Component
from ..inputs import CalibrationInputs
from ..report import ReportBuilder
from .availability import AvailabilitySet
from .channels import ChannelSet


def with_link_budget(inp: CalibrationInputs, channels: ChannelSet, static_sweeps: str | os.PathLike,
                      rep: ReportBuilder) -> ChannelSet:
    """``channels`` with the link budget of :func:`link_budget_for_runs` on every anchor (unchanged, and
    said so, when the recordings' losses do not follow the predicted power)."""
    from ..link_budget import link_budget_for_runs

    params, mean_det, lb_rep = link_budget_for_runs(inp.traces, static_sweeps)
    rep.sections["link_budget"] = {**lb_rep, "applied": params is not None}
    if params is None:
        rep.not_identifiable.append("channel.link_budget (the recordings' losses do not follow the power "
                                    "the static sweeps predict)")
        return channels
    det = lb_rep["detection"]
    rep.param("channel.link_budget.sensitivity_dbm", params.sensitivity_dbm, n=det["n_attempts"],
              note=f"losses along the truth, likelihood ratio {det['likelihood_ratio']:.1f}")
    rep.param("channel.link_budget.shadowing_std_db", params.shadowing_std_db, n=det["n_attempts"])
    rep.param("channel.link_budget.tag_height_m", params.tag_height_m, n=lb_rep["static"]["n_positions"],
              note="from the static sweeps' ground nulls")
    per = {aid: c.model_copy(update={"link_budget": params}) for aid, c in channels.per_anchor.items()}
    return replace(channels, pooled=channels.pooled.model_copy(update={"link_budget": params}), per_anchor=per)


def link_losses_out_of_dropouts(availability: AvailabilitySet, rep: ReportBuilder) -> AvailabilitySet:
    """The per-attempt dropout probabilities with the losses the link budget now makes taken out: the
    dropouts were fitted on all losses, the budget's among them, and the two must not count them twice.
    Per anchor, with m its mean detection under the budget over the recordings' bursts,
    (1 - d') = (1 - d) / m, at least 0; what a dropout probability of 0 cannot take out, (1 - d) - m,
    is reported (``link_loss_not_compensated``, a probability per attempt)."""
    lb = rep.sections.get("link_budget", {})
    mean_det = lb.get("mean_detection_per_anchor")
    if not lb.get("applied") or not mean_det:
        return availability
    pooled_d = availability.pooled.dropout_prob
    per = dict(availability.per_anchor)
    before, left = {}, {}
    for aid, m in mean_det.items():
        o = per.get(aid, AvailabilityOverride())
        d = pooled_d if o.dropout_prob is None else o.dropout_prob
        d_new = max(0.0, 1.0 - (1.0 - d) / max(m, 1e-6))
        before[aid], left[aid] = d, max(0.0, (1.0 - d) - (1.0 - d_new) * m)  # survival lost beyond d
        per[aid] = o.model_copy(update={"dropout_prob": rounded(d_new, 6)})  # the report: reconcile_parameters
    lb["dropout_prob_before"], lb["link_loss_not_compensated"] = before, left
    return replace(availability, per_anchor=per)


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkBudgetFit:
    """The channels and availability with the link budget applied."""

    channels: ChannelSet
    availability: AvailabilitySet


def _fit(ctx: CalibrationContext) -> LinkBudgetFit:
    channels = with_link_budget(ctx.inputs, ctx.fitted["channels"], ctx.options.static_sweeps, ctx.report)
    return LinkBudgetFit(channels=channels, availability=link_losses_out_of_dropouts(ctx.fitted["availability"],
                                                                                     ctx.report))


def _off(ctx: CalibrationContext) -> str | None:
    if not ctx.options.link_budget:
        return "link_budget=False"
    return None if ctx.options.static_sweeps is not None else "no static sweeps"


def without_link_budget(scn: Scenario, report: dict[str, Any]) -> Scenario:
    """``scn`` without the link budget, every anchor's dropout probability as fitted before it."""
    lb = report.get("link_budget", {})
    if not lb.get("applied"):
        return scn
    d = scn.model_dump(mode="json")
    d["channel"]["link_budget"] = None
    for over in d["channel_per_anchor"].values():
        over.pop("link_budget", None)
    for aid, p in (lb.get("dropout_prob_before") or {}).items():
        if aid in d["availability_per_anchor"]:
            d["availability_per_anchor"][aid]["dropout_prob"] = p
    return scenario_from_dict(d, "without the link budget")


COMPONENT = Component(
    without=without_link_budget,
    name="link_budget", needs=("channels", "availability"), fit=_fit, off=_off,
    data="the static sweeps (received power, detection against distance) and the recordings' losses",
    fits="channel.link_budget (every anchor), availability dropouts without its losses")
