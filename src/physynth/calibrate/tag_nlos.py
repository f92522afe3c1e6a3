"""The tag-side NLOS fraction (``uwb.tag_nlos_prob``) from how often the anchors are NLOS together.

The real Hanyang walks' wide range errors (beyond the LOS spread, within a metre) strike the anchors of
one burst together: residuals above 0.15 m of two anchors ranged in the same burst correlate at
0.86-0.91, and their difference stays at 4-5 cm at 25-50 m, against 12 cm for anchors drawn
independently (docs/calibration.md). A far tag sees its anchors within a narrow angle: whatever blocks
the tag's antenna (the body carrying it, the ground) blocks all of them. The generator's tag-side
process (:func:`physynth.models.uwb.tag_nlos`) is one episode process for the whole tag.

Fit: a row is "seen near NLOS" when the anchor's mixture calls it NLOS and its most likely NLOS mode is
the anchor's near-LOS one (the mode a tag-side episode gives, :func:`physynth.models.uwb.tag_mode_index`).
Many rows of that mode lie within the LOS spread and are not seen: anchor a's detection probability is
d_a = P_a / pi_a, its seen fraction over the fraction pi_a the mixture gives the mode (nlos_prob x weight).
For two anchors a, b ranged in the same burst, an own process per anchor and a shared one of fraction p
(whose rows, of one shared draw, are seen together: both missed with probability 1 - max(d_a, d_b)) give

    P(neither seen) = (1 - p - P_a + p d_a)(1 - p - P_b + p d_b) / (1 - p) + p (1 - max(d_a, d_b)),

solved for p on a grid over [0, min(pi_a, pi_b)] (with d = 1 it is p = 1 - (1 - P_a)(1 - P_b) /
P(neither)). P_a, P_b and P(neither) are counted over the bursts where both were ranged. The estimate
pools the pairs of every run (weighted by their bursts) of anchors that both have a near-LOS mode: an
anchor without one never joins a tag-side episode (:func:`physynth.models.uwb.tag_mode_index`), so its
pairs say nothing about the fraction (counted as 0 they diluted it: on the Hanyang fold without LOS
Case_1 one pair of six was informative, and whether it was turned on the mixture order of one anchor).
Kept when it rests on at least
:data:`MIN_BURSTS` shared bursts and exceeds :data:`MIN_PROB`.
"""

from __future__ import annotations

from collections.abc import Iterable
from itertools import combinations
from typing import Any

import numpy as np

MIN_BURSTS = 500
"""Fewest bursts with two anchors ranged on which a tag-side fraction is fitted."""
MIN_PROB = 0.002
"""Smallest tag-side fraction kept (below it the shared part is noise of the counts)."""


def _burst_ids(t_s: np.ndarray, gap_s: float) -> np.ndarray:
    """Burst id of each row of one run (rows sorted by time): a new burst after a gap of ``gap_s``."""
    return np.concatenate([[0], np.cumsum(np.diff(t_s) > gap_s)])


def _pair_counts(burst: np.ndarray, anchor: np.ndarray, near: np.ndarray, n_anchors: int) -> np.ndarray:
    """(n_anchors, n_anchors, 4) counts over the bursts where both anchors were ranged: bursts, a near,
    b near, neither near."""
    nb = int(burst.max()) + 1 if burst.size else 0
    seen = np.zeros((nb, n_anchors), dtype=bool)
    hit = np.zeros((nb, n_anchors), dtype=bool)
    seen[burst, anchor] = True
    hit[burst, anchor] = near
    out = np.zeros((n_anchors, n_anchors, 4))
    for a, b in combinations(range(n_anchors), 2):
        both = seen[:, a] & seen[:, b]
        ha, hb = hit[both, a], hit[both, b]
        out[a, b] = (both.sum(), ha.sum(), hb.sum(), (~ha & ~hb).sum())
    return out


def _solve_pair(pa: float, pb: float, p0: float, da: float, db: float, ceiling: float) -> float:
    """The shared fraction p of one pair of anchors (the module's equation), on a grid over [0, ceiling]."""
    p = np.linspace(0.0, max(ceiling, 0.0), 2001)[:-1] if ceiling > 0 else np.zeros(1)
    model = (1 - p - pa + p * da) * (1 - p - pb + p * db) / (1 - p) + p * (1 - max(da, db))
    return float(p[np.argmin(np.abs(model - p0))])


def fit_tag_nlos(runs: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]], n_anchors: int,
                 burst_period_s: float, near_prob: np.ndarray | None = None) -> dict[str, Any]:
    """Fit the tag-side NLOS fraction from ``runs``: per run (row times [s], anchor index, seen near-NLOS
    flag); ``near_prob`` (A,): each anchor's fraction of rows in its near-LOS NLOS mode by its mixture
    (None: every near row is seen, d = 1).

    Returns ``identifiable``, ``prob`` (0 when not kept), ``n_bursts`` (pairs' shared bursts summed),
    ``per_pair`` (anchor indices, bursts, p_a, p_b, P(neither), p), ``pairs_without_near_mode`` (pairs
    left out: an anchor without a near-LOS mode) and ``why`` when not kept.
    """
    counts = np.zeros((n_anchors, n_anchors, 4))
    for t, anchor, near in runs:
        if t.size < 2:
            continue
        order = np.argsort(t, kind="stable")
        burst = _burst_ids(t[order], 0.5 * burst_period_s)
        counts += _pair_counts(burst, anchor[order], near[order], n_anchors)
    pairs, skipped = [], 0
    for a, b in combinations(range(n_anchors), 2):
        n, na, nb, n0 = counts[a, b]
        if n < 1 or n0 < 1:
            continue
        if near_prob is not None and min(near_prob[a], near_prob[b]) <= 0:
            skipped += 1  # an anchor without a near-LOS mode never joins a tag-side episode: the pair says nothing
            continue
        pa, pb, p0 = na / n, nb / n, n0 / n
        pi_a, pi_b = (1.0, 1.0) if near_prob is None else (float(near_prob[a]), float(near_prob[b]))
        da, db = (1.0, 1.0) if near_prob is None else (min(1.0, pa / max(pi_a, 1e-12)), min(1.0, pb / max(pi_b, 1e-12)))
        ceiling = min(pi_a, pi_b) if near_prob is not None else min(1.0, 1.0 - (1.0 - pa) * (1.0 - pb))
        pairs.append({"anchors": [a, b], "n_bursts": int(n), "p_a": float(pa), "p_b": float(pb),
                      "p_neither": float(p0), "detect_a": float(da), "detect_b": float(db),
                      "prob": _solve_pair(pa, pb, p0, da, db, ceiling)})
    total = sum(p["n_bursts"] for p in pairs)
    out: dict[str, Any] = {"identifiable": False, "prob": 0.0, "n_bursts": int(total), "per_pair": pairs}
    out["pairs_without_near_mode"] = skipped
    if total < MIN_BURSTS:
        lacking = f" ({skipped} pairs left out: an anchor without a near-LOS NLOS mode)" if skipped else ""
        out["why"] = f"{total} bursts with two anchors ranged, fewer than {MIN_BURSTS}{lacking}"
        return out
    prob = float(sum(p["prob"] * p["n_bursts"] for p in pairs) / total)
    out["prob"] = prob
    if prob < MIN_PROB:
        out["why"] = f"the anchors are NLOS together no more often than apart (fraction {prob:.4f})"
        return out
    out["identifiable"] = True
    return out
