"""NLOS episodes: the alternating renewal process of each anchor's LOS / NLOS-mode state, and the NLOS
zones along the path.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import accumulate

import numpy as np

from ..renewal import initial_pairs, is_ascending, rows_by_label, switch_counts
from .arrays import ChannelArrays, EpisodeLaw, episode_law


def nlos_episodes(t_s: np.ndarray, nlos_prob: float, weights: np.ndarray, dwell_s: np.ndarray, *,
                  rng: np.random.Generator, fixed_dwell: np.ndarray | None = None, first_episode: int = 0,
                  ascending: bool | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NLOS state and mode at sorted times of one anchor: an alternating renewal process in which each
    NLOS episode keeps one mode m for an exponential time of mean ``dwell_s[m]``.

    Episodes pick mode m with probability proportional to weight_m / dwell_m, so that ``weights`` is
    the share of NLOS *time* in each mode; LOS gaps are exponential with the mean that makes the
    long-run NLOS fraction ``nlos_prob``. A mode with ``fixed_dwell`` lasts exactly ``dwell_s`` (the
    exponential draw is still made, so the stream does not depend on the flag). Returns (nlos (N,)
    bool, mode (N,) int, -1 where LOS, episode (N,) int: ``first_episode`` + index of the episode, -1
    where LOS). ``ascending``: as in :func:`~physynth.models.renewal.switch_counts`.
    """
    k, modes, start_on = episode_switches(t_s, episode_law(nlos_prob, weights, dwell_s, fixed_dwell), rng=rng,
                                          ascending=ascending)
    nlos = (k & 1) == (0 if start_on else 1)  # k >= 0: k & 1 is k % 2 and k >> 1 is k // 2
    pair = np.right_shift(k, 1, out=k)
    np.minimum(pair, modes.size - 1, out=pair)
    mode = np.where(nlos, modes.take(pair), -1)
    if first_episode:
        pair += first_episode
    return nlos, mode, np.where(nlos, pair, -1)


def episode_switches(t_s: np.ndarray, law: EpisodeLaw, *, rng: np.random.Generator,
                     ascending: bool | None = None) -> tuple[np.ndarray, np.ndarray, bool]:
    """The draws of :func:`nlos_episodes`: (switch counts (N,) at the sorted times ``t_s``, the mode of
    each episode, whether the process starts in an episode). Even counts: the starting state; count k
    is in pair k // 2 (episode and gap)."""
    start_on = bool(rng.random() < law.nlos_prob)
    col_on = 0 if start_on else 1
    cum_q, dwell_s, fixed = law.cum_q, law.dwell_s, law.fixed

    def draw(n: int) -> tuple[np.ndarray, np.ndarray]:
        modes = np.minimum(cum_q.searchsorted(rng.random(n), side="right"), cum_q.size - 1)
        pairs = np.empty((n, 2))  # (on, off) or (off, on): the state the process starts in first
        on = rng.exponential(1.0, n)
        on *= dwell_s[modes]
        if fixed is not None:
            on = np.where(fixed[modes], dwell_s[modes], on)
        pairs[:, col_on] = on
        pairs[:, 1 - col_on] = rng.exponential(law.mean_off_s, n)
        return pairs, modes

    k, modes = switch_counts(t_s, draw, initial_pairs(float(t_s[-1] - t_s[0]), law.mean_cycle_s),
                             ascending=ascending)
    return k, modes, start_on


def nlos_states(t_s: np.ndarray, anchor: np.ndarray, s_m: np.ndarray | None, ch: ChannelArrays, *,
                rng: np.random.Generator, blocked: np.ndarray | None = None,
                rows_of: Sequence[np.ndarray] | None = None,
                forced_out: np.ndarray | None = None, zone_prob: np.ndarray | None = None,
                ascending: bool | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NLOS indicator, mode and episode id of each row: per-anchor episodes, raised inside NLOS zones and
    where ``blocked`` (the line of sight meets an obstacle).

    Rows made NLOS by a zone or an obstacle (and not by an episode) draw their mode by weight (mode -1
    marks them). Episode ids are unique over anchors (-1 outside an episode). ``rows_of``: the rows of
    each anchor, ``rows_by_label(anchor, A)``, when the caller has them already. ``forced_out``: a
    boolean array of the rows, set where a zone or ``blocked`` makes a row NLOS (whatever its episodes).
    ``zone_prob``: the zones' NLOS probability of each row (:func:`zone_nlos_prob_at`) when the caller has
    it; ``s_m`` (the rows' path coordinates) is then not read and may be None. ``ascending``: whether
    ``t_s`` is known to be sorted (:func:`~physynth.models.renewal.is_ascending`; None: checked here).
    """
    nlos = np.zeros(t_s.shape[0], dtype=bool)
    mode = np.full(t_s.shape[0], -1, dtype=np.int64)
    episode = np.full(t_s.shape[0], -1, dtype=np.int64)
    if ascending is None:
        ascending = is_ascending(t_s)  # checked once for every anchor's rows
    if rows_of is None:
        rows_of = rows_by_label(anchor, ch.nlos_prob.shape[0])
    parts = []  # (rows, switch counts, episode modes, start_on) of each anchor with episodes
    for i, rows in enumerate(rows_of):  # one renewal process per anchor (the draws anchor by anchor)
        if rows.size == 0 or ch.nlos_prob[i] <= 0:
            continue
        if ch.nlos_prob[i] >= 1:
            nlos[rows] = True
            continue
        parts.append((rows, *episode_switches(t_s.take(rows), ch.episode_laws[i], rng=rng, ascending=ascending)))
    if parts:  # the anchors' rows are disjoint: their states in one pass over all of them
        _write_episodes(parts, nlos, mode, episode)
    forced = nlos if forced_out is None else forced_out  # the zone and obstacle rows: into nlos, or apart
    if ch.zone_s_m.size:
        p_zone = zone_nlos_prob(s_m, ch) if zone_prob is None else zone_prob
        forced |= rng.random(t_s.shape[0]) < p_zone
    if blocked is not None:
        forced |= blocked
    if forced_out is not None:
        nlos |= forced_out
    return nlos, mode, episode


def _write_episodes(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, bool]], nlos: np.ndarray,
                    mode: np.ndarray, episode: np.ndarray) -> None:
    """Write the anchors' episode states into the columns at their rows: ``parts`` holds (rows, switch
    counts, episode modes, start_on) of each anchor (:func:`episode_switches`), in anchor order. The
    values of :func:`nlos_episodes` anchor by anchor, with ``first_episode`` running over the anchors
    (each anchor's episodes numbered after the last one of the anchors before it); LOS rows keep their
    state (False), mode and episode (-1). The switch counts are changed in place."""
    for _, k, _, start_on in parts:
        if not start_on:  # in an episode exactly where the count with its lowest bit flipped is even;
            np.bitwise_xor(k, 1, out=k)  # there, k >> 1 (the episode's pair) is that of the unflipped count
    k = np.concatenate([q[1] for q in parts])
    rows = np.concatenate([q[0] for q in parts])
    at = np.flatnonzero((k & 1) == 0)  # the few rows in an episode: state, pair, mode and id set there only
    pair = np.right_shift(k.take(at), 1)  # the (episode, gap) pair: k // 2
    mode_at = np.empty_like(pair)
    ends = at.searchsorted(list(accumulate(q[0].size for q in parts))).tolist()  # each anchor's rows in `at`
    start, first = 0, 0  # the anchor's first row in `at`, its first episode id
    for (_, _, modes, _), end in zip(parts, ends, strict=True):
        if end > start:
            p = pair[start:end]  # a view: clipped and numbered in place
            np.minimum(p, modes.size - 1, out=p)
            mode_at[start:end] = modes.take(p)
            last = int(p.max())
            p += first
            first += last + 1
        start = end
    dest = rows.take(at)
    nlos[dest] = True
    mode[dest] = mode_at
    episode[dest] = pair


def zone_nlos_prob(s_m: np.ndarray, ch: ChannelArrays) -> np.ndarray:
    """(N,) NLOS probability of the zones at path coordinates ``s_m``: the largest of the zones that
    contain each point, 0 outside every zone. One zone at a time (no (N, Z) temporaries)."""
    p = None
    for z_s, half, prob in zip(ch.zone_s_m.tolist(), ch.zone_half_width_m.tolist(), ch.zone_nlos_prob.tolist(),
                               strict=True):
        dist = np.subtract(s_m, z_s)
        np.abs(dist, out=dist)
        here = np.where(dist <= half, prob, 0.0)
        p = here if p is None else np.maximum(p, here, out=p)
    return p


ZONE_MARGIN = 1e-9
"""Relative margin [of the path's scale] by which :func:`zone_nlos_prob_at` widens each zone when it
looks for the rows near it (interpolation rounds by a few ulp, some 1e-16 relative)."""


def zone_nlos_prob_at(t_s: np.ndarray, grid_t_s: np.ndarray, grid_s_m: np.ndarray, ch: ChannelArrays, *,
                      ascending: bool | None = None) -> np.ndarray:
    """``zone_nlos_prob(numpy.interp(t_s, grid_t_s, grid_s_m), ch)`` (the zones' NLOS probability at the
    sorted times ``t_s`` of a run whose path coordinate is ``grid_s_m`` at ``grid_t_s``), bit for bit.

    When the path coordinate is monotone (the usual run: forwards or backwards along the path), each
    zone is met over one stretch of times: the path coordinate is interpolated only at the rows of that
    stretch (widened by a knot and :data:`ZONE_MARGIN`), the other rows lie outside the zone (0).
    ``ascending``: whether ``t_s`` is known to be sorted (None: checked here).
    """
    n, m = t_s.shape[0], grid_s_m.shape[0]
    if n == 0 or m < 2 or not (is_ascending(t_s) if ascending is None else ascending):
        return zone_nlos_prob(np.interp(t_s, grid_t_s, grid_s_m), ch)
    forwards = bool(grid_s_m[0] <= grid_s_m[-1])
    key = grid_s_m if forwards else np.negative(grid_s_m)  # ascending when the run is monotone
    if not is_ascending(key):
        return zone_nlos_prob(np.interp(t_s, grid_t_s, grid_s_m), ch)
    scale = 1.0 + max(abs(float(key[0])), abs(float(key[-1])))
    p = np.zeros(n)
    for z_s, half, prob in zip(ch.zone_s_m.tolist(), ch.zone_half_width_m.tolist(), ch.zone_nlos_prob.tolist(),
                               strict=True):
        centre = z_s if forwards else -z_s
        pad = half + ZONE_MARGIN * (scale + abs(z_s) + half)
        below = int(key.searchsorted(centre - pad, side="left")) - 1  # the last knot before the zone
        above = int(key.searchsorted(centre + pad, side="right"))  # the first knot past it
        lo = 0 if below < 0 else int(t_s.searchsorted(grid_t_s[below], side="left"))
        hi = n if above >= m else int(t_s.searchsorted(grid_t_s[above], side="right"))
        if hi > lo:
            dist = np.interp(t_s[lo:hi], grid_t_s, grid_s_m)
            dist -= z_s
            np.abs(dist, out=dist)
            np.maximum(p[lo:hi], np.where(dist <= half, prob, 0.0), out=p[lo:hi])
    return p
