"""The UWB model composed: every effect applied in one place (:func:`simulate_uwb`), and the record."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...records import Reason, Uwb
from ..interp import interp_many
from ..kinematics import Kinematics
from ..obstacles import obstacle_losses
from ..renewal import by_label, is_ascending
from .arrays import ChannelArrays
from .link_budget import link_detection_probability, link_probability
from .nlos import nlos_states, zone_nlos_prob_at
from .params import UwbParams
from .pattern import heading_at, tag_pattern_bias
from .ranging_error import range_decades, range_error
from .run_effects import LAG_MARGIN_STDS, run_offsets, run_slopes, trace_time_offset
from .schedule import burst_times
from .sway import sway_at
from .tag_nlos import TagRows, tag_nlos


@dataclass(frozen=True, slots=True, kw_only=True)
class UwbAttempts:
    """Every scheduled ranging attempt of one run before availability: rows sorted by true time."""

    bursts_s: np.ndarray  # (B,) true start time of every tag burst
    burst: np.ndarray  # (N,) burst index of each attempt
    anchor: np.ndarray  # (N,) anchor index
    t_true_s: np.ndarray  # (N,) true time of the attempt
    true_range_m: np.ndarray
    measured_m: np.ndarray  # range the radio would report (never negative)
    nlos: np.ndarray
    linked: np.ndarray  # inside the radio horizon
    anchor_rows: tuple[np.ndarray, ...] | None = None  # rows of each anchor (rows_by_label), for the availability
    time_offset_s: float = 0.0  # the trace's lag: stamp = t_true_s + time_offset_s


def simulate_uwb(kin: Kinematics, params: UwbParams, ch: ChannelArrays, *, rng: np.random.Generator,
                 sway_rng: np.random.Generator | None = None,
                 tag_rng: np.random.Generator | None = None,
                 omega_body_radps: np.ndarray | None = None) -> UwbAttempts:
    """All ranging attempts of one run with their true and measured ranges and NLOS state.

    ``omega_body_radps``: the truth's body rate (T, 3), for an antenna sway on the ``motion`` clock.

    ``sway_rng``: the stream of the antenna sway, needed when ``params.antenna_sway_std_m`` > 0;
    ``tag_rng``: that of the tag-side NLOS, needed when the channel has a tag-side process.
    """
    u = params
    n_anchors = ch.anchor_pos_enu_m.shape[0]
    # stamps (true time + the trace's lag) stay inside the truth span, for lags within LAG_MARGIN_STDS
    spread = LAG_MARGIN_STDS * u.time_offset_std_s
    t_end = float(kin.t_s[-1]) - n_anchors * u.slot_s - max(0.0, u.time_offset_s + spread)
    phase = None if u.burst_phase_s is None else u.burst_phase_s - u.time_offset_s  # stamp -> true time
    bursts = burst_times(float(kin.t_s[0]), t_end, u.burst_rate_hz, u.burst_jitter_s,
                         n_anchors * u.slot_s + 1e-4, rng=rng, phase_s=phase)
    lead = spread - u.time_offset_s  # a UWB clock ahead of the truth: no burst whose stamp precedes it
    if lead > 0:
        bursts = bursts[bursts.searchsorted(float(kin.t_s[0]) + lead, side="left"):]
    scheduled = rng.random((bursts.shape[0], n_anchors)) < ch.attempt_prob
    # row-major: sorted by burst, then anchor slot (np.nonzero's indices; flat indices and their quotient
    # and remainder are ~2.5x faster than its 2-D multi-index iteration; // by a number is faster than divmod)
    flat = np.flatnonzero(scheduled)
    b_idx = flat // n_anchors
    anchor = flat - b_idx * n_anchors
    t_true = bursts.take(b_idx) + anchor * u.slot_s
    # the tag's E, N, U at the attempts (rows of one block): numpy.interp's values (the path coordinate
    # only near the zones, where it decides: zone_nlos_prob_at)
    (tag_enu,) = interp_many(t_true, kin.t_s, [kin.pos_enu_m.T])
    sq = None
    for k in range(3):  # |p(t) - a_i|, one ENU component at a time (contiguous, no (N, 3) temporaries)
        d = tag_enu[k] - ch.anchor_pos_enu_m[:, k].take(anchor)  # take: numpy's fastest gather
        d *= d
        sq = d if sq is None else np.add(sq, d, out=sq)  # as 0 + d_E^2 + d_N^2 + d_U^2 (0 + x is x)
    true_range = np.sqrt(sq)

    p_link = link_probability(true_range, by_label(ch.max_range_m, anchor), by_label(ch.edge_width_m, anchor))
    blocked = None
    if ch.obstacles or ch.terrain is not None or ch.link is not None:  # geometry-aware parts (optional)
        tag = np.stack(tag_enu, axis=1)
        loss: np.ndarray | float = 0.0
        if ch.obstacles or ch.terrain is not None:
            blocked, loss = obstacle_losses(tag, ch.anchor_pos_enu_m[anchor], ch.obstacles, ch.terrain)
        p_link = p_link * link_detection_probability(tag, anchor, ch, loss)
    linked = rng.random(t_true.shape[0]) < p_link
    rows_of = _rows_per_anchor(scheduled)
    forced = np.zeros(t_true.shape[0], dtype=bool) if ch.tag_prob > 0 else None
    ascending = is_ascending(t_true)  # checked once for the zones and every anchor's rows
    zone_prob = zone_nlos_prob_at(t_true, kin.t_s, kin.s_m, ch, ascending=ascending) if ch.zone_s_m.size else None
    nlos, mode, episode = nlos_states(t_true, anchor, None, ch, rng=rng, blocked=blocked, rows_of=rows_of,
                                      forced_out=forced, zone_prob=zone_prob, ascending=ascending)
    err = range_error(true_range, anchor, nlos, mode, ch, rng=rng, episode=episode)
    if forced is not None:  # the tag's own obstruction: every anchor at once
        if tag_rng is None:
            raise ValueError("tag-side NLOS needs its random stream (tag_rng)")
        tag_nlos(bursts, b_idx, TagRows(anchor, true_range, nlos, mode, episode, forced), err, ch, u.nlos_dwell_s,
                 rng=tag_rng)
    offsets = run_offsets(n_anchors, u, rng=rng)
    if offsets.any():  # adding zeros would change only a -0.0 error, and true_range + (-0.0) is true_range
        err += offsets[anchor]
    tilts = run_slopes(n_anchors, u, rng=rng)
    if tilts.any():
        err += tilts[anchor] * (range_decades(true_range) - np.log10(u.run_slope_ref_range_m))
    if u.antenna_sway_std_m > 0:  # the range from the swaying antenna: + u . offset
        if sway_rng is None:
            raise ValueError("antenna sway needs its random stream (sway_rng)")
        sway = sway_at(t_true, kin, u, rng=sway_rng, omega_body_radps=omega_body_radps)
        for k in range(3):
            err += (tag_enu[k] - ch.anchor_pos_enu_m[:, k][anchor]) / np.maximum(true_range, 1e-9) * sway[:, k]
    if any(u.tag_pattern_m):  # the tag antenna's delay towards the anchor's bearing (deterministic)
        head = heading_at(t_true, kin.t_s, kin.vel_enu_mps)
        err += tag_pattern_bias(tag_enu[0], tag_enu[1], ch.anchor_pos_enu_m[:, 0].take(anchor),
                                ch.anchor_pos_enu_m[:, 1].take(anchor), head, u.tag_pattern_m)
    err += true_range  # true_range + err
    measured = np.maximum(err, 0.0, out=err)  # a range is never negative
    return UwbAttempts(bursts_s=bursts, burst=b_idx, anchor=anchor, t_true_s=t_true, true_range_m=true_range,
                       measured_m=measured, nlos=nlos, linked=linked, anchor_rows=rows_of,
                       time_offset_s=trace_time_offset(u, rng=rng))


def _rows_per_anchor(scheduled: np.ndarray) -> tuple[np.ndarray, ...]:
    """The attempt rows of each anchor (``rows_by_label(anchor, A)``) from the (bursts, anchors) schedule
    whose row-major nonzeros are the attempts: each scheduled entry's rank among them, anchor by anchor."""
    rank = np.cumsum(scheduled.ravel()).reshape(scheduled.shape)
    rank -= 1
    return tuple(rank[:, i][scheduled[:, i]] for i in range(scheduled.shape[1]))


def uwb_record(att: UwbAttempts, *, outage: np.ndarray, dropped: np.ndarray) -> Uwb:
    """The ``uwb`` record of a run: attempts with the availability applied and stamps on the tag clock
    (``att.time_offset_s`` after the true times)."""
    n = att.t_true_s.shape[0]
    masks = (att.linked, outage, dropped)
    if all(isinstance(m, np.ndarray) and m.dtype == np.bool_ and m.shape == (n,) for m in masks):
        # boolean masks (as simulate_availability returns): the precedence below as the largest code that
        # applies, in 8-bit integer passes (twice as fast as two selections): a dropped row is 1 = DROPOUT,
        # an outage 2 = OUTAGE, no link 3 = NO_LINK, a kept row 0 = OK
        reason = np.left_shift(outage.view(np.int8), 1)
        np.maximum(reason, dropped.view(np.int8), out=reason)
        no_link = np.invert(att.linked).view(np.int8)
        no_link *= np.int8(Reason.NO_LINK)
        np.maximum(reason, no_link, out=reason)
    else:
        reason = np.full(n, Reason.OK, dtype=np.int8)
        reason[dropped] = Reason.DROPOUT
        reason[outage] = Reason.OUTAGE
        reason[~att.linked] = Reason.NO_LINK
    range_m = np.where(reason == np.int8(Reason.OK), att.measured_m, np.nan)  # an enum operand: 7x slower
    return Uwb(t_s=att.t_true_s + att.time_offset_s, anchor=att.anchor, range_m=range_m,
               true_range_m=att.true_range_m, nlos=att.nlos, burst=att.burst, reason=reason, nlos_known=True)
