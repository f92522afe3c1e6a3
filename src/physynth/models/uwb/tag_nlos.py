"""Tag-side NLOS: bursts in which the walker's body blocks the tag, every anchor at once."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .arrays import ChannelArrays, episode_law
from .nlos import episode_switches
from .ranging_error import los_errors

TAG_MODE_MAX_M = 0.5
"""A tag-side episode gives an anchor its near-LOS NLOS mode: the heaviest mode whose mean offset and
std are both within this [m] (a mode of gross outliers, metres off, is the anchor's own radio's)."""


def tag_mode_index(weights: np.ndarray, mean_m: np.ndarray, std_m: np.ndarray) -> int:
    """Index of the NLOS mode a tag-side episode gives (see :data:`TAG_MODE_MAX_M`); -1: none."""
    ok = (np.asarray(weights) > 0) & (np.abs(mean_m) <= TAG_MODE_MAX_M) & (np.asarray(std_m) <= TAG_MODE_MAX_M)
    return int(np.argmax(np.where(ok, weights, -1.0))) if ok.any() else -1


def tag_thinning(p_tag: float, nlos_prob: np.ndarray, cumw: np.ndarray, mean: np.ndarray,
                  std: np.ndarray) -> dict[str, np.ndarray]:
    """How each anchor's own NLOS episodes make room for a tag-side process of fraction ``p_tag``.

    A tag-side episode gives anchor a its near-LOS mode n (:func:`tag_mode_index`; an anchor without
    one does not join) and is joined by the anchor with probability j = min(1, p_a w_n / p_tag), so the
    tag side brings t = p_tag j of NLOS time in mode n where the anchor's own process is LOS. The
    anchor's own process is drawn as its channel says (the same draws as without a tag side); each of
    its episodes of mode n is then dropped with probability d = (p_a - q) / (p_a w_n), q = (p_a - t) /
    (1 - t), which leaves own NLOS time q: the union q + (1 - q) t is p_a, and the other modes keep
    their time p_a w_m, so the NLOS fraction and every mode's time share stay those of the channel.
    Returns per anchor the tag ``mode``, the ``join`` and ``drop`` probabilities (anchors with p_a of 0
    or 1 keep their own process and do not join).
    """
    weights = np.diff(cumw, axis=1, prepend=0.0)
    found = np.array([tag_mode_index(weights[i], mean[i], std[i]) for i in range(nlos_prob.size)], dtype=np.intp)
    mode = np.maximum(found, 0)
    w_n = np.where(found >= 0, weights[np.arange(nlos_prob.size), mode], 0.0)
    open_ = (nlos_prob > 0) & (nlos_prob < 1) & (found >= 0) & (w_n > 0)
    join = np.where(open_, np.minimum(1.0, nlos_prob * w_n / p_tag), 0.0)
    t = p_tag * join
    q = np.where(open_, (nlos_prob - t) / (1.0 - t), nlos_prob)
    near = np.where(open_, nlos_prob * w_n, 1.0)
    drop = np.where(open_, np.clip((nlos_prob - q) / near, 0.0, 1.0), 0.0)
    return {"mode": mode, "join": join, "drop": drop}


def tag_nlos(bursts_s: np.ndarray, burst: np.ndarray, rows: TagRows, err: np.ndarray, ch: ChannelArrays,
             dwell_s: float, *, rng: np.random.Generator) -> None:
    """Tag-side NLOS episodes (in place on ``rows.nlos`` and ``err``): one alternating renewal process
    over the bursts (fraction ``ch.tag_prob``, exponential episodes of mean ``dwell_s``); each anchor
    joins each episode with probability ``ch.tag_join``; a joined row that its own process left LOS
    becomes NLOS with the error mean + std * z of the anchor's ``ch.tag_mode``, z one draw per burst
    shared by the anchors of that burst. First, each own episode of mode ``ch.tag_mode`` is dropped with
    probability ``ch.tag_drop`` (its rows turn LOS and draw a LOS error; rows a zone or an obstacle
    makes NLOS stay as they are): see :func:`tag_thinning`. Every draw comes from ``rng``, so the
    anchors' own streams draw what they draw without a tag side. Draws: the process, the joins
    (episodes x anchors), z per burst, one per own episode id, one per dropped row."""
    if bursts_s.size == 0:
        return
    anchor, nlos = rows.anchor, rows.nlos
    law = episode_law(ch.tag_prob, np.ones(1), np.array([dwell_s]))
    k, _, start_on = episode_switches(bursts_s, law, rng=rng, ascending=True)
    if not start_on:
        k = k + 1
    on_burst = (k & 1) == 0
    ep_of_burst = np.right_shift(k, 1) - (0 if start_on else 1)
    n_ep = int(ep_of_burst.max()) + 1
    joins = rng.random((max(n_ep, 1), ch.tag_join.size)) < ch.tag_join
    z = rng.standard_normal(bursts_s.size)
    coin = rng.random(int(rows.episode.max()) + 1) if rows.episode.size else np.empty(0)
    own = np.flatnonzero((rows.episode >= 0) & ~rows.forced)
    a = anchor.take(own)
    gone = own[(rows.mode.take(own) == ch.tag_mode.take(a)) & (coin.take(rows.episode.take(own)) < ch.tag_drop.take(a))]
    nlos[gone] = False
    err[gone] = los_errors(rows.true_range_m.take(gone), anchor.take(gone), ch, rng.standard_normal(gone.size))
    on = on_burst.take(burst)
    hit = np.flatnonzero(on & ~nlos)
    a = anchor.take(hit)
    b = burst.take(hit)
    hit = hit[joins[ep_of_burst.take(b), a]]
    a, b = anchor.take(hit), burst.take(hit)
    m = ch.tag_mode.take(a)
    err[hit] = ch.mode_mean_m[a, m] + ch.mode_std_m[a, m] * z.take(b)
    nlos[hit] = True


@dataclass(frozen=True, slots=True)
class TagRows:
    """The rows' state that :func:`tag_nlos` reads (and changes: ``nlos``): anchor, true range [m],
    NLOS indicator, episode mode and id (-1 outside an own episode), and the rows a zone or an
    obstacle makes NLOS."""

    anchor: np.ndarray
    true_range_m: np.ndarray
    nlos: np.ndarray
    mode: np.ndarray
    episode: np.ndarray
    forced: np.ndarray
