"""UWB ranging model: burst schedule, link/visibility, LOS/NLOS errors per anchor, availability.

For anchor i at a_i the geometric range is r = |p(t) - a_i| (paper eq. 2) and the measured range
(eq. 3) is r + (1 - z) N(mu_i + beta_i r, sigma_i^2) + z delta_i with z the NLOS indicator and
delta_i drawn from the anchor's Gaussian mixture (bimodal allowed). ``beta_i`` is an optional
range-proportional bias (clock/antenna scale error; Hanyang's static sweeps show ~+0.4 cm per m).

z follows an alternating renewal process in time (NLOS episodes of mean ``nlos_dwell_s``, or of the
mode's own ``dwell_s``, and long-run probability ``nlos_prob``); an episode keeps one mixture mode
(one reflector) throughout. z is forced up with probability ``zone.nlos_prob`` while the tag is in
an NLOS zone along the path (support pylons). Every scheduled attempt is a row: dropped, outage and
out-of-link attempts keep a NaN range and their :class:`~physynth.records.Reason`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .availability import outage_mask
from .motion import Kinematics
from .records import Reason, Uwb
from .scenario import Scenario


@dataclass(frozen=True, slots=True, kw_only=True)
class ChannelArrays:
    """Per-anchor parameters of a scenario as arrays (A,) / (A, M) for vectorised sampling."""

    anchor_pos_enu_m: np.ndarray
    attempt_prob: np.ndarray
    los_mean_m: np.ndarray
    los_std_m: np.ndarray
    range_bias_per_m: np.ndarray
    nlos_prob: np.ndarray
    mode_cumw: np.ndarray  # (A, M) cumulative weights, last column 1
    mode_mean_m: np.ndarray  # (A, M)
    mode_std_m: np.ndarray  # (A, M)
    mode_dwell_s: np.ndarray  # (A, M) mean NLOS episode length per mode
    max_range_m: np.ndarray
    edge_width_m: np.ndarray
    dropout_prob: np.ndarray
    outage_onset_prob: np.ndarray
    outage_mean_s: np.ndarray
    zone_s_m: np.ndarray  # (Z,)
    zone_half_width_m: np.ndarray
    zone_nlos_prob: np.ndarray


def channel_arrays(scn: Scenario) -> ChannelArrays:
    chans = [scn.channel_for(a) for a in scn.anchor_ids]
    avs = [scn.availability_for(a) for a in scn.anchor_ids]
    m = max(len(c.nlos_modes) for c in chans)
    cumw = np.ones((len(chans), m))
    mean = np.zeros((len(chans), m))
    std = np.ones((len(chans), m))
    dwell = np.full((len(chans), m), scn.uwb.nlos_dwell_s)
    for i, c in enumerate(chans):
        w = np.array([mode.weight for mode in c.nlos_modes])
        k = w.size
        cumw[i, :k] = np.cumsum(w) / w.sum()
        mean[i, :k] = [mode.mean_m for mode in c.nlos_modes]
        std[i, :k] = [mode.std_m for mode in c.nlos_modes]
        dwell[i, :k] = [mode.dwell_s or scn.uwb.nlos_dwell_s for mode in c.nlos_modes]
        mean[i, k:], std[i, k:], dwell[i, k:] = mean[i, k - 1], std[i, k - 1], dwell[i, k - 1]
    z = scn.uwb.zones
    return ChannelArrays(
        anchor_pos_enu_m=np.array([a.pos_enu_m for a in scn.anchors], dtype=float),
        attempt_prob=np.array([c.rate_hz for c in chans]) / scn.uwb.burst_rate_hz,
        los_mean_m=np.array([c.los_mean_m for c in chans]),
        los_std_m=np.array([c.los_std_m for c in chans]),
        range_bias_per_m=np.array([c.range_bias_per_m for c in chans]),
        nlos_prob=np.array([c.nlos_prob for c in chans]),
        mode_cumw=cumw, mode_mean_m=mean, mode_std_m=std, mode_dwell_s=dwell,
        max_range_m=np.array([c.max_range_m for c in chans]),
        edge_width_m=np.array([c.edge_width_m for c in chans]),
        dropout_prob=np.array([a.dropout_prob for a in avs]),
        outage_onset_prob=np.array([a.outage_onset_prob for a in avs]),
        outage_mean_s=np.array([a.outage_mean_s for a in avs]),
        zone_s_m=np.array([q.s_m for q in z]), zone_half_width_m=np.array([q.half_width_m for q in z]),
        zone_nlos_prob=np.array([q.nlos_prob for q in z]),
    )


def burst_times(t_start_s: float, t_end_s: float, burst_rate_hz: float, jitter_s: float, min_period_s: float,
                *, rng: np.random.Generator, phase_s: float | None = None) -> np.ndarray:
    """Tag burst start times in [t_start, t_end).

    The tag's clock locks the bursts to a fixed period (random phase at the start); each burst is
    displaced by its own Gaussian jitter of standard deviation ``jitter_s``, so consecutive periods
    scatter by ``sqrt(2) * jitter_s`` without the schedule drifting. Bursts keep at least
    ``min_period_s`` apart (room for every anchor slot).
    """
    period = 1.0 / burst_rate_hz
    n = int(np.ceil((t_end_s - t_start_s) * burst_rate_hz)) + 2
    first = rng.uniform(0.0, period) if phase_s is None else float(phase_s) % period
    t = t_start_s + first + period * np.arange(n)
    if jitter_s > 0:
        t = t + np.clip(jitter_s * rng.standard_normal(n), -0.45 * period, 0.45 * period)
        gap = np.maximum(np.diff(t), min_period_s)
        t = np.concatenate([t[:1], t[0] + np.cumsum(gap)])
    return t[(t >= t_start_s) & (t < t_end_s)]


def link_probability(range_m: np.ndarray, max_range_m: np.ndarray, edge_width_m: np.ndarray) -> np.ndarray:
    """Soft radio horizon: 1 / (1 + exp((r - max_range) / edge_width))."""
    x = np.clip((range_m - max_range_m) / edge_width_m, -50.0, 50.0)
    return 1.0 / (1.0 + np.exp(x))


def sample_nlos_offset(anchor: np.ndarray, ch: ChannelArrays, *, rng: np.random.Generator,
                       mode: np.ndarray | None = None) -> np.ndarray:
    """NLOS offsets delta [m] for rows of the given anchors (Gaussian mixture per anchor).

    ``mode`` fixes each row's mixture component (the episode's reflector); drawn by weight otherwise.
    """
    if mode is None:
        u = rng.random(anchor.shape[0])
        mode = np.minimum((u[:, None] > ch.mode_cumw[anchor]).sum(axis=1), ch.mode_cumw.shape[1] - 1)
    return ch.mode_mean_m[anchor, mode] + ch.mode_std_m[anchor, mode] * rng.standard_normal(anchor.shape[0])


def nlos_episodes(t_s: np.ndarray, nlos_prob: float, weights: np.ndarray, dwell_s: np.ndarray, *,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """NLOS state and mode at sorted times of one anchor: an alternating renewal process in which each
    NLOS episode keeps one mode m for an exponential time of mean ``dwell_s[m]``.

    Episodes pick mode m with probability proportional to weight_m / dwell_m, so that ``weights`` is
    the share of NLOS *time* in each mode; LOS gaps are exponential with the mean that makes the
    long-run NLOS fraction ``nlos_prob``. Returns (nlos (N,) bool, mode (N,) int, -1 where LOS).
    """
    q = weights / dwell_s
    q = q / q.sum()
    mean_on = float(np.sum(q * dwell_s))
    mean_off = mean_on * (1.0 - nlos_prob) / nlos_prob
    t0, span = float(t_s[0]), float(t_s[-1] - t_s[0])
    start_on = bool(rng.random() < nlos_prob)
    n_pairs = int(2.0 * span / (mean_on + mean_off)) + 8
    while True:
        modes = np.minimum(np.searchsorted(np.cumsum(q), rng.random(n_pairs), side="right"), q.size - 1)
        on = rng.exponential(1.0, n_pairs) * dwell_s[modes]
        off = rng.exponential(mean_off, n_pairs)
        pairs = np.stack([on, off] if start_on else [off, on], axis=1)  # memoryless: a stationary start
        switches = t0 + np.cumsum(pairs.ravel())
        if switches[-1] > t_s[-1]:
            break
        n_pairs *= 2
    k = np.searchsorted(switches, t_s, side="right")  # switches at or before t
    nlos = (k % 2 == 0) == start_on
    return nlos, np.where(nlos, modes[np.minimum(k // 2, n_pairs - 1)], -1)


def nlos_states(t_s: np.ndarray, anchor: np.ndarray, s_m: np.ndarray, ch: ChannelArrays, *,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """NLOS indicator and mode of each row: per-anchor episodes, raised inside NLOS zones.

    Rows made NLOS by a zone (and not by an episode) draw their mode by weight (mode -1 marks them).
    """
    nlos = np.zeros(t_s.shape[0], dtype=bool)
    mode = np.full(t_s.shape[0], -1, dtype=np.int64)
    for i in range(ch.nlos_prob.shape[0]):  # one renewal process per anchor
        p = ch.nlos_prob[i]
        rows = np.flatnonzero(anchor == i)
        if rows.size == 0 or p <= 0:
            continue
        weights = np.diff(np.concatenate([[0.0], ch.mode_cumw[i]]))
        if p >= 1:
            nlos[rows] = True
            continue
        nlos[rows], mode[rows] = nlos_episodes(t_s[rows], p, weights, ch.mode_dwell_s[i], rng=rng)
    if ch.zone_s_m.size:
        dist = np.abs(s_m[:, None] - ch.zone_s_m[None, :])
        p_zone = np.where(dist <= ch.zone_half_width_m, ch.zone_nlos_prob, 0.0).max(axis=1)
        nlos |= rng.random(t_s.shape[0]) < p_zone
    return nlos, mode


def simulate_uwb(kin: Kinematics, scn: Scenario, ch: ChannelArrays, *, rng: np.random.Generator,
                 rng_availability: np.random.Generator) -> Uwb:
    """All ranging attempts of one run (rows sorted by time)."""
    u = scn.uwb
    n_anchors = ch.anchor_pos_enu_m.shape[0]
    t_end = float(kin.t_s[-1]) - n_anchors * u.slot_s - abs(u.time_offset_s)
    phase = None if u.burst_phase_s is None else u.burst_phase_s - u.time_offset_s  # stamp -> true time
    bursts = burst_times(float(kin.t_s[0]), t_end, u.burst_rate_hz, u.burst_jitter_s,
                         n_anchors * u.slot_s + 1e-4, rng=rng, phase_s=phase)
    scheduled = rng.random((bursts.shape[0], n_anchors)) < ch.attempt_prob
    b_idx, anchor = np.nonzero(scheduled)  # row-major: sorted by burst, then anchor slot
    t_true = bursts[b_idx] + anchor * u.slot_s
    sq = np.zeros(t_true.shape[0])
    for k in range(3):  # |p(t) - a_i|, one ENU component at a time (contiguous, no (N, 3) temporaries)
        d = np.interp(t_true, kin.t_s, kin.pos_enu_m[:, k]) - ch.anchor_pos_enu_m[:, k][anchor]
        sq += d * d
    true_range = np.sqrt(sq)
    s_m = np.interp(t_true, kin.t_s, kin.s_m)

    linked = rng.random(t_true.shape[0]) < link_probability(true_range, ch.max_range_m[anchor],
                                                            ch.edge_width_m[anchor])
    nlos, mode = nlos_states(t_true, anchor, s_m, ch, rng=rng)
    err = (ch.los_mean_m[anchor] + ch.range_bias_per_m[anchor] * true_range
           + ch.los_std_m[anchor] * rng.standard_normal(t_true.shape[0]))
    # NLOS replaces the LOS error (eq. 3); an episode keeps its reflector (its mode's offset), rows
    # made NLOS by a zone alone draw a mode by weight
    in_episode = mode >= 0
    zone_only = nlos & ~in_episode
    err[in_episode] = sample_nlos_offset(anchor[in_episode], ch, rng=rng, mode=mode[in_episode])
    err[zone_only] = sample_nlos_offset(anchor[zone_only], ch, rng=rng)
    measured = np.maximum(true_range + err, 0.0)  # a range is never negative

    outage = np.zeros(t_true.shape[0], dtype=bool)
    for i in range(n_anchors):  # one outage process per anchor
        rows = np.flatnonzero(anchor == i)
        outage[rows] = outage_mask(t_true[rows], ch.outage_onset_prob[i], u.burst_rate_hz, ch.outage_mean_s[i],
                                   start_stationary=scn.availability.start_stationary, rng=rng_availability)
    av = scn.availability
    if av.tag_outage_onset_prob > 0:  # one process for the tag, applied to every anchor of a burst
        tag_out = outage_mask(bursts, av.tag_outage_onset_prob, u.burst_rate_hz, av.tag_outage_mean_s,
                              start_stationary=av.start_stationary, rng=rng_availability)
        outage |= tag_out[b_idx]
    dropped = rng_availability.random(t_true.shape[0]) < ch.dropout_prob[anchor]

    reason = np.full(t_true.shape[0], Reason.OK, dtype=np.int8)
    reason[dropped] = Reason.DROPOUT
    reason[outage] = Reason.OUTAGE
    reason[~linked] = Reason.NO_LINK
    range_m = np.where(reason == Reason.OK, measured, np.nan)
    return Uwb(t_s=t_true + u.time_offset_s, anchor=anchor, range_m=range_m, true_range_m=true_range,
               nlos=nlos, burst=b_idx, reason=reason, nlos_known=True)
