"""Calibration of long outages: a second, rarer outage process whose rate grows with range.

The per-anchor outage process of :mod:`physynth.calibrate.availability_fit` has exponential durations.
Real links also fade for seconds where the link margin is thin: on the shared Hanyang runs the runs of
missed attempts between two heard ones fall off geometrically (314, 151, 81, 36 runs of 3, 4, 5, 6
misses at 10 Hz), but 11 of 660 runs last 1.3 s or more where a geometric tail predicts 0.6, and 6 of
those 11 start 45-50 m from the anchor, where only 5 % of the time is spent. The availability model
(:mod:`physynth.models.availability`) adds *long outages*: per anchor, a Poisson process of onsets
with rate

    h_L(r) = long_outage_rate_per_s * exp(slope * (r - ref_range))      [1/s]

at tag-anchor range r, each lasting an exponential time of mean ``long_outage_mean_s``, overlaid on the
ordinary outages.

Estimation by maximum likelihood on the runs of at least :data:`LONG_RUN_MISSES` consecutive missed
attempts between two heard ones (runs that long are outages: a run of independent dropouts that long
has probability dropout_prob ** 3, below 1e-3 on the shared data), pooled over runs and anchors. An
outage of exponential length D (mean mu) starting uniformly inside an attempt period T covers at least
K attempts with probability p_K(mu) = exp(-(K - 1) T / mu) (1 - q) mu / T, q = exp(-T / mu), and then
misses K + Geometric(1 - q) attempts. So runs of >= K misses start at rate
h_a p_K(mu_a) + h_L(r) p_K(mu_L) per second of up time (the attempts outside such runs), and their
lengths are the matching mixture of geometric laws. The ordinary part (h_a, mu_a per anchor) is a
nuisance here (the HMM fit sets the generated values); the long part (rate, slope, mean) is site-wide.
The long process is kept when the likelihood ratio against no long process reaches
:data:`MIN_LIKELIHOOD_RATIO` (the convention of the run offsets), its slope only when the ratio
against slope 0 does too. ``ref_range`` is the median range of the exposure.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import minimize

LONG_RUN_MISSES = 3
"""Runs of at least this many consecutive missed attempts (between two heard ones) count as outages."""
MIN_LIKELIHOOD_RATIO = 10.0
"""A long process, or its slope, is kept only when 2 (log L - log L0) reaches this."""
MAX_SLOPE_PER_M = 0.5
"""Bound on the slope [1/m] during the fit (an e-folding over 2 m or more)."""
MIN_LONG_MEAN_FACTOR = 3.0
"""The long outages' mean is at least this many times the longest ordinary mean (they must be long)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class AnchorRuns:
    """One anchor's long runs and exposure, pooled over traces."""

    anchor_id: str
    period_s: float  # attempt period T [s]
    onset_range_m: np.ndarray  # (E,) range at the first missed attempt of each long run
    extra_misses: np.ndarray  # (E,) m - K
    exposure_range_m: np.ndarray  # (X,) range at every observed attempt outside a long run


def anchor_runs(anchor_id: str, period_s: float, codes: Sequence[np.ndarray], ranges: Sequence[np.ndarray],
                min_misses: int = LONG_RUN_MISSES) -> AnchorRuns:
    """Long runs of one anchor from its attempt sequences (code 1 heard, 0 missed, -1 unobserved).

    Only runs between two heard attempts with every attempt in between observed count; runs cut by an
    unobserved attempt or by the ends of the data are left out of both the events and the exposure.
    """
    onset, extra, expo = [], [], []
    for code, r in zip(codes, ranges, strict=True):
        code = np.where(np.isfinite(r), code, -1)  # no range (no truth): unobserved
        heard = np.flatnonzero(code == 1)
        if heard.size < 2:
            continue
        m = np.diff(heard) - 1
        # a run is clean when no attempt between the two heard ones is unobserved
        bad = np.concatenate([[0], np.cumsum(code < 0)])
        clean = (bad[heard[1:]] - bad[heard[:-1] + 1]) == 0
        long_run = clean & (m >= min_misses)
        onset.append(r[heard[:-1][long_run] + 1])
        extra.append(m[long_run] - min_misses)
        inside = np.zeros(code.size + 1, dtype=np.int64)  # attempts inside a long run are not exposure
        np.add.at(inside, heard[:-1][long_run] + 1, 1)
        np.add.at(inside, heard[1:][long_run], -1)
        exposed = (np.cumsum(inside)[:-1] == 0) & (code >= 0)
        exposed[: heard[0]] = False
        exposed[heard[-1] + 1:] = False
        expo.append(r[exposed])

    def cat(x: list[np.ndarray]) -> np.ndarray:
        return np.concatenate(x) if x else np.zeros(0)

    return AnchorRuns(anchor_id=anchor_id, period_s=period_s, onset_range_m=cat(onset),
                      extra_misses=cat(extra).astype(float), exposure_range_m=cat(expo))


def _log_pk(mu: np.ndarray | float, t: float, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(log P(an outage of mean mu covers >= k attempts), log q, log(1 - q)), q = exp(-t / mu)."""
    x = t / np.asarray(mu, dtype=float)
    log_1mq = np.log(-np.expm1(-x))
    return -(k - 1) * x + log_1mq - np.log(x), -x, log_1mq


@dataclass(frozen=True, slots=True)
class _Model:
    long: bool = False  # a long-outage process at all
    slope: bool = False  # its rate depends on range
    frailty: bool = False  # its rate is scaled per placement by G ~ Gamma(k, 1/k)


_G_GRID = np.logspace(-4.0, 3.0, 141)
"""Grid of the frailty G for the integral over its Gamma law; G below the grid counts as G = 0."""


def _frailty_log_weights(log_k: float) -> tuple[float, np.ndarray]:
    """log prior mass of G < grid (taken as G = 0) and log weights of the grid points (trapezoids in log G)."""
    from scipy import stats

    k = float(np.exp(log_k))
    law = stats.gamma(a=k, scale=1.0 / k)
    m0 = float(law.cdf(_G_GRID[0]))
    dens = law.logpdf(_G_GRID) + np.log(_G_GRID)  # density in log G
    h = np.diff(np.log(_G_GRID))
    tw = np.zeros(_G_GRID.size)
    tw[:-1] += h / 2.0
    tw[1:] += h / 2.0
    logw = dens + np.log(tw)
    total = np.logaddexp(np.log(max(m0, 1e-300)), np.logaddexp.reduce(logw))
    return np.log(max(m0, 1e-300)) - total, logw - total  # renormalised: the grid's ends are cut


def _neg_loglik(theta: np.ndarray, runs: Sequence[AnchorRuns], ids: Sequence[str], r_ref: float, k: int,
                model: _Model) -> float:
    """Minus the log likelihood of the long runs of every placement (one anchor in one run)."""
    col = {a: i for i, a in enumerate(ids)}
    nuis = theta[: 2 * len(ids)]
    rest = list(theta[2 * len(ids):])
    log_rate_l = rest.pop(0) if model.long else -np.inf
    log_mu_l = rest.pop(0) if model.long else 0.0
    slope = rest.pop(0) if model.slope else 0.0
    fr = _frailty_log_weights(rest.pop(0)) if model.frailty else None
    nll = 0.0
    for a in runs:
        t = a.period_s
        log_h, log_mu = nuis[2 * col[a.anchor_id]], nuis[2 * col[a.anchor_id] + 1]
        lpk_s, lq_s, l1q_s = _log_pk(np.exp(log_mu), t, k)
        nll += float(np.exp(log_h + lpk_s) * a.exposure_range_m.size * t)
        short = log_h + lpk_s + l1q_s + a.extra_misses * lq_s  # log(rate x P(length)) of each run
        if not model.long:
            nll -= float(np.sum(short))
            continue
        lpk_l, lq_l, l1q_l = _log_pk(np.exp(log_mu_l), t, k)
        e_long = float(np.sum(np.exp(log_rate_l + slope * (a.exposure_range_m - r_ref) + lpk_l))) * t
        long_ = log_rate_l + slope * (a.onset_range_m - r_ref) + lpk_l + l1q_l + a.extra_misses * lq_l
        if fr is None:
            nll += e_long - float(np.sum(np.logaddexp(short, long_)))
            continue
        log_m0, logw = fr  # integrate the placement's likelihood over its frailty G
        at0 = float(np.sum(short))
        per_g = np.logaddexp(short[:, None], long_[:, None] + np.log(_G_GRID)[None, :]).sum(axis=0)
        per_g = per_g - _G_GRID * e_long + logw
        nll -= float(np.logaddexp(log_m0 + at0, np.logaddexp.reduce(per_g)))
    return nll


MAX_FRAILTY_SHAPE = 50.0
"""Upper bound of the frailty shape k (placements all alike: no frailty kept)."""


def _fit(runs: Sequence[AnchorRuns], ids: Sequence[str], r_ref: float, k: int, model: _Model,
         start: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    x0, bounds = [], []
    for aid in ids:
        mine = [a for a in runs if a.anchor_id == aid]
        span = max(sum(a.exposure_range_m.size * a.period_s for a in mine), 1e-3)
        n = sum(a.onset_range_m.size for a in mine)
        extra = np.concatenate([a.extra_misses for a in mine])
        period = mine[0].period_s
        x0 += [np.log(max(n, 0.5) / span) + 1.0, np.log(period * (1.0 + (float(extra.mean()) if extra.size else 0.5)))]
        bounds += [(-30.0, 10.0), (np.log(period) - 5.0, np.log(period) + 5.0)]
    longest = max(a.period_s for a in runs) * 200.0
    if model.long:
        x0 += [np.log(1e-3), np.log(2.0)]
        bounds += [(-30.0, 5.0), (np.log(0.3), np.log(longest))]
    if model.slope:
        x0 += [0.0]
        bounds += [(-MAX_SLOPE_PER_M, MAX_SLOPE_PER_M)]
    if model.frailty:
        x0 += [0.0]
        bounds += [(np.log(0.02), np.log(MAX_FRAILTY_SHAPE))]
    x = np.array(x0) if start is None else np.asarray(start, dtype=float)
    res = minimize(_neg_loglik, x, args=(runs, ids, r_ref, k, model), method="L-BFGS-B", bounds=bounds)
    return res.x, float(res.fun)


def fit_long_outages(runs: Sequence[AnchorRuns], *, min_misses: int = LONG_RUN_MISSES) -> dict[str, Any]:
    """The long-outage process (module docstring) from runs of missed attempts, one AnchorRuns per placement.

    A *placement* is one anchor in one run (pass one :class:`AnchorRuns` per placement; the ordinary
    outages are per anchor id, pooled over its placements). Returns a report with ``identifiable``;
    when true ``rate_per_s`` (at ``ref_range_m``), ``mean_s``, ``range_slope_per_m`` (0 when the slope
    is not kept), ``frailty_shape`` (None when not kept) and the likelihood ratios ``lr_long`` (long
    process against none), ``lr_slope`` (slope against none) and ``lr_frailty`` (placements differing
    against all alike).
    """
    used = [a for a in runs if a.exposure_range_m.size > 0]
    n_events = int(sum(a.onset_range_m.size for a in used))
    out: dict[str, Any] = {"min_missed_attempts": min_misses, "n_runs": n_events, "n_placements": len(used),
                           "identifiable": False}
    if n_events < 10:
        out["why"] = f"{n_events} runs of >= {min_misses} missed attempts (need 10)"
        return out
    ids = list(dict.fromkeys(a.anchor_id for a in used))
    r_ref = float(np.median(np.concatenate([a.exposure_range_m for a in used])))
    th0, nll0 = _fit(used, ids, r_ref, min_misses, _Model())
    th1, nll1 = _fit(used, ids, r_ref, min_misses, _Model(long=True), start=np.r_[th0, np.log(1e-3), np.log(2.0)])
    th2, nll2 = _fit(used, ids, r_ref, min_misses, _Model(long=True, slope=True), start=np.r_[th1, 0.0])
    keep_slope = 2.0 * (nll1 - nll2) >= MIN_LIKELIHOOD_RATIO
    th_s, nll_s = (th2, nll2) if keep_slope else (th1, nll1)
    th3, nll3 = _fit(used, ids, r_ref, min_misses, _Model(long=True, slope=keep_slope, frailty=True),
                     start=np.r_[th_s, 0.0])
    keep_frailty = len(used) > 1 and 2.0 * (nll_s - nll3) >= MIN_LIKELIHOOD_RATIO
    th, nll_best = (th3, nll3) if keep_frailty else (th_s, nll_s)
    n_a = len(ids)
    mu_ord = float(np.exp(th[1:2 * n_a:2]).max())  # the ordinary outages of the model with long ones
    mean_l = float(np.exp(th[2 * n_a + 1]))
    out.update(ref_range_m=r_ref, max_range_m=float(max(a.exposure_range_m.max() for a in used)),
               lr_long=2.0 * (nll0 - nll_best), lr_slope=2.0 * (nll1 - nll2), lr_frailty=2.0 * (nll_s - nll3),
               ordinary_mean_s_max=mu_ord, rate_per_s=float(np.exp(th[2 * n_a])), mean_s=mean_l,
               range_slope_per_m=float(th[2 * n_a + 2]) if keep_slope else 0.0,
               frailty_shape=float(np.exp(th[-1])) if keep_frailty else None)
    if not out["lr_long"] >= MIN_LIKELIHOOD_RATIO:
        out["why"] = f"likelihood ratio {out['lr_long']:.3g} < {MIN_LIKELIHOOD_RATIO:g}: no long outages"
    elif mean_l < MIN_LONG_MEAN_FACTOR * mu_ord:
        out["why"] = f"long mean {mean_l:.3g} s is not {MIN_LONG_MEAN_FACTOR:g} x the ordinary {mu_ord:.3g} s"
    else:
        out["identifiable"] = True
    return out
