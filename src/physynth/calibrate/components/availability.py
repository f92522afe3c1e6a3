"""Component ``availability``: dropouts and outages per anchor, tag outages and long outages, each
rate with its Gamma posterior."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ...models.availability import AvailabilityOverride, RatePosterior, gamma_rate_posterior
from ...scenario import AvailabilityParams
from .._base import rounded
from ..component import Component
from ..inputs import CalibrationInputs
from ..report import ReportBuilder
from .link_availability import AvailabilityFit
from .timing import TimingFit


@dataclass(frozen=True, slots=True, kw_only=True)
class AvailabilitySet:
    pooled: AvailabilityParams
    per_anchor: dict[str, AvailabilityOverride]

THIN_DATA_EVENTS = 10
"""A rate estimated from fewer events than this is drawn per synthetic trace from its Gamma posterior."""


def _rate_report(rep: ReportBuilder, key: str, post: RatePosterior, burst_rate_hz: float, note: str,
                 se: float | None = None) -> None:
    lo, hi = post.interval_per_s(0.05, 0.95)
    rep.param(key, post.mean_per_s / burst_rate_hz, n=int(round(post.events)), summary=True, se=se,
              interval=[lo / burst_rate_hz, hi / burst_rate_hz],
              note=f"{note}; Gamma posterior mean per burst, 90 % interval (prior Gamma({post.prior_shape:g}, "
                   f"{post.prior_rate_s:g} s)), {post.events:.3g} events in {post.exposure_s:.4g} s")


def _long_outage_params(fit: dict[str, Any], rep: ReportBuilder, *, use: bool) -> dict[str, Any]:
    """The ``long_outage_*`` fields of the pooled availability (:mod:`physynth.calibrate.outage_range`);
    with ``use`` False they are reported and left out of the scenario."""
    if not fit.get("identifiable"):
        if fit:
            rep.not_identifiable.append(f"availability.long_outage_* ({fit.get('why')}; none generated)")
        return {}
    slope = fit["range_slope_per_m"]
    out = {"long_outage_rate_per_s": rounded(fit["rate_per_s"], 8), "long_outage_mean_s": rounded(fit["mean_s"], 5),
           "long_outage_range_slope_per_m": rounded(slope, 5),
           "long_outage_ref_range_m": rounded(fit["ref_range_m"], 3),
           "long_outage_max_range_m": rounded(fit["max_range_m"], 3) if slope else None,
           "long_outage_frailty_shape": (rounded(fit["frailty_shape"], 5) if fit.get("frailty_shape") is not None
                                         else None)}
    note = (f"{fit['n_runs']} runs of >= {fit['min_missed_attempts']} missed attempts; likelihood ratio "
            f"{fit['lr_long']:.3g} against no long outages")
    rep.param("availability.long_outage_rate_per_s", out["long_outage_rate_per_s"], n=fit["n_runs"], summary=True,
              note=note + f"; rate at {out['long_outage_ref_range_m']} m")
    rep.param("availability.long_outage_mean_s", out["long_outage_mean_s"], n=fit["n_runs"], summary=True)
    rep.param("availability.long_outage_range_slope_per_m", out["long_outage_range_slope_per_m"], n=fit["n_runs"],
              summary=True, note=f"likelihood ratio {fit['lr_slope']:.3g} against slope 0"
              + ("" if slope else " (< 10: not kept)"))
    rep.param("availability.long_outage_frailty_shape", out["long_outage_frailty_shape"], n=fit["n_placements"],
              summary=True, note=f"placements (anchor x run); likelihood ratio {fit['lr_frailty']:.3g} against "
                                 "all placements alike" + ("" if out["long_outage_frailty_shape"] else
                                                          " (< 10: not kept)"))
    if not use:
        rep.not_identifiable.append("availability.long_outage_* (fitted and reported; not generated unless "
                                    "long_outages=True)")
        return {}
    return out


def _report_pooled_availability(pooled: AvailabilityParams, n_attempts: int, rep: ReportBuilder, *,
                                in_force: bool) -> None:
    """The pooled dropout and outages in the report: the scenario's values for every anchor without an
    override (``in_force``, in the summary: no anchor has one, as when the anchors were re-placed)."""
    note = "the anchors' values weighted by their attempts"
    rep.param("availability.dropout_prob", pooled.dropout_prob, n=n_attempts, note=note, summary=in_force)
    rep.param("availability.outage_onset_prob", pooled.outage_onset_prob, n=n_attempts, note=note, summary=in_force)
    rep.param("availability.outage_mean_s", pooled.outage_mean_s, n=n_attempts, summary=in_force,
              note="median of the outage means of the anchors with outages")


def assemble_availability(inp: CalibrationInputs, avail: AvailabilityFit, timing: TimingFit,
                          report: ReportBuilder, *, long_outages: bool = False) -> AvailabilitySet:
    """Availability parameters: dropout per anchor, outage and tag-outage rates with Gamma posteriors.

    An outage onset rate is estimated from a handful of events, so it is reported as the posterior of
    a Poisson rate under the prior :data:`physynth.models.availability.RATE_PRIOR_SHAPE` (Jeffreys,
    no prior exposure): Gamma(prior + events, exposure). The scenario gets the posterior mean and,
    when fewer than :data:`THIN_DATA_EVENTS` events back it, the posterior shape, so that each
    synthetic trace draws its own rate (``*_onset_shape``). A process never observed is not generated
    (its interval is still reported). When the anchors were re-placed between the recordings, the
    scenario gets no per-anchor overrides: availability is the placement's, and a new run places them
    anew (leave-one-out on the Hanyang runs: docs/calibration.md).
    """
    ids, av, tag, rep = inp.anchor_ids, avail.per_anchor, avail.tag, report
    burst_rate = timing.burst_rate_hz
    per_anchor: dict[str, AvailabilityOverride] = {}
    for aid in ids:
        do = av[aid]["dropout_outage"]
        pre = f"availability_per_anchor.{aid}"
        if do.get("identifiable"):
            rate_s = do["outage_onset_prob"] * burst_rate
            mean_s = do["outage_mean_s"]
            up_s = do["n_attempts"] * do["attempt_period_s"] * (1.0 / (1.0 + rate_s * mean_s))
            post = gamma_rate_posterior(events=rate_s * up_s, exposure_s=up_s)
            shape = rounded(post.shape, 5) if post.events < THIN_DATA_EVENTS else None
            p = AvailabilityOverride(dropout_prob=rounded(do["dropout_prob"], 5),
                                     outage_onset_prob=rounded(post.mean_per_s / burst_rate, 5),
                                     outage_mean_s=rounded(mean_s, 5), outage_onset_shape=shape)
            _rate_report(rep, f"{pre}.outage_onset_prob", post, burst_rate, "HMM events (rate x up time)",
                         se=do.get("outage_onset_prob_se"))
            rep.param(f"{pre}.outage_mean_s", p.outage_mean_s, se=do.get("outage_mean_s_se"),
                      n=do["n_attempts"], summary=True, note=do.get("why") if do.get("outage_mean_censored") else None)
            if do.get("outage_mean_censored"):
                rep.not_identifiable.append(f"{pre}.outage_mean_s ({do['why']})")
        else:
            p = AvailabilityOverride(dropout_prob=rounded(min(do.get("dropout_prob", 0.0), 1.0), 5),
                                     outage_onset_prob=0.0, outage_mean_s=AvailabilityParams().outage_mean_s)
            rep.not_identifiable.append(f"{pre}.outage_* ({do.get('why', 'not identifiable')}; no outages)")
            rep.param(f"{pre}.outage_onset_prob", 0.0, n=do["n_attempts"], note=do.get("why"))
        rep.param(f"{pre}.dropout_prob", p.dropout_prob, se=do.get("dropout_prob_se"), n=do["n_attempts"],
                  summary=True)
        per_anchor[aid] = p
    attempts = np.array([av[a]["dropout_outage"]["n_attempts"] for a in ids], dtype=float)
    weights = attempts / attempts.sum() if attempts.sum() > 0 else np.full(len(ids), 1.0 / len(ids))
    means = [p.outage_mean_s for p in per_anchor.values() if p.outage_onset_prob > 0]
    # tag outages: n events (the dark runs' tag probabilities summed) over the up bursts of every run
    n_tag = tag.get("events", tag["n_outages"] + tag["n_censored"])
    up_s = tag["effective_up_bursts"] / burst_rate  # outages too short to be told apart are not exposure
    tag_post = gamma_rate_posterior(events=float(n_tag), exposure_s=max(up_s, 1e-9))
    if n_tag:
        tag_onset = rounded(tag_post.mean_per_s / burst_rate, 5)
        tag_shape = rounded(tag_post.shape, 5) if n_tag < THIN_DATA_EVENTS else None
    else:
        tag_onset, tag_shape = 0.0, None
    pooled = AvailabilityParams(
        dropout_prob=rounded(float(np.dot(weights, [p.dropout_prob for p in per_anchor.values()])), 5),
        outage_onset_prob=rounded(float(np.dot(weights, [p.outage_onset_prob for p in per_anchor.values()])), 5),
        outage_mean_s=rounded(float(np.median(means)) if means else AvailabilityParams().outage_mean_s, 5),
        tag_outage_onset_prob=tag_onset,
        tag_outage_mean_s=rounded(tag["mean_s"], 5) if tag.get("mean_s") else AvailabilityParams().tag_outage_mean_s,
        tag_outage_onset_shape=tag_shape,
        **_long_outage_params(avail.long_outages, rep, use=long_outages),
    )
    _report_pooled_availability(pooled, int(attempts.sum()), rep, in_force=bool(inp.layout.get("conflicts")))
    if up_s > 0:
        _rate_report(rep, "availability.tag_outage_onset_prob", tag_post, burst_rate,
                     "tag outages" + ("" if n_tag else " (none seen: not generated)"))
    else:
        rep.param("availability.tag_outage_onset_prob", 0.0, n=0, note="no up time", summary=True)
    if tag.get("mean_s"):
        rep.param("availability.tag_outage_mean_s", pooled.tag_outage_mean_s, n=tag["n_outages"],
                  note="uncensored tag outages")
    if inp.layout.get("conflicts"):  # anchors re-placed between the runs
        rep.not_identifiable.append(
            "availability_per_anchor (the anchors were re-placed between the recordings: an anchor's outages "
            "and dropouts belong to its placement, not to the device, so the scenario takes the values pooled "
            "over anchors and placements; the per-anchor fits are in this report)")
        return AvailabilitySet(pooled=pooled, per_anchor={})
    return AvailabilitySet(pooled=pooled, per_anchor=per_anchor)


COMPONENT = Component(
    name="availability", needs=("link_availability", "timing"),
    data="the per-anchor dropout and outage fits, the tag and long outages, the burst rate",
    fits="availability, availability_per_anchor (dropouts, outages, tag outages, long outages)",
    fit=lambda ctx: assemble_availability(ctx.inputs, ctx.fitted["link_availability"], ctx.fitted["timing"],
                                          ctx.report, long_outages=ctx.options.long_outages))
