"""Calibration of availability: link range, per-burst dropout, outage onset and duration, tag outages.

The generator (:mod:`physynth.availability`, :mod:`physynth.uwb`) lets each anchor alternate between
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
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, logit

from ..records import Reason, Trace
from ._base import Fit, trace_label
from .outage_range import anchor_runs, fit_long_outages
from .uwb_fit import burst_ids, geometric_range

LINK_IN_RANGE_PROB = 0.999
"""Attempts with a modelled link probability below this are left out of dropout/outage fitting."""
MIN_ATTEMPTS_BEYOND_HORIZON = 30
"""A radio horizon is identifiable only with at least this many attempts beyond it (r > R + w)."""
OBSERVED_OUTAGE_MIN_MISSES = 2
"""Descriptive outage table: runs of at least this many consecutive missed attempts."""
TAG_OUTAGE_MIN_S = 1.0
"""Dark runs (no in-range anchor heard) at least this long [s] are candidate tag outages; shorter ones are
left to coincident dropouts and outages (the tag durations are fitted left-truncated here)."""


# --------------------------------------------------------------------------------------------------
# Attempts
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class AttemptTable:
    """Ranging attempts of one trace on its burst grid: times (B,), attempted/heard (B, A)."""

    t_s: np.ndarray
    attempted: np.ndarray
    heard: np.ndarray
    recorded: bool  # True: attempt rows were in the data; False: inferred from the burst schedule
    burst_rate_hz: float


def has_attempt_rows(trace: Trace) -> bool:
    """Whether a trace records failed attempts (dropout/outage/no-link rows), as synthetic traces do."""
    r = trace.uwb.reason
    return bool(np.isin(r, (Reason.DROPOUT, Reason.OUTAGE, Reason.NO_LINK)).any())


def attempt_table(trace: Trace, burst_rate_hz: float) -> AttemptTable:
    """The (burst x anchor) attempt and heard matrices of a trace.

    With recorded attempt rows, every row is an attempt of its burst. Without, every anchor is taken
    as attempted in every burst (SOURCE.md: all Hanyang anchors are ranged in one burst) and bursts
    missing from the data (no row at all) are filled in on the burst period.
    """
    u = trace.uwb
    n_a = len(trace.anchors)
    b = burst_ids(trace)
    ids, inv = np.unique(b, return_inverse=True)
    nb = ids.size
    start = np.full(nb, np.inf)
    np.minimum.at(start, inv, u.t_s)
    recorded = has_attempt_rows(trace)
    if recorded:
        attempted = np.zeros((nb, n_a), dtype=bool)
        heard = np.zeros((nb, n_a), dtype=bool)
        attempted[inv, u.anchor] = True
        ok = u.valid
        heard[inv[ok], u.anchor[ok]] = True
        return AttemptTable(t_s=start, attempted=attempted, heard=heard, recorded=True,
                            burst_rate_hz=burst_rate_hz)
    ok = u.valid
    has_valid = np.zeros(nb, dtype=bool)
    has_valid[inv[ok]] = True
    # bursts with no valid row are not evidence of a burst: rebuild the grid from bursts with data
    keep = np.flatnonzero(has_valid)
    st = start[keep]
    period = 1.0 / burst_rate_hz
    k = np.maximum(np.round(np.diff(st) / period).astype(np.int64), 1)
    n_new = np.concatenate([[1], k])  # grid slots from the previous kept burst to this one
    pos = np.cumsum(n_new) - 1  # grid index of each kept burst
    total = int(pos[-1]) + 1
    grid_t = np.interp(np.arange(total), pos, st)
    remap = np.full(nb, -1)
    remap[keep] = pos
    heard = np.zeros((total, n_a), dtype=bool)
    rows = ok & (remap[inv] >= 0)
    heard[remap[inv[rows]], u.anchor[rows]] = True
    return AttemptTable(t_s=grid_t, attempted=np.ones((total, n_a), dtype=bool), heard=heard, recorded=False,
                        burst_rate_hz=burst_rate_hz)


# --------------------------------------------------------------------------------------------------
# Link range
# --------------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------------
# Dropout / outage: the sampled alternating process as a hidden Markov chain
# --------------------------------------------------------------------------------------------------


@dataclass(slots=True)
class RunStats:
    """Run-length statistics of one anchor's observed attempt blocks (pooled over traces)."""

    internal: list[np.ndarray] = field(default_factory=list)  # misses between two heard attempts
    leading: list[np.ndarray] = field(default_factory=list)  # misses before the first heard of a block
    trailing: list[np.ndarray] = field(default_factory=list)  # misses after the last heard of a block
    full: list[np.ndarray] = field(default_factory=list)  # blocks without any heard attempt
    n_attempts: int = 0
    n_heard: int = 0
    span_s: float = 0.0
    durations_s: list[np.ndarray] = field(default_factory=list)  # descriptive: gaps of runs >= 2 misses
    censored_s: list[np.ndarray] = field(default_factory=list)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        def cat(x: list[np.ndarray]) -> np.ndarray:
            return np.concatenate(x).astype(np.int64) if x else np.zeros(0, np.int64)

        return cat(self.internal), cat(self.leading), cat(self.trailing), cat(self.full)


def add_runs(stats: RunStats, t_s: np.ndarray, code: np.ndarray) -> None:
    """Add one anchor's attempt sequence: code 1 heard, 0 missed, -1 unobserved (splits blocks)."""
    obs = code >= 0
    if not obs.any():
        return
    stats.n_attempts += int(obs.sum())
    stats.n_heard += int((code == 1).sum())
    start_flag = obs & ~np.concatenate([[False], obs[:-1]])
    end_flag = obs & ~np.concatenate([obs[1:], [False]])
    b_start, b_end = np.flatnonzero(start_flag), np.flatnonzero(end_flag) + 1
    block = np.cumsum(start_flag) - 1  # block id of each (observed) position
    heard_idx = np.flatnonzero(code == 1)
    hb = block[heard_idx]
    # internal runs: consecutive heard positions in the same block
    same = np.diff(hb) == 0
    stats.internal.append((np.diff(heard_idx) - 1)[same])
    gaps_t = np.diff(t_s[heard_idx])[same]
    m_int = (np.diff(heard_idx) - 1)[same]
    stats.durations_s.append(gaps_t[m_int >= OBSERVED_OUTAGE_MIN_MISSES])
    # first / last heard per block
    first = np.full(b_start.size, -1)
    last = np.full(b_start.size, -1)
    if heard_idx.size:
        uniq, fi = np.unique(hb, return_index=True)
        first[uniq] = heard_idx[fi]
        _, li = np.unique(hb[::-1], return_index=True)
        last[uniq] = heard_idx[::-1][li]
    has = first >= 0
    stats.leading.append((first - b_start)[has])
    trail = (b_end - 1 - last)[has]
    stats.trailing.append(trail)
    cens = trail >= OBSERVED_OUTAGE_MIN_MISSES
    stats.censored_s.append((t_s[np.minimum(b_end - 1, t_s.size - 1)] - t_s[last])[has][cens])
    stats.full.append((b_end - b_start)[~has])
    stats.span_s += float(np.sum(t_s[b_end - 1] - t_s[b_start]))


def _matpow_rows(b: np.ndarray, v: np.ndarray, m: np.ndarray) -> np.ndarray:
    """v B^m for a 2x2 matrix B, a row vector v (2,) and integer powers m (N,) -> (N, 2) (Sylvester)."""
    tr, det = np.trace(b), np.linalg.det(b)
    disc = max(tr * tr / 4.0 - det, 0.0)
    l1, l2 = tr / 2.0 + np.sqrt(disc), tr / 2.0 - np.sqrt(disc)
    vb = v @ b
    m = m.astype(float)
    if abs(l1 - l2) < 1e-12:
        # repeated eigenvalue: B^m = l^(m-1) (m B - (m-1) l I)
        lm1 = np.where(m > 0, l1 ** np.maximum(m - 1, 0), 0.0)
        return np.where(m[:, None] == 0, v, lm1[:, None] * (m[:, None] * vb - (m - 1)[:, None] * l1 * v))
    p1, p2 = l1**m, l2**m
    return ((p1[:, None] * (vb - l2 * v) - p2[:, None] * (vb - l1 * v)) / (l1 - l2))


def _chain(alpha: float, beta: float, pd: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    a = np.array([[1.0 - alpha, alpha], [beta, 1.0 - beta]])
    dm = np.diag([pd, 1.0])
    dh = np.array([1.0 - pd, 0.0])
    pi = np.array([beta, alpha]) / (alpha + beta) if alpha + beta > 0 else np.array([1.0, 0.0])
    return a, dm, dh, pi


def _hmm_loglik(alpha: float, beta: float, pd: float, runs: tuple[np.ndarray, ...]) -> float:
    internal, leading, trailing, full = runs
    a, dm, dh, pi = _chain(alpha, beta, pd)
    b = a @ dm
    up = np.array([1.0, 0.0])
    ahd = a @ dh
    ll = 0.0
    if internal.size:
        vals, cnt = np.unique(internal, return_counts=True)
        ll += float(np.sum(cnt * np.log(np.maximum(_matpow_rows(b, up, vals) @ ahd, 1e-300))))
    if leading.size:
        vals, cnt = np.unique(leading, return_counts=True)
        start = pi @ dm  # leading run l >= 1: pi Dm B^(l-1) A Dh 1; l = 0: pi Dh 1
        p = np.where(vals == 0, pi @ dh, _matpow_rows(b, start, np.maximum(vals - 1, 0)) @ ahd)
        ll += float(np.sum(cnt * np.log(np.maximum(p, 1e-300))))
    if trailing.size:
        vals, cnt = np.unique(trailing, return_counts=True)
        ll += float(np.sum(cnt * np.log(np.maximum(_matpow_rows(b, up, vals).sum(axis=1), 1e-300))))
    if full.size:
        vals, cnt = np.unique(full, return_counts=True)
        p = _matpow_rows(b, pi @ dm, np.maximum(vals - 1, 0)).sum(axis=1)
        ll += float(np.sum(cnt * np.log(np.maximum(p, 1e-300))))
    return ll


def _to_rates(alpha: float, beta: float, period_s: float) -> tuple[float, float]:
    """(onset rate [1/s], outage mean [s]) of the continuous process whose T-step matrix has alpha, beta."""
    s = alpha + beta
    if alpha <= 0:
        return 0.0, float("inf")
    total = -np.log(max(1.0 - s, 1e-300)) / period_s
    lam = alpha / s * total
    nu = beta / s * total
    return float(lam), float(1.0 / nu) if nu > 0 else float("inf")


def _from_rates(lam: float, mean_s: float, period_s: float) -> tuple[float, float]:
    nu = 1.0 / mean_s
    s = lam + nu
    f = 1.0 - np.exp(-s * period_s)
    return lam / s * f, nu / s * f


def fit_dropout_outage(stats: RunStats, period_s: float, burst_rate_hz: float,
                       start: dict[str, Any] | None = None) -> dict[str, Any]:
    """ML dropout probability, outage onset per burst and outage mean from run-length statistics.

    ``start``: an earlier fit of the same anchor (on slightly different data) to start the search from.
    """
    runs = stats.arrays()
    n_att, n_heard = stats.n_attempts, stats.n_heard
    out: dict[str, Any] = {"n_attempts": n_att, "n_heard": n_heard, "attempt_period_s": period_s}
    if n_att == 0:
        out.update(identifiable=False, why="no attempt within link range to fit dropouts and outages on")
        return out
    miss_frac = 1.0 - n_heard / n_att
    # dropout-only model (alpha = 0): closed form
    pd0 = float(np.clip(miss_frac, 1e-9, 1 - 1e-9))
    ll0 = (n_att - n_heard) * np.log(pd0) + n_heard * np.log(1 - pd0)

    def nll(theta: np.ndarray) -> float:
        al, be, pd = expit(theta)
        return -_hmm_loglik(al, be, pd, runs)

    best = None
    starts = [(0.01, 0.3, 0.5 * miss_frac), (0.001, 0.05, 0.8 * miss_frac), (0.05, 0.6, 0.1 * miss_frac),
              (1e-4, 0.005, 0.5 * miss_frac)]
    if start is not None and start.get("identifiable") and start.get("outage_onset_prob", 0.0) > 0:
        a0, b0 = _from_rates(start["outage_onset_prob"] * burst_rate_hz, start["outage_mean_s"], period_s)
        starts = [(a0, b0, start["dropout_prob"]), starts[0]]
    for a0, b0, d0 in starts:  # a few starts of a 3-parameter optimisation
        x0 = logit(np.clip([a0, b0, d0], 1e-6, 1 - 1e-6))
        res = minimize(nll, x0, method="Nelder-Mead", options={"xatol": 1e-7, "fatol": 1e-9, "maxiter": 4000})
        if best is None or res.fun < best.fun:
            best = res
    alpha, beta, pd = (float(x) for x in expit(best.x))
    lr = 2.0 * (-best.fun - ll0)
    lam, mean_s = _to_rates(alpha, beta, period_s)
    out.update(log_likelihood=float(-best.fun), log_likelihood_dropout_only=float(ll0), lr_outage=float(lr),
               missed_frac=miss_frac)
    if lr < 10.0:
        out.update(identifiable=False, dropout_prob=pd0, outage_onset_prob=0.0, outage_mean_s=None,
                   why=f"no evidence of outages beyond independent dropouts (LR {lr:.1f} < 10)")
        out["dropout_prob_se"] = float(np.sqrt(pd0 * (1 - pd0) / n_att))
        return out
    onset = lam / burst_rate_hz
    span_s = n_att * period_s  # the time this anchor was observed, over all runs
    if not mean_s <= span_s:  # longer, or infinite (the outage state never left)
        # the outages outlast the recording (one covers a whole run, none ends): the likelihood keeps
        # growing with the mean, which the data bounds only from below; keep the recorded span
        out.update(identifiable=True, dropout_prob=pd, outage_onset_prob=onset, outage_mean_s=span_s,
                   outage_mean_censored=True, outage_mean_ml_s=float(min(mean_s, 1e300)),
                   why=(f"the outages outlast the recording: mean outage length set to the {span_s:.0f} s "
                        "observed (a lower bound)"))
        return out
    out.update(identifiable=True, dropout_prob=pd, outage_onset_prob=onset, outage_mean_s=mean_s)
    out.update(_hmm_standard_errors(pd, onset, mean_s, period_s, burst_rate_hz, runs))
    return out


def _hmm_standard_errors(pd: float, onset: float, mean_s: float, period_s: float, burst_rate_hz: float,
                         runs: tuple[np.ndarray, ...]) -> dict[str, float]:
    """Standard errors from the inverse numerical Hessian of the log-likelihood in log-parameters."""
    x0 = np.log([max(pd, 1e-9), onset, mean_s])

    def ll(x: np.ndarray) -> float:
        p, o, m = np.exp(x)
        if p >= 1:
            return -1e300
        al, be = _from_rates(o * burst_rate_hz, m, period_s)
        return _hmm_loglik(al, be, p, runs)

    h = 1e-3
    n = 3
    hess = np.zeros((n, n))
    f0 = ll(x0)
    for i in range(n):  # 3 x 3 finite differences
        for j in range(i, n):
            ei, ej = np.eye(n)[i] * h, np.eye(n)[j] * h
            if i == j:
                v = (ll(x0 + ei) - 2 * f0 + ll(x0 - ei)) / h**2
            else:
                v = (ll(x0 + ei + ej) - ll(x0 + ei - ej) - ll(x0 - ei + ej) + ll(x0 - ei - ej)) / (4 * h * h)
            hess[i, j] = hess[j, i] = v
    try:
        cov = np.linalg.inv(-hess)
        rel = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        rel = np.full(n, np.nan)
    if pd < 1e-6:
        rel[0] = np.nan
    return {"dropout_prob_se": float(pd * rel[0]), "outage_onset_prob_se": float(onset * rel[1]),
            "outage_mean_s_se": float(mean_s * rel[2])}


# --------------------------------------------------------------------------------------------------
# Per-anchor and tag-level availability of a set of traces
# --------------------------------------------------------------------------------------------------


def _dark_runs(tab: AttemptTable, in_range: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs of bursts where no anchor is heard, each with at least one burst where an anchor is in range.

    Bursts without any in-range attempt do not end a run (they say nothing about the tag). Returns
    (start index, end index exclusive, censored) of each run; censored runs touch the data's ends.
    """
    any_heard = tab.heard.any(axis=1)
    any_in = (in_range & tab.attempted).any(axis=1)
    x = np.concatenate([[0], (~any_heard).astype(np.int8), [0]])
    d = np.diff(x)
    s, e = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    n_in = np.concatenate([[0], np.cumsum(any_in & ~any_heard)])
    keep = n_in[e] > n_in[s]
    s, e = s[keep], e[keep]
    cens = (s == 0) | (e == any_heard.size)
    return s, e, cens


@dataclass(frozen=True, slots=True)
class AnchorSequence:
    """One anchor's attempts in one trace: burst index of each attempt, code 1 heard / 0 missed / -1 out of range."""

    trace: int
    anchor_id: str
    burst: np.ndarray
    code: np.ndarray


def _anchor_sequences(trace_anchor_ids: Sequence[Sequence[str]], tabs: Sequence[AttemptTable],
                      in_range: Sequence[np.ndarray]) -> list[AnchorSequence]:
    out = []
    for i, (ids, tab, ok) in enumerate(zip(trace_anchor_ids, tabs, in_range, strict=True)):
        for j, aid in enumerate(ids):  # one pass per anchor
            att = np.flatnonzero(tab.attempted[:, j])
            code = np.where(ok[att, j], np.where(tab.heard[att, j], 1, 0), -1).astype(np.int8)
            out.append(AnchorSequence(trace=i, anchor_id=aid, burst=att, code=code))
    return out


def _log_vbw(b: np.ndarray, v: np.ndarray, w: np.ndarray, m: np.ndarray) -> np.ndarray:
    """log(v B^m w) for a non-negative 2x2 matrix B and integer powers m (N,), in log space (no underflow)."""
    m = np.asarray(m, dtype=float)
    tr, det = np.trace(b), np.linalg.det(b)
    disc = max(tr * tr / 4.0 - det, 0.0)
    l1, l2 = tr / 2.0 + np.sqrt(disc), tr / 2.0 - np.sqrt(disc)  # l1 >= |l2| (Perron-Frobenius)
    vw, vbw = float(v @ w), float(v @ b @ w)
    l1 = max(l1, 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        if l1 - l2 < 1e-9 * l1:  # repeated eigenvalue: v B^m w = l^(m-1) (m vBw - (m-1) l vw)
            val = np.where(m == 0, vw, (m * vbw - (m - 1) * l1 * vw) / l1)
        else:
            r = l2 / l1
            c1, c2 = (vbw - l2 * vw) / (l1 - l2), (l1 * vw - vbw) / (l1 - l2)
            val = c1 + c2 * np.sign(r) ** m * np.abs(r) ** m
        return m * np.log(l1) + np.log(np.maximum(val, 1e-300))


def _run_logp(alpha: float, beta: float, pd: float, kind: str, m: np.ndarray) -> np.ndarray:
    """Log-probability of runs of m missed attempts of one anchor (the kinds of :class:`RunStats`).

    internal: heard, m misses, heard (the first heard not counted); leading: block start, m misses,
    heard; trailing: heard, m misses, block end; full: block start, m misses, block end (m = 0: no block).
    """
    a, dm, dh, pi = _chain(alpha, beta, pd)
    b = a @ dm
    up, one = np.array([1.0, 0.0]), np.ones(2)
    m = np.asarray(m, dtype=np.int64)
    mm1 = np.maximum(m - 1, 0)
    if kind == "internal":
        return _log_vbw(b, up, a @ dh, m)
    if kind == "trailing":
        return _log_vbw(b, up, one, m)
    if kind == "leading":
        return np.where(m == 0, np.log(max(float(pi @ dh), 1e-300)), _log_vbw(b, pi @ dm, a @ dh, mm1))
    if kind == "full":
        return np.where(m == 0, 0.0, _log_vbw(b, pi @ dm, one, mm1))
    raise ValueError(kind)


def _chain_of_fit(fit: dict[str, Any], burst_rate_hz: float) -> tuple[float, float, float]:
    """(alpha, beta, dropout) per attempt interval of a per-anchor fit (alpha = 0: no outages)."""
    pd = float(np.clip(fit.get("dropout_prob", 0.0), 1e-9, 1 - 1e-9))
    if fit.get("identifiable") and fit.get("outage_onset_prob", 0.0) > 0 and fit.get("outage_mean_s"):
        al, be = _from_rates(fit["outage_onset_prob"] * burst_rate_hz, fit["outage_mean_s"], fit["attempt_period_s"])
        return al, be, pd
    return 0.0, 1.0, pd


def _run_neighbours(seq: AnchorSequence, s: np.ndarray, e: np.ndarray, masked: np.ndarray) -> dict[str, np.ndarray]:
    """Where the anchor's run of misses through each dark run [s, e) begins and ends (attempt indices).

    ``prev`` / ``nxt``: its last / next attempt with a code other than "missed" before / from the run
    (-1 / n when none), whether those were heard, and ``use``: the anchor is in link range over the
    whole run and attempted in it (an anchor out of range during part of run k says nothing about it).
    ``masked`` (bursts) marks the dark runs currently attributed to the tag: they bound the runs.
    """
    burst, code0 = seq.burst, seq.code
    code = np.where(masked[burst], -1, code0)
    ps, pe = np.searchsorted(burst, s), np.searchsorted(burst, e)  # its attempts inside [s, e)
    oor = np.concatenate([[0], np.cumsum(code0 == -1)])
    nz = np.flatnonzero(code != 0)
    n = code.size
    ip = np.searchsorted(nz, ps) - 1
    has_prev = ip >= 0
    prev = np.where(has_prev, nz[np.maximum(ip, 0)] if nz.size else -1, -1)
    inx = np.searchsorted(nz, pe)
    has_next = inx < nz.size
    nxt = np.where(has_next, nz[np.minimum(inx, nz.size - 1)] if nz.size else n, n)
    return {"ps": ps, "pe": pe, "prev": prev, "nxt": nxt, "use": (pe > ps) & (oor[pe] == oor[ps]),
            "left_heard": has_prev & (code[np.maximum(prev, 0)] == 1),
            "right_heard": has_next & (code[np.minimum(nxt, n - 1)] == 1)}


def _split_logp(chain: tuple[float, float, float], heard: np.ndarray, m: np.ndarray, side: str) -> np.ndarray:
    """Log-probability of the piece of an anchor's run of misses on one side of a tag outage: m misses
    after a heard attempt (or the block start) up to the outage (``left``), or from the outage's end to
    a heard attempt (or the block end) (``right``)."""
    al, be, pd = chain
    cut = "trailing" if side == "left" else "leading"
    return np.where(heard, _run_logp(al, be, pd, cut, m), _run_logp(al, be, pd, "full", m))


def _whole_logp(chain: tuple[float, float, float], lh: np.ndarray, rh: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Log-probability of an anchor's whole run of m misses through a dark run (no tag outage)."""
    al, be, pd = chain
    out = np.zeros(m.shape)
    for lft in (False, True):  # the four kinds of run
        for rgt in (False, True):
            sel = (lh == lft) & (rh == rgt)
            if sel.any():
                kind = {(True, True): "internal", (True, False): "trailing", (False, True): "leading",
                        (False, False): "full"}[(lft, rgt)]
                out[sel] = _run_logp(al, be, pd, kind, m[sel])
    return out


def _tag_log_odds_parts(p: np.ndarray, q: np.ndarray, n_bursts: int, alpha: float, beta: float
                        ) -> tuple[np.ndarray, np.ndarray]:
    """The tag chain's log-odds of "off exactly over [p, q), up around it" against "up throughout",
    split as T_p(p) + T_q(q) (it depends on the outage's length only linearly)."""
    lo_a, lo_1a = np.log(max(alpha, 1e-300)), np.log1p(-min(alpha, 1 - 1e-12))
    lo_b, lo_1b = np.log(max(beta, 1e-300)), np.log1p(-min(beta, 1 - 1e-12))
    pi_off = alpha / (alpha + beta)
    d = lo_1b - lo_1a
    at0 = p == 0
    t_p = (np.where(at0, np.log(max(pi_off, 1e-300)) + lo_1a - np.log1p(-min(pi_off, 1 - 1e-12)), lo_a)
           - p * d - lo_1b - lo_1a)
    t_q = np.where(q < n_bursts, lo_b, lo_1a) + q * d
    return t_p, t_q


def _tag_log_odds(s: np.ndarray, e: np.ndarray, n_bursts: int, alpha: float, beta: float) -> np.ndarray:
    """log P(tag off exactly over [s, e), up around it) - log P(tag up throughout), per burst-grid run."""
    t_p, t_q = _tag_log_odds_parts(s, e, n_bursts, alpha, beta)
    return t_p + t_q


def _boundary_positions(s: np.ndarray, e: np.ndarray, min_len: int) -> tuple[np.ndarray, ...]:
    """Every possible start p in [s_k, e_k - min_len] and end q in [s_k + min_len, e_k] of a tag outage
    inside each dark run k: (p, run of p, q, run of q), flat over the runs."""
    n_pos = np.maximum(e - s - min_len + 1, 0)
    run = np.repeat(np.arange(s.size), n_pos)
    off = np.arange(run.size) - np.repeat(np.cumsum(n_pos) - n_pos, n_pos)
    return s[run] + off, run, s[run] + min_len + off, run


def _anchor_boundary_terms(seq: AnchorSequence, s: np.ndarray, e: np.ndarray, masked: np.ndarray,
                           chain: tuple[float, float, float], pos: tuple[np.ndarray, ...]
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One anchor's log-likelihood terms of a tag outage over [p, q) inside each dark run [s, e).

    Its attempts in [p, q) are unobserved; its misses from the dark run's start to p end a trailing
    piece, those from q to the run's end begin a leading one: f(p) + g(q). Returns (f at every start of
    ``pos``, g at every end, the log-probability of the whole run without tag outage), zero where the
    anchor says nothing about the run.
    """
    nb = _run_neighbours(seq, s, e, masked)
    p, rp, q, rq = pos
    m1 = np.searchsorted(seq.burst, p) - nb["prev"][rp] - 1
    m2 = nb["nxt"][rq] - np.searchsorted(seq.burst, q)
    m0 = nb["nxt"] - nb["prev"] - 1
    use = nb["use"]
    f = np.where(use[rp], _split_logp(chain, nb["left_heard"][rp], m1, "left"), 0.0)
    g = np.where(use[rq], _split_logp(chain, nb["right_heard"][rq], m2, "right"), 0.0)
    whole = np.where(use, _whole_logp(chain, nb["left_heard"], nb["right_heard"], m0), 0.0)
    return f, g, whole


def _tag_posterior(s: np.ndarray, e: np.ndarray, n_bursts: int, f: np.ndarray, g: np.ndarray, whole: np.ndarray,
                   pos: tuple[np.ndarray, ...], tag_chain: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Log-odds that each dark run holds a tag outage, and the outage's expected length [bursts] if so.

    The outage may begin after the run's start and end before its end (the anchors' own outages and
    dropouts then fill the edges: the run is longer than the tag outage). Summed over every [p, q)
    with q - p >= the minimum length: the terms separate as A(p) + B(q), so the sum over p <= q - min
    is a running log-sum (one pass per run, over its bursts).
    """
    p, rp, q, rq = pos
    t_p, t_q = _tag_log_odds_parts(p, q, n_bursts, *tag_chain)
    a_all, b_all = f + t_p, g + t_q
    odds, length = np.full(s.size, -np.inf), (e - s).astype(float)
    bounds = np.searchsorted(rp, np.arange(s.size + 1))  # rp and rq share the same run blocks
    for k in np.flatnonzero(np.diff(bounds) > 0):  # one pass per dark run, vectorised over its bursts
        sl = slice(bounds[k], bounds[k + 1])
        a, b = a_all[sl], b_all[sl]  # start j pairs with ends j' >= j (q - p >= min_len)
        pre = np.logaddexp.accumulate(a)  # log sum of exp(a) over starts up to j
        suf = np.logaddexp.accumulate(b[::-1])[::-1]  # log sum of exp(b) over ends from j
        z = float(np.logaddexp.reduce(b + pre))
        e_q = float(np.sum(q[sl] * np.exp(b + pre - z)))
        e_p = float(np.sum(p[sl] * np.exp(a + suf - z)))
        odds[k] = z - float(whole[k])
        length[k] = e_q - e_p
    return odds, length


def _tag_m_step(tabs: Sequence[AttemptTable], dark: Sequence[tuple[np.ndarray, ...]], w: list[np.ndarray],
                period: float, lengths: list[np.ndarray] | None = None) -> dict[str, Any]:
    """Exponential tag outages seen only above TAG_OUTAGE_MIN_S: onset rate and mean of the dark runs.

    ``w`` weights each dark run by the probability that it is a tag outage (0 or 1 for a hard split);
    ``lengths`` (bursts, per dark run) are the tag outages' expected lengths inside the runs (the E-step's),
    else the runs' own lengths.
    """
    d_min = TAG_OUTAGE_MIN_S
    dur = (np.concatenate(lengths) * period if lengths is not None
           else np.concatenate([(e - s) * period for s, e, _ in dark]))
    cens = np.concatenate([c for _, _, c in dark])
    # an outage under way when the trace begins has no onset in it, but its end is seen (the exponential
    # forgets: what is left of it is exponential with the same mean); one still under way at the end
    # has an onset and no end
    started = np.concatenate([s > 0 for s, _, _ in dark])
    ended = np.concatenate([e < t.t_s.size for (_, e, _), t in zip(dark, tabs, strict=True)])
    wt = np.concatenate(w).astype(float)
    hard = wt > 0.5
    onsets = float(np.sum(wt[started]))
    up_bursts = float(sum(t.t_s.size for t in tabs) - np.sum(wt * dur / period))
    out: dict[str, Any] = {"min_duration_s": d_min, "n_outages": int((hard & ~cens).sum()),
                           "n_censored": int((hard & cens).sum()), "events": onsets,
                           "up_bursts": up_bursts, "effective_up_bursts": up_bursts,
                           "durations_s": dur[hard & ~cens].tolist(), "censored_s": dur[hard & cens].tolist()}
    if wt.sum() < 0.5:
        out["onset_prob"] = 0.0
        return out
    # exponential durations seen only above d_min: the excess D - d_min is exponential with the same mean
    # (every attributed stretch counts as exposure, every seen end as an event), and only a share
    # exp(-d_min / mean) of the outages is long enough to be attributed
    mean_s = max(float(np.sum(wt * (dur - d_min).clip(0))) / max(float(np.sum(wt[ended])), 0.5), period)
    seen = float(np.exp(-d_min / mean_s))
    out.update(mean_s=mean_s, effective_up_bursts=up_bursts * seen,
               onset_prob=float(onsets / max(up_bursts * seen, 1)))
    return out


def _masks(tabs: Sequence[AttemptTable], dark: Sequence[tuple[np.ndarray, ...]],
           z: list[np.ndarray]) -> list[np.ndarray]:
    """Bursts inside the dark runs flagged in ``z``, per trace."""
    masks = []
    for tab, (s, e, _), zz in zip(tabs, dark, z, strict=True):
        m = np.zeros(tab.t_s.size + 1, dtype=np.int64)
        np.add.at(m, s[zz], 1)
        np.add.at(m, e[zz], -1)
        masks.append(np.cumsum(m)[:-1] > 0)
    return masks


def _tag_e_step(tabs: Sequence[AttemptTable], dark: Sequence[tuple[np.ndarray, ...]], cand: list[np.ndarray],
                pos: list[tuple[np.ndarray, ...]], seqs: Sequence[AnchorSequence], masks: list[np.ndarray],
                chains: dict[str, tuple[float, float, float]], tag_chain: tuple[float, float]
                ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per trace, every dark run's log-odds of holding a tag outage (-inf for runs shorter than the
    minimum) and the tag outage's expected length in bursts (the run's own length where not a candidate)."""
    n_pos = [p[0].size for p in pos]
    f = [np.zeros(n) for n in n_pos]
    g = [np.zeros(n) for n in n_pos]
    whole = [np.zeros(int(c.sum())) for c in cand]
    for sq in seqs:  # one pass per anchor and trace
        s, e, _ = dark[sq.trace]
        c = cand[sq.trace]
        if not c.any():
            continue
        fa, ga, wa = _anchor_boundary_terms(sq, s[c], e[c], masks[sq.trace], chains[sq.anchor_id], pos[sq.trace])
        f[sq.trace] += fa
        g[sq.trace] += ga
        whole[sq.trace] += wa
    odds, lengths = [], []
    for i, (tab, (s, e, _), c) in enumerate(zip(tabs, dark, cand, strict=True)):
        o, ln = np.full(s.size, -np.inf), (e - s).astype(float)
        if c.any():
            o[c], ln[c] = _tag_posterior(s[c], e[c], tab.t_s.size, f[i], g[i], whole[i], pos[i], tag_chain)
        odds.append(o)
        lengths.append(ln)
    return odds, lengths


TAG_EM_MAX_ITER = 30
"""EM iterations of the tag attribution (it stops when no attribution and no tag parameter changes)."""
TAG_EM_RTOL = 1e-3
"""Relative change of the tag onset and mean below which the EM has converged."""
TAG_LR_MIN = 10.0
"""Likelihood-ratio statistic a tag process needs over independent per-anchor outages alone."""


def fit_tag_outages(tabs: Sequence[AttemptTable], dark: Sequence[tuple[np.ndarray, ...]],
                    seqs: Sequence[AnchorSequence], fits: dict[str, dict[str, Any]],
                    refit: Any, burst_rate_hz: float) -> tuple[dict[str, Any], list[np.ndarray], Any, Any]:
    """Tag outages and per-anchor outages jointly: which dark runs are tag outages (EM).

    Model: every anchor alternates up/outage on its own (the per-anchor chain of
    :func:`fit_dropout_outage`); a tag process of the same kind, on the burst grid, silences every
    anchor while it lasts. A *dark run* (no anchor heard, >= TAG_OUTAGE_MIN_S) is either a tag outage
    or holds a tag outage of at least TAG_OUTAGE_MIN_S, over the whole run or part of it (the anchors'
    own outages filling the edges). E-step: for each dark run the log-odds of the two, summed over every
    placement [p, q) of the tag outage in the run: the tag chain's term (off exactly over [p, q) vs up
    throughout) plus, per anchor in link range over the run, the exact likelihood of its run of misses
    through the dark run whole (no tag outage) or cut by [p, q); its posterior probability of holding a
    tag outage is expit(log-odds), with the outage's expected length. M-step: tag onset and mean from
    the dark runs weighted by that probability, of those expected lengths (left-truncated at
    TAG_OUTAGE_MIN_S); per-anchor fits with the runs of probability > 0.5 unobserved (``refit``, only
    when that set changes). Starts from every dark run attributed to the tag. The tag process is kept
    when the classification likelihood (tag chain plus per-anchor fits, runs split at 0.5) beats the
    per-anchor fits alone by TAG_LR_MIN. Returns (tag report, excluded bursts per trace, per-anchor
    stats, per-anchor fits); per-anchor stats are None when no tag process is kept.
    """
    period = 1.0 / burst_rate_hz
    d_min_bursts = TAG_OUTAGE_MIN_S * burst_rate_hz - 1e-9
    cand = [(e - s) >= d_min_bursts for s, e, _ in dark]
    pos = [_boundary_positions(s[c], e[c], int(np.ceil(d_min_bursts))) for (s, e, _), c in zip(dark, cand, strict=True)]
    lengths: list[np.ndarray] | None = None
    no_ex = [np.zeros(t.t_s.size, dtype=bool) for t in tabs]
    n_cand = int(sum(c.sum() for c in cand))
    ll_indep = float(sum(f.get("log_likelihood", 0.0) for f in fits.values()))
    if not n_cand:
        tag = _tag_m_step(tabs, dark, [np.zeros(c.size) for c in cand], period)
        tag["note"] = f"no run of >= {TAG_OUTAGE_MIN_S:.3g} s without any in-range anchor: no tag outage"
        return tag, no_ex, None, None
    w = [c.astype(float) for c in cand]
    z = [c.copy() for c in cand]
    z_fitted: list[np.ndarray] | None = None
    history: list[float] = []
    cur_fits, stats_t, prev = fits, None, None
    masks = no_ex
    for _ in range(TAG_EM_MAX_ITER):
        # M-step: per-anchor fits when the set of tag outages changed, tag process from the weights
        if z_fitted is None or not all(np.array_equal(a, b) for a, b in zip(z, z_fitted, strict=True)):
            masks = _masks(tabs, dark, z)
            if any(zz.any() for zz in z):
                stats_t, cur_fits = refit(masks, cur_fits)
            else:
                stats_t, cur_fits = None, fits
            z_fitted = [zz.copy() for zz in z]
        tag = _tag_m_step(tabs, dark, w, period, lengths)
        history.append(round(tag["events"], 2))
        if not tag["onset_prob"]:
            break
        par = np.array([tag["onset_prob"], tag["mean_s"]])
        if prev is not None and np.all(np.abs(par - prev) <= TAG_EM_RTOL * prev):
            break
        prev = par
        al_t, be_t = _from_rates(tag["onset_prob"] * burst_rate_hz, tag["mean_s"], period)
        # E-step: over where in each dark run the tag outage begins and ends
        odds, lengths = _tag_e_step(tabs, dark, cand, pos, seqs, masks,
                                    {a: _chain_of_fit(f, burst_rate_hz) for a, f in cur_fits.items()}, (al_t, be_t))
        w = [np.where(c, expit(o), 0.0) for o, c in zip(odds, cand, strict=True)]
        z = [ww > 0.5 for ww in w]
    n_tag = int(sum(zz.sum() for zz in z_fitted or z))
    ll_tag = 0.0
    if n_tag and tag["onset_prob"]:
        al_t, be_t = _from_rates(tag["onset_prob"] * burst_rate_hz, tag["mean_s"], period)
        # tag chain: up -> up on every transition, plus each attributed run's log-odds against staying up
        ll_tag = float(sum((tab.t_s.size - 1) * np.log1p(-al_t) + np.sum(_tag_log_odds(s[zz], e[zz], tab.t_s.size,
                                                                                        al_t, be_t))
                           for tab, (s, e, _), zz in zip(tabs, dark, z_fitted or z, strict=True)))
    ll_joint = float(sum(f.get("log_likelihood", 0.0) for f in cur_fits.values())) + ll_tag
    lr = 2.0 * (ll_joint - ll_indep) if n_tag else 0.0
    tag.update(method=("EM over the dark runs (no in-range anchor heard) of at least min_duration_s: each is a tag "
                       "outage or an overlap of per-anchor outages, by the joint likelihood of the per-anchor "
                       "up/outage chains and the tag chain; exponential tag durations truncated at min_duration_s; "
                       "events = sum of the runs' tag probabilities"),
               n_candidates=n_cand, em_iterations=len(history), events_per_iteration=history,
               lr_statistic=float(lr))
    if n_tag == 0 or lr < TAG_LR_MIN:
        tag = _tag_m_step(tabs, dark, [np.zeros(c.size) for c in cand], period)
        tag.update(n_candidates=n_cand, lr_statistic=float(lr),
                   note=(f"{n_cand} dark runs of >= {TAG_OUTAGE_MIN_S:.3g} s, explained by overlapping per-anchor "
                         f"outages (tag process LR {lr:.1f} < {TAG_LR_MIN:g}): no tag outage"))
        return tag, no_ex, None, None
    return tag, masks, stats_t, cur_fits


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
    dark = [_dark_runs(tab, ok) for tab, ok in zip(tabs, in_range, strict=True)]
    seqs = _anchor_sequences(trace_anchor_ids, tabs, in_range)

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
            s, e, _ = _dark_runs(tab, ok)
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


def _in_range_limit(link: dict[str, Any], range_m: np.ndarray) -> float:
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
    limits = {a: _in_range_limit(lk, np.concatenate(ranges[a])) for a, lk in links.items() if lk.get("identifiable")}
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
