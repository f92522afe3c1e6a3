"""Calibration of availability: link range, per-burst dropout, outage onset and duration, tag outages.

The generator (:mod:`physynth.models.availability`, :mod:`physynth.models.uwb`) lets each anchor alternate between
*up* and *outage* in continuous time (onset rate ``outage_onset_prob * burst_rate_hz`` per second of
up time, exponential outages of mean ``outage_mean_s``), drops each attempt while up with probability
``dropout_prob``, and refuses the link with probability ``1 - 1 / (1 + exp((r - max_range_m) /
edge_width_m))`` at range r. A tag-level process of the same kind silences every anchor at once.

Estimation, per anchor, from its sequence of ranging attempts (recorded attempt rows when the trace
has them, e.g. synthetic traces; otherwise one attempt per burst of the tag's burst schedule, bursts
with no row at all included):

1. the link model by maximum likelihood on (range, heard) of every attempt, with a free loss floor;
   when the anchor is heard at every range seen, or its likelihood ratio against a range-independent
   loss, divided by the design effect of the attempts' correlated misses (outages), is below 10, the
   limit is *not identifiable* and ``max_range_m`` is put above the largest range;
2. attempts the link model gives less than 99.9 % (or beyond R, when that would leave fewer than 10 %
   of them) are unobserved for the availability process, and so are the bursts of a detected tag
   outage;
3. dropout and outage by exact maximum likelihood of the alternating process *sampled at the
   attempts*: a two-state hidden Markov chain whose transition matrix over one attempt interval T is
   expm(Q T), Q the generator of the up/outage process, and whose *up* state is heard with probability
   1 - dropout_prob. Between two heard attempts the chain restarts from *up*, so the likelihood only
   needs the lengths of the runs of missed attempts; a run cut off by the end of the data (or by
   unobserved attempts) is censored. For long outages this reduces to the exponential MLE
   sum(durations incl. censored) / n_uncensored; for short ones it accounts for outages too short to
   cover an attempt and for dropouts next to outages;
4. tag outages jointly with the per-anchor outages (:func:`fit_tag_outages`): every dark run of at
   least TAG_OUTAGE_MIN_S is a tag outage or an overlap of per-anchor outages, decided by EM over the
   joint likelihood of the per-anchor chains of step 3 and the tag chain; the per-anchor fits are
   redone with the tag outages unobserved.

A descriptive table of observed outages (runs of >= 2 missed attempts) is reported beside the fit.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, logit

from ..records import Trace
from ._base import Fit, trace_label
from .attempts import AttemptTable, attempt_table
from .dropout_outage import OBSERVED_OUTAGE_MIN_MISSES, RunStats, add_runs, fit_dropout_outage
from .outage_range import anchor_runs, fit_long_outages
from .tag_outages import TAG_OUTAGE_MIN_S, anchor_sequences, dark_runs, fit_tag_outages
from .uwb_fit import geometric_range

LINK_IN_RANGE_PROB = 0.999
"""Attempts with a modelled link probability below this are left out of dropout/outage fitting."""

MIN_ATTEMPTS_BEYOND_HORIZON = 30
"""A radio horizon is identifiable only with at least this many attempts beyond it (r > R + w)."""

LINK_MIN_RANGE_M = 1e-3
"""Lower bound of the fitted horizon R: a detection probability that falls over every range seen has
its best fit at R <= 0, which no radio has; with R held >= 0 the loss floor takes the difference."""

LINK_BOUNDS = [(LINK_MIN_RANGE_M, None), (None, None), (None, None)]


def _link_nll(theta: np.ndarray, r: np.ndarray, h: np.ndarray) -> float:
    big_r, log_w, lg_e = theta
    w = np.exp(log_w)
    x = np.clip((r - big_r) / w, -50, 50)
    p = expit(-x) * (1.0 - expit(lg_e))
    p = np.clip(p, 1e-12, 1 - 1e-12)
    return float(-np.sum(np.where(h, np.log(p), np.log1p(-p))))


LINK_DEFF_BLOCKS = 5
"""The design effect of :func:`fit_link` from batch means over this many blocks per recording ..."""

LINK_DEFF_MIN_BLOCK = 20
"""... of at least this many attempts each."""


def _design_effect(u: np.ndarray, starts: np.ndarray) -> float:
    """Variance inflation of a sum of per-attempt score contributions ``u`` (time order, recordings
    starting at ``starts``) over independent ones, by batch means: each recording cut into up to
    :data:`LINK_DEFF_BLOCKS` blocks in time, the summed squared block sums over the summed squares
    (at least 1)."""
    ss = float(u @ u)
    if ss <= 0.0:
        return 1.0
    sq = 0.0
    for a, b in zip(starts, [*starts[1:], u.size], strict=True):  # a handful of recordings
        nb = int(min(LINK_DEFF_BLOCKS, (b - a) // LINK_DEFF_MIN_BLOCK))
        if nb >= 1:
            sq += sum(float(blk.sum()) ** 2 for blk in np.array_split(u[a:b], nb))  # <= 5 blocks
        else:
            sq += float(u[a:b] @ u[a:b])
    return max(1.0, sq / ss)


def fit_link(range_m: np.ndarray, heard: np.ndarray, lengths: Sequence[int] | None = None) -> dict[str, Any]:
    """Maximum-likelihood soft radio horizon P(heard) = (1 - e) / (1 + exp((r - R) / w)).

    Compared by a likelihood-ratio test with a range-independent loss; when the anchor is heard
    equally at all ranges seen (effective LR < 10) or R lies beyond them, R is not identifiable.

    ``range_m``, ``heard``: the anchor's attempts in time order, recordings one after the other, of
    ``lengths`` attempts each (default: one recording). The likelihood treats attempts as independent,
    but outages miss hundreds in a row: a few long outages that happen to fall at long range then look
    like a horizon. The LR statistic is therefore divided by the design effect of the fitted model's
    residuals (:func:`_design_effect`, batch means within each recording; a first-order Rao-Scott
    correction): a real horizon explains its own run of misses and leaves independent residuals,
    outages leave them correlated.
    """
    ok = np.isfinite(range_m)
    bounds = np.cumsum([0, *(lengths if lengths is not None else [range_m.size])])
    if int(bounds[-1]) != range_m.size:
        raise ValueError("lengths must add up to the number of attempts")
    # recording starts among the finite attempts
    starts = np.unique(np.cumsum(np.concatenate([[0], ok]))[bounds[:-1]])
    r, h = range_m[ok], heard[ok]
    out: dict[str, Any] = {"n_attempts": int(r.size), "max_range_seen_m": float(r.max()) if r.size else None,
                           "max_range_heard_m": float(r[h].max()) if h.any() else None}
    if r.size < 20 or h.all() or not h.any():
        out.update(identifiable=False, why="heard at every range seen" if h.all() else "too few attempts")
        return out
    e0 = 1.0 - h.mean()
    nll0 = _link_nll(np.array([1e9, 0.0, logit(np.clip(e0, 1e-6, 1 - 1e-6))]), r, h)
    best = None
    heard_r = r[h]
    for q in (0.9, 0.99, 1.0):  # a few starts, each a small vectorised optimisation
        x0 = np.array([np.quantile(heard_r, q), np.log(max(np.ptp(r) / 50.0, 0.5)),
                       logit(np.clip(e0 / 2, 1e-4, 0.5))])
        res = minimize(_link_nll, x0, args=(r, h), method="Nelder-Mead", bounds=LINK_BOUNDS,
                       options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 2000})
        if best is None or res.fun < best.fun:
            best = res
    lr = 2.0 * (nll0 - best.fun)
    big_r, w = float(best.x[0]), float(np.exp(best.x[1]))
    # the score of the horizon R per attempt: (h - p) / (p (1 - p)) dp/dR, dp/dR = p sigma((r - R) / w) / w
    x = np.clip((r - big_r) / w, -50, 50)
    p_fit = np.clip(expit(-x) * (1.0 - expit(best.x[2])), 1e-9, 1 - 1e-9)
    deff = _design_effect((h - p_fit) / (1.0 - p_fit) * expit(x) / w, starts)
    lr_eff = lr / deff
    beyond = r > big_r + w
    n_beyond = int(beyond.sum())
    heard_beyond = float(h[beyond].mean()) if n_beyond else float("nan")
    out.update(lr_statistic=float(lr), design_effect=deff,
               lr_effective=float(lr_eff), max_range_m=big_r, edge_width_m=w, loss_floor=float(expit(best.x[2])),
               n_attempts_beyond=n_beyond, heard_frac_beyond=heard_beyond)
    if lr_eff < 10.0:
        out.update(identifiable=False, why=f"no range dependence (LR {lr:.1f} / design effect {deff:.1f} = "
                   f"{lr_eff:.1f} < 10)")
    elif n_beyond < MIN_ATTEMPTS_BEYOND_HORIZON:
        out.update(identifiable=False, why=f"only {n_beyond} attempts beyond the fitted horizon "
                   f"({big_r:.1f} m; at least {MIN_ATTEMPTS_BEYOND_HORIZON} needed)")
    else:
        out["identifiable"] = True
    return out


def fit_outages(tabs: Sequence[AttemptTable], in_range: Sequence[np.ndarray], trace_anchor_ids: Sequence[Sequence[str]],
                anchor_ids: Sequence[str], att_period: dict[str, float],
                burst_rate_hz: float) -> tuple[dict[str, RunStats], dict[str, dict[str, Any]], dict[str, Any]]:
    """Dropout and outages per anchor and tag outages, jointly, from attempt tables (pooled over traces).

    ``in_range[i]`` (bursts x anchors of trace i) marks attempts inside link range, ``trace_anchor_ids[i]``
    names the columns of trace i, ``att_period`` is each anchor's mean attempt interval [s]. Returns the
    per-anchor run statistics and fits (with the tag outages unobserved when a tag process is kept) and the
    tag report (:func:`fit_tag_outages`).
    """
    def per_anchor_runs(exclude: list[np.ndarray]) -> dict[str, RunStats]:
        stats = {a: RunStats() for a in anchor_ids}
        for ids, tab, ok, ex in zip(trace_anchor_ids, tabs, in_range, exclude, strict=True):
            for j, aid in enumerate(ids):  # one pass per anchor
                att = tab.attempted[:, j]
                code = np.where(tab.heard[:, j], 1, 0)
                code = np.where(ok[:, j] & ~ex, code, -1)[att]
                add_runs(stats[aid], tab.t_s[att], code)
        return stats

    stats = per_anchor_runs([np.zeros(t.t_s.size, dtype=bool) for t in tabs])
    fits = {a: fit_dropout_outage(stats[a], att_period[a], burst_rate_hz) for a in anchor_ids}
    dark = [dark_runs(tab, ok) for tab, ok in zip(tabs, in_range, strict=True)]
    seqs = anchor_sequences(trace_anchor_ids, tabs, in_range)

    def refit(excl: list[np.ndarray], prev: dict[str, dict[str, Any]]) -> tuple[dict[str, RunStats], dict]:
        st = per_anchor_runs(excl)
        return st, {a: fit_dropout_outage(st[a], att_period[a], burst_rate_hz, start=prev.get(a))
                    for a in anchor_ids}

    tag, _, stats_t, fits_t = fit_tag_outages(tabs, dark, seqs, fits, refit, burst_rate_hz)
    if tag.get("onset_prob", 0.0) > 0:
        stats, fits = stats_t, fits_t
    return stats, fits, tag


def _fit_long(traces: Sequence[Trace], tabs: Sequence[AttemptTable], in_range: Sequence[np.ndarray],
              ranges: Sequence[np.ndarray], att_period: dict[str, float], *, tag_kept: bool) -> dict[str, Any]:
    """Long outages (:mod:`physynth.calibrate.outage_range`) from every placement's attempt sequence (one
    anchor in one run); the dark runs of a kept tag process (every anchor silent for TAG_OUTAGE_MIN_S or
    more) are unobserved."""
    runs = []
    for tr, tab, ok, r_all in zip(traces, tabs, in_range, ranges, strict=True):
        dark = np.zeros(tab.t_s.size + 1, dtype=np.int64)
        if tag_kept:
            s, e, _ = dark_runs(tab, ok)
            last = np.minimum(e, tab.t_s.size) - 1
            long_dark = tab.t_s[last] - tab.t_s[s] >= TAG_OUTAGE_MIN_S
            np.add.at(dark, s[long_dark], 1)
            np.add.at(dark, e[long_dark], -1)
        dark_mask = np.cumsum(dark)[:-1] > 0
        for j, aid in enumerate(tr.anchors.ids):  # one pass per anchor
            att = tab.attempted[:, j]
            code = np.where(ok[:, j] & ~dark_mask, np.where(tab.heard[:, j], 1, 0), -1)
            runs.append(anchor_runs(aid, att_period[aid], [code[att]], [r_all[att, j]]))  # one placement
    return fit_long_outages(runs)


LINK_MIN_IN_RANGE_FRAC = 0.1
"""Share of an anchor's attempts that must lie within its in-range limit; below it the limit is R itself."""


def in_range_limit(link: dict[str, Any], range_m: np.ndarray) -> float:
    """The range [m] up to which an anchor's attempts count as in link range for the dropout/outage fit:
    where the fitted link probability is :data:`LINK_IN_RANGE_PROB`, or the horizon R itself when that
    leaves fewer than :data:`LINK_MIN_IN_RANGE_FRAC` of the attempts (a soft edge as wide as the ranges
    seen); recorded in ``link`` (``in_range_limit_m``)."""
    lim = link["max_range_m"] - link["edge_width_m"] * np.log(LINK_IN_RANGE_PROB / (1 - LINK_IN_RANGE_PROB))
    r = range_m[np.isfinite(range_m)]
    if r.size and np.mean(r <= lim) < LINK_MIN_IN_RANGE_FRAC:
        link["in_range_note"] = (f"the {LINK_IN_RANGE_PROB:g} link-probability range ({lim:.1f} m) holds "
                                 f"{100 * np.mean(r <= lim):.0f} % of the attempts: attempts up to the horizon R count")
        lim = link["max_range_m"]
    link["in_range_limit_m"] = float(lim)
    return float(lim)


def fit_availability(traces: Sequence[Trace], offset_s: float, burst_rate_hz: float,
                     anchor_ids: Sequence[str]) -> Fit[dict[str, Any]]:
    """Link range, attempt rate, dropout and outages per anchor, and tag outages, pooled over traces."""
    tabs = [attempt_table(t, burst_rate_hz) for t in traces]
    period = 1.0 / burst_rate_hz
    per_anchor: dict[str, dict[str, Any]] = {}
    ranges: dict[str, list[np.ndarray]] = {a: [] for a in anchor_ids}
    heards: dict[str, list[np.ndarray]] = {a: [] for a in anchor_ids}
    att_count = dict.fromkeys(anchor_ids, 0)
    burst_count = dict.fromkeys(anchor_ids, 0)
    rng_tab = []
    for tr, tab in zip(traces, tabs, strict=True):
        r_all = np.full(tab.heard.shape, np.nan)
        for j, aid in enumerate(tr.anchors.ids):  # one pass per anchor
            att = tab.attempted[:, j]
            r = geometric_range(tr, tab.t_s - offset_s, np.full(tab.t_s.size, j))
            r_all[:, j] = r
            ranges[aid].append(r[att])
            heards[aid].append(tab.heard[att, j])
            att_count[aid] += int(att.sum())
            burst_count[aid] += tab.t_s.size
        rng_tab.append(r_all)
    links = {a: fit_link(np.concatenate(ranges[a]), np.concatenate(heards[a]), [x.size for x in ranges[a]])
             for a in anchor_ids if ranges[a]}
    limits = {a: in_range_limit(lk, np.concatenate(ranges[a])) for a, lk in links.items() if lk.get("identifiable")}
    in_range = []
    for tr, r_all in zip(traces, rng_tab, strict=True):
        ok = np.isfinite(r_all)
        for j, aid in enumerate(tr.anchors.ids):
            if aid in limits:
                ok[:, j] &= r_all[:, j] <= limits[aid]
        in_range.append(ok)

    att_period = {a: period * burst_count[a] / max(att_count[a], 1) for a in anchor_ids}
    stats, fits, tag = fit_outages(tabs, in_range, [tr.anchors.ids for tr in traces], anchor_ids, att_period,
                                   burst_rate_hz)
    long_outages = _fit_long(traces, tabs, in_range, rng_tab, att_period, tag_kept=tag.get("onset_prob", 0.0) > 0)
    for a in anchor_ids:
        st = stats[a]
        dur = np.concatenate(st.durations_s) if st.durations_s else np.zeros(0)
        cen = np.concatenate(st.censored_s) if st.censored_s else np.zeros(0)
        observed = {"min_missed_attempts": OBSERVED_OUTAGE_MIN_MISSES, "n": int(dur.size), "n_censored": int(cen.size),
                    "mean_gap_s": float(dur.mean()) if dur.size else None,
                    "censored_mle_mean_s": float((dur.sum() + cen.sum()) / dur.size) if dur.size else None}
        per_anchor[a] = {
            "attempts": att_count[a],
            "bursts": burst_count[a],
            "attempts_recorded": all(t.recorded for t in tabs),
            "attempt_prob": att_count[a] / max(burst_count[a], 1),
            "link": links.get(a, {"identifiable": False, "why": "no attempts"}),
            "dropout_outage": fits[a],
            "observed_outages": observed,
        }
    n = int(sum(att_count.values()))
    return Fit(params={"per_anchor": per_anchor, "tag": tag, "long_outages": long_outages}, n_samples=n,
               diagnostics={"attempts_recorded": [t.recorded for t in tabs],
                            "labels": [trace_label(t, i) for i, t in enumerate(traces)]})
