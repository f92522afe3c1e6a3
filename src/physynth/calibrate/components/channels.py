"""Component ``channels``: every anchor's channel (LOS error, NLOS modes with their episodes, rate, link
range) and the channel pooled over anchors, from the components before it."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...scenario import ChannelParams, NlosMode
from .._base import rounded
from ..anchor_channels import Channels
from ..component import CalibrationContext, Component
from ..inputs import CalibrationInputs
from ..report import ReportBuilder
from ..uwb_fit import MixtureFit
from .link_availability import AvailabilityFit
from .nlos_episodes import NlosEpisodes, anchor_nlos_modes, nlos_run_lengths
from .ranging import RangingFit
from .timing import TimingFit


@dataclass(frozen=True, slots=True, kw_only=True)
class ChannelSet:
    pooled: ChannelParams
    per_anchor: dict[str, ChannelParams]
    nlos_dwell_s: float
    sway: dict[str, Any] = field(default_factory=lambda: {"identifiable": False})
    tag_nlos: dict[str, Any] = field(default_factory=lambda: {"identifiable": False})

MIN_WHITE_SHARE = 0.01
"""Smallest share of an anchor's LOS error variance left white (per attempt) when the antenna sway is fitted."""


def _anchor_link_range(aid: str, link: dict[str, Any], rep: ReportBuilder) -> tuple[float, float]:
    """(max range, edge width) of an anchor's link; above the largest range seen when not identifiable."""
    seen = link.get("max_range_seen_m") or 0.0
    if link.get("identifiable"):
        max_range, edge = link["max_range_m"], link["edge_width_m"]
    else:
        max_range, edge = 2.0 * seen + 10.0, 5.0
        rep.not_identifiable.append(f"channel_per_anchor.{aid}.max_range_m ({link.get('why', 'not identifiable')}; "
                                    f"set to {max_range:.0f} m, above the largest range {seen:.1f} m)")
    return max_range, edge


def _anchor_std_errors(aid: str, f: MixtureFit, ranging: RangingFit, n_rows: int, period_s: float,
                       anchor_dwell: float | None, nlos_dwell: float) -> dict[str, Any]:
    """An anchor's standard errors, widened by the time-offset uncertainty and by NLOS episodes."""
    se = dict(f.se)
    sens = ((ranging.refinement or {}).get("sensitivity") or {}).get(aid)
    se_off = ranging.offset_se_s
    if sens:  # the LOS mean and slope move with the time offset: add its uncertainty
        se["los_mean_m"] = float(np.hypot(se["los_mean_m"], sens["d_los_mean_per_s"] * se_off))
        d_slope = sens["d_range_bias_per_decade_per_s" if ranging.range_bias_law == "log" else "d_range_bias_per_s"]
        se[ranging.slope_key] = float(np.hypot(se[ranging.slope_key], d_slope * se_off))
        se["includes_time_offset_uncertainty"] = True
    if f.nlos_prob > 0:
        # NLOS comes in episodes: Var(p) ~ 2 p (1 - p) tau_c / T_obs with tau_c = dwell (1 - p)
        t_obs = n_rows * period_s
        tau = (anchor_dwell or nlos_dwell) * (1.0 - f.nlos_prob)
        se["nlos_prob"] = float(max(se["nlos_prob"],
                                    np.sqrt(2.0 * f.nlos_prob * (1.0 - f.nlos_prob) * tau / max(t_obs, 1e-9))))
        se["nlos_prob_method"] = "episodes: sqrt(2 p (1-p) dwell (1-p) / T_obs), at least the binomial SE"
    return se


def _report_anchor_channel(aid: str, f: MixtureFit, se: dict[str, Any], n_a: int, a_av: dict[str, Any],
                           rate: float, max_range: float, chan: Channels, ranging: RangingFit,
                           rep: ReportBuilder) -> None:
    """An anchor's channel in the report: what was not identifiable, modes below the LOS mean, parameters."""
    link = a_av["link"]
    if not f.modes:
        rep.not_identifiable.append(f"channel_per_anchor.{aid}.nlos_modes (no NLOS rows; nlos_prob = 0, "
                                    "default mode kept)")
    centre = float(f.los_centre(float(np.median(chan.per_anchor_rows.get(aid, ([1.0],) * 3)[1]))))
    negative = [m.mean_m for m in f.modes if m.mean_m < centre]
    if negative:
        rep.warnings.append(
            f"{aid}: {len(negative)} NLOS mode(s) below the LOS mean (means "
            f"{', '.join(f'{m:.2f}' for m in negative)} m): ranges shorter than the truth are not radio NLOS "
            "(that lengthens ranges) but truth errors or ranging outliers; the mixture reproduces them")
    pre = f"channel_per_anchor.{aid}"
    rep.param(f"{pre}.los_mean_m", f.los_mean_m, se=se["los_mean_m"], n=n_a, summary=True)
    rep.param(f"{pre}.los_std_m", f.los_std_m, se=se["los_std_m"], n=n_a, summary=True)
    key = ranging.slope_key
    rep.param(f"{pre}.{key}", getattr(f, key), se=se[key], n=n_a,
              note="fixed to the static-sweep slope" if ranging.fixed_slope is not None else None)
    rep.param(f"{pre}.nlos_prob", f.nlos_prob, se=se["nlos_prob"], n=n_a, summary=True)
    rep.param(f"{pre}.nlos_modes", [[m.weight, m.mean_m, m.std_m] for m in f.modes], se=f.se.get("mode_mean_m"),
              n=n_a, note="(weight, mean_m, std_m); std error of the means")
    rep.param(f"{pre}.rate_hz", rate, n=a_av["attempts"],
              note="recorded attempts" if a_av["attempts_recorded"] else "one attempt per burst (inferred)")
    rep.param(f"{pre}.max_range_m", max_range, n=link.get("n_attempts"),
              note=None if link.get("identifiable") else "not identifiable")


def _pooled_channel(pooled_fit: MixtureFit, per_channel: dict[str, ChannelParams], ids: Sequence[str],
                    burst_rate: float, white: float = 1.0) -> ChannelParams:
    """The channel pooled over anchors (the mean rate, the largest link range, the median edge);
    ``white``: the share of the LOS std left white by the antenna sway."""
    pooled_rate = float(np.mean([per_channel[a].rate_hz for a in ids]))
    pooled_modes = ([NlosMode(weight=rounded(m.weight, 4), mean_m=rounded(m.mean_m, 5), std_m=rounded(m.std_m, 4))
                     for m in pooled_fit.modes] or ChannelParams().nlos_modes)
    return ChannelParams(rate_hz=min(rounded(pooled_rate, 6), burst_rate),
                         los_mean_m=rounded(pooled_fit.los_mean_m, 5),
                         los_std_m=rounded(pooled_fit.los_std_m * white, 5),
                         range_bias_per_m=rounded(pooled_fit.range_bias_per_m, 5),
                         range_bias_per_decade_m=rounded(pooled_fit.range_bias_per_decade_m, 5),
                         nlos_prob=rounded(pooled_fit.nlos_prob, 5), nlos_modes=pooled_modes,
                         max_range_m=rounded(max(c.max_range_m for c in per_channel.values()), 5),
                         edge_width_m=rounded(float(np.median([c.edge_width_m for c in per_channel.values()])), 4))


def report_static_bias(static: dict[str, Any], ranging: RangingFit, rep: ReportBuilder) -> None:
    """The static sweeps' range-bias slopes in the report (both laws; the fitted law's in the summary)."""
    for key in ("range_bias_per_m", "range_bias_per_decade_m"):
        rep.param(f"static.{key}", static[key], se=static["std_errors"][key], n=static["n_rows"],
                  note=f"static sweeps ({static['environment']}), {static['n_files']} files, rms "
                       f"{static['residual_std_per_law_m'][key]:.4f} m about the per-file medians",
                  summary=key == ranging.slope_key)


def assemble_channels(inp: CalibrationInputs, ranging: RangingFit, avail: AvailabilityFit, timing: TimingFit,
                      report: ReportBuilder, *, episodes: NlosEpisodes, sway: dict[str, Any],
                      tag: dict[str, Any]) -> ChannelSet:
    """Per-anchor channel parameters (LOS, NLOS modes with their episode lengths, rate, link range) from
    the mixtures (``ranging``), the NLOS ``episodes``, the antenna ``sway`` and the tag NLOS ``tag``."""
    ids, chan, av, rep = inp.anchor_ids, ranging.channels, avail.per_anchor, report
    burst_rate = timing.burst_rate_hz
    mix, mix_diag, flags = chan.mix, chan.mix_diag, chan.flags
    periods, per_anchor_dwell, nlos_dwell = episodes.periods_s, episodes.per_anchor_dwell_s, episodes.nlos_dwell_s
    all_runs, dwell, episodes_of, short_pool = episodes.all_runs, episodes.dwell_s, episodes.episodes_of, \
        episodes.short_pool
    # the share of the LOS variance left white: never 0 (each attempt has its own timing noise; a sway fit on
    # few rows can take the whole variance, which left a LOS std of 0)
    white = float(np.sqrt(max(1.0 - sway["slow_share"], MIN_WHITE_SHARE))) if sway["identifiable"] else 1.0
    channel_diag: dict[str, Any] = {}
    per_channel: dict[str, ChannelParams] = {}
    for aid in ids:
        f = mix[aid]
        a_av = av[aid]
        rate = min(a_av["attempt_prob"] * burst_rate, burst_rate)
        max_range, edge = _anchor_link_range(aid, a_av["link"], rep)
        mode_eps = episodes_of[aid]
        modes, shapes, hmm_dwell = anchor_nlos_modes(chan, aid, f, mode_eps, short_pool, periods[aid], burst_rate,
                                                     nlos_dwell)
        per_channel[aid] = ChannelParams(
            rate_hz=min(rounded(rate, 6), burst_rate), los_mean_m=rounded(f.los_mean_m, 5),
            los_std_m=rounded(f.los_std_m * white, 5),
            range_bias_per_m=rounded(f.range_bias_per_m, 5),
            range_bias_per_decade_m=rounded(f.range_bias_per_decade_m, 5), nlos_prob=rounded(f.nlos_prob, 5),
            nlos_modes=modes,
            max_range_m=rounded(max_range, 5), edge_width_m=rounded(edge, 4))
        se = _anchor_std_errors(aid, f, ranging, mix_diag[aid]["n"], periods[aid], per_anchor_dwell[aid], nlos_dwell)
        channel_diag[aid] = {**mix_diag[aid], "std_errors": se,
                             "nlos_mode_dwell_hmm": hmm_dwell, "nlos_dwell_s": per_anchor_dwell[aid],
                             "nlos_mode_episodes": [int(e.lengths.size) for e in mode_eps],
                             "nlos_mode_dwell_s": [sh["dwell_s"] for sh in shapes],
                             "nlos_mode_episode_shape": shapes,
                             "n_nlos_episodes": int(nlos_run_lengths(flags[aid]).size)}
        _report_anchor_channel(aid, f, se, mix_diag[aid]["n"], a_av, rate, max_range, chan, ranging, rep)
    pooled_fit = chan.pooled_fit
    pooled = _pooled_channel(pooled_fit, per_channel, ids, burst_rate, white)
    rep.sections["channel"] = {"pooled": {"n": int(chan.pooled_r.size), **chan.pooled_sel,
                                          "std_errors": pooled_fit.se},
                               "per_anchor": channel_diag}
    if dwell is None:
        rep.not_identifiable.append("uwb.nlos_dwell_s (no NLOS episodes; default kept)")
    rep.param("uwb.nlos_dwell_s", nlos_dwell, n=int(all_runs.size), note="number of NLOS episodes")
    return ChannelSet(pooled=pooled, per_anchor=per_channel, nlos_dwell_s=nlos_dwell, sway=sway, tag_nlos=tag)


def _fit(ctx: CalibrationContext) -> ChannelSet:
    f = ctx.fitted
    channels = assemble_channels(ctx.inputs, f["ranging"], f["link_availability"], f["timing"], ctx.report,
                                 episodes=f["nlos_episodes"], sway=f["antenna_sway"], tag=f["tag_nlos"])
    if f["ranging"].static is not None:
        report_static_bias(f["ranging"].static, f["ranging"], ctx.report)
    return channels


COMPONENT = Component(
    name="channels", needs=("ranging", "link_availability", "timing", "nlos_episodes", "antenna_sway", "tag_nlos"),
    data="the per-anchor mixtures, link fits, NLOS episodes, sway and tag NLOS",
    fits="channel, channel_per_anchor (LOS, NLOS modes, rate_hz, max_range_m, edge_width_m)", fit=_fit)
